// The star-tracker latency as a filter state (spacecraft_config.h StarTrackerConfig::
// latency_sigma, session.h): estimated online from the star-tracker differences, its effect on
// calibration, and its place in the checkpoint.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <utility>
#include <vector>

#include "estimator/session.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/paper_setup.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::PaperFlight;

SessionOptions Model(const char* name) {
  SessionOptions o;
  o.model = *ParseModel(name);
  return o;
}

struct CalibrationRun {
  EstimationSession session;
  int rejected = 0;           // star-tracker steps rejected by eq. (12) or (14)
  double worst_sigma = 0.0;   // |estimate - truth| / sigma over coefficients and misalignments
};

// Runs the model 10+11 filter with `config` over the simulated flight.
CalibrationRun Calibrate(const SpacecraftConfig& config, const SimulationSpec& spec, const SimulationResult& sim) {
  CalibrationRun r{*EstimationSession::Create(config, Model("10+11"))};
  for (const TelemetryFrame& frame : sim.recording.frames) {
    auto report = r.session.AddFrame(frame);
    EXPECT_THAT(report, IsOk());
    if (!report.ok()) return r;
    for (const Event& e : report->events) {
      r.rejected += e.kind == Event::Kind::kStarTrackerInnovation ||
                    e.kind == Event::Kind::kStarTrackerFault;
    }
  }
  for (const GyroEstimate& g : r.session.Gyros()) {
    const DriftVector t = sim.true_coefficients[g.id - 1]->AsVector();
    const DriftVector e = g.coefficients.AsVector(), sg = g.sigma.AsVector();
    for (int i = 0; i < kNumDriftCoefficients; ++i) {
      if (sg(i) > 0.0) r.worst_sigma = std::max(r.worst_sigma, std::abs(e(i) - t(i)) / sg(i));
    }
    const Eigen::Vector3d truth = spec.gyros[g.id - 1].misalignment_b;
    for (int k = 0; k < 3; ++k) {
      if (g.misalignment_sigma_b(k) <= 0.0) continue;
      r.worst_sigma = std::max(r.worst_sigma,
                               std::abs(g.misalignment_b(k) - truth(k)) / g.misalignment_sigma_b(k));
    }
  }
  return r;
}

// Runs the flight with an unknown latency of `truth_s` twice: the latency a state with prior
// 0 +- 0.5 s, and held at 0. Prints and returns both.
std::pair<CalibrationRun, CalibrationRun> EstimatedAndHeldAtZero(SimulationSpec spec,
                                                                 double truth_s) {
  spec.star_tracker.latency = truth_s;
  auto sim = Simulate(spec);
  EXPECT_THAT(sim, IsOk());
  SpacecraftConfig config = spec.config;
  config.star_tracker.latency = 0.0;
  config.star_tracker.latency_sigma = 0.5;
  CalibrationRun estimated = Calibrate(config, spec, *sim);
  config.star_tracker.latency_sigma = 0.0;
  CalibrationRun held_at_zero = Calibrate(config, spec, *sim);
  const LatencyEstimate e = estimated.session.StarTrackerLatency();
  std::printf("seed %llu, %.0f s frames, latency %+.1f s: estimated %.4f +- %.4f s; rejections %d "
              "(held at 0: %d); worst coefficient/misalignment error %.2f sigma (held at 0: %.2f)\n",
              static_cast<unsigned long long>(spec.seed), spec.telemetry_step, truth_s,
              e.latency_s, e.sigma_s, estimated.rejected, held_at_zero.rejected,
              estimated.worst_sigma, held_at_zero.worst_sigma);
  EXPECT_FALSE(held_at_zero.session.StarTrackerLatency().estimated);
  return {std::move(estimated), std::move(held_at_zero)};
}

// A latency of +-0.3 s that the configuration does not know (prior 0 +- 0.5 s) on the mixed
// profile (orbital, calibration turns, inertial hold: the body rate changes size and axis) with
// gyro readings every 10 s: the estimate is within 3 sigma of the truth with a sigma 100 times
// below the prior, the coefficients and misalignments within 3 sigma, and the star tracker is
// rejected at less than a fifth of the steps it is when the latency is left at 0. A sign error in
// the measurement model would drive the estimate to the opposite value; a filter blind to the
// latency's effect would keep the prior.
TEST(LatencyEstimation, AnUnknownLatencyIsEstimatedWithinThreeSigma) {
  for (uint64_t seed : {1, 2, 3}) {
    for (double truth_s : {0.3, -0.3}) {
      SimulationSpec spec = PaperFlight(seed, 24.0, "mixed");
      spec.telemetry_step = 10.0;
      const auto [estimated, held_at_zero] = EstimatedAndHeldAtZero(spec, truth_s);
      const LatencyEstimate e = estimated.session.StarTrackerLatency();
      ASSERT_TRUE(e.estimated);
      EXPECT_LE(std::abs(e.latency_s - truth_s), 3.0 * e.sigma_s) << "seed " << seed;
      EXPECT_LT(e.sigma_s, 0.5 / 100.0);
      EXPECT_LE(estimated.worst_sigma, 3.0) << "seed " << seed;
      EXPECT_LT(5 * estimated.rejected, held_at_zero.rejected) << "seed " << seed;
    }
  }
}

// The paper's calibration flight with readings every 60 s: the rate at the star-tracker sample is
// extrapolated from 60 s means, and during the slews between spin axes (where the latency is
// observable at all: a steady spin about the sun line makes it a common rotation of the spin
// axes) that leaves the estimate short of the truth by 4-5% (measured: 0.288 and -0.284 s, at
// 3-4 sigma; docs/formats.md states it). Asserted: within 8% of the truth, calibration within 3
// sigma, and less than a fifth of the rejections of a latency left at 0.
TEST(LatencyEstimation, OnSixtySecondReadingsTheEstimateIsWithinEightPercent) {
  for (double truth_s : {0.3, -0.3}) {
    const auto [estimated, held_at_zero] =
        EstimatedAndHeldAtZero(PaperFlight(3, 24.0, "calibration"), truth_s);
    const LatencyEstimate e = estimated.session.StarTrackerLatency();
    ASSERT_TRUE(e.estimated);
    EXPECT_LE(std::abs(e.latency_s - truth_s), 0.08 * std::abs(truth_s));
    EXPECT_LE(estimated.worst_sigma, 3.0);
    EXPECT_LT(5 * estimated.rejected, held_at_zero.rejected);
  }
}

// A session with the latency state restored from its checkpoint mid-flight continues bit for bit:
// the same latency estimate, covariance and coefficients after the remaining frames.
TEST(LatencyEstimation, TheEstimatedLatencyResumesBitForBitFromACheckpoint) {
  SimulationSpec spec = PaperFlight(4, 6.0, "calibration");
  spec.star_tracker.latency = 0.2;
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  SpacecraftConfig config = spec.config;
  config.star_tracker.latency_sigma = 0.5;
  EstimationSession straight = *EstimationSession::Create(config, Model("10+11"));
  const auto& frames = sim->recording.frames;
  const size_t cut = frames.size() / 2;
  for (size_t k = 0; k < cut; ++k) ASSERT_THAT(straight.AddFrame(frames[k]), IsOk());
  const SessionCheckpoint checkpoint = straight.ExportCheckpoint();
  EXPECT_EQ(checkpoint.version, 10);
  auto restored = EstimationSession::FromCheckpoint(config, Model("10+11"), checkpoint);
  ASSERT_THAT(restored, IsOk());
  EXPECT_EQ(restored->StarTrackerLatency().latency_s, straight.StarTrackerLatency().latency_s);
  EXPECT_NE(straight.StarTrackerLatency().latency_s, 0.0);
  for (size_t k = cut; k < frames.size(); ++k) {
    ASSERT_THAT(straight.AddFrame(frames[k]), IsOk());
    ASSERT_THAT(restored->AddFrame(frames[k]), IsOk());
  }
  EXPECT_EQ(restored->StarTrackerLatency().latency_s, straight.StarTrackerLatency().latency_s);
  EXPECT_EQ(restored->StarTrackerLatency().sigma_s, straight.StarTrackerLatency().sigma_s);
  EXPECT_TRUE(restored->covariance() == straight.covariance());
  // A configuration that holds the latency does not fit a checkpoint with the latency state.
  config.star_tracker.latency_sigma = 0.0;
  EXPECT_FALSE(EstimationSession::FromCheckpoint(config, Model("10+11"), checkpoint).ok());
}

}  // namespace
}  // namespace esg::estimator
