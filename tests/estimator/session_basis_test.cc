// Basis terms (estimator/basis_term.h) as model terms of the session's filter
// (session_propagation.cc, session_update.cc, session_initialization.cc): a free term is
// calibrated from a simulated recording, a held term propagates exactly as the eq. (10) term it
// equals, and a readout distortion is undone where readings enter.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "estimator/basis_term.h"
#include "estimator/calibration_model.h"
#include "estimator/drift_model.h"
#include "estimator/session.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/paper_setup.h"
#include "tests/testing/quaternion_matchers.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::PaperFlight;

SessionOptions Options(const char* model) {
  SessionOptions o;
  o.model = *ParseModel(model);
  return o;
}

// Three case-fixed drift terms (spin_axis_harmonic of degree 0) along case axes 1..3.
std::vector<BasisTerm> CaseFixedTerms(const Eigen::Vector3d& value, double sigma) {
  std::vector<BasisTerm> terms;
  for (int m = 1; m <= 3; ++m) {
    BasisTerm t;
    t.kind = BasisKind::kSpinAxisHarmonic;
    t.axis = m;
    t.exponents = {0, 0, 0};
    t.value = value(m - 1);
    t.sigma = sigma;
    terms.push_back(t);
  }
  return terms;
}

// The rotor displacement of the paper's flight (gyros 1-3) without its C2 part (c20 = 0) is a
// case-fixed C1 drift, dw = (h h^T - I) C1 (eq. (8), (10)); a filter without free C1, C2 but with
// three free degree-0 basis terms per gyro explains it with values -C1 (the same drift across
// h_k, up to the part along h that does not move the spin axis). Each calibrated value lies
// within 3 sigma of -C1 of the simulator's truth, and the data shrank its sigma well below the
// 0.1 deg/h prior.
TEST(SessionBasis, FreeCaseFixedTermsCalibrateToMinusTheDisplacementC1) {
  SimulationSpec spec = PaperFlight(7, 8.0);
  for (GyroTruth& g : spec.gyros) g.c20_per_m = 0.0;
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  SpacecraftConfig config = testing::PaperConfig(/*estimate_c=*/false);
  const double prior = DegPerHourToRadPerSec(0.1);
  for (GyroConfig& g : config.gyros) g.basis_terms = CaseFixedTerms(Eigen::Vector3d::Zero(), prior);
  auto session = EstimationSession::Create(config, Options("10+11"));
  ASSERT_THAT(session, IsOk());
  for (const TelemetryFrame& f : sim->recording.frames) ASSERT_THAT(session->AddFrame(f), IsOk());
  int checked = 0;
  double worst_normalised = 0.0, worst_ratio = 0.0;
  for (const GyroEstimate& e : session->Gyros()) {
    if (e.id > 3) continue;
    const Eigen::Vector3d C1 = sim->true_coefficients[e.id - 1]->C1;
    ASSERT_GT(C1.norm(), DegPerHourToRadPerSec(0.05)) << "gyro " << e.id;
    EXPECT_TRUE(sim->true_coefficients[e.id - 1]->C2.isZero(0.0));
    ASSERT_EQ(e.basis_terms.size(), 3u);
    ASSERT_EQ(e.basis_sigma.size(), 3u);
    for (int m = 0; m < 3; ++m) {
      const double value = e.basis_terms[m].value, sigma = e.basis_sigma[m];
      EXPECT_NEAR(value, -C1(m), 3.0 * sigma)
          << "gyro " << e.id << " axis " << m + 1 << ": " << RadPerSecToDegPerHour(value)
          << " +- " << RadPerSecToDegPerHour(sigma) << " deg/h, truth "
          << RadPerSecToDegPerHour(-C1(m));
      EXPECT_LT(sigma, 0.3 * prior) << "gyro " << e.id << " axis " << m + 1;
      EXPECT_GT(sigma, 0.0);
      worst_normalised = std::max(worst_normalised, std::abs(value + C1(m)) / sigma);
      worst_ratio = std::max(worst_ratio, sigma / prior);
      ++checked;
    }
  }
  EXPECT_EQ(checked, 9);
  std::printf("worst |value + C1| / sigma %.2f, worst sigma / prior %.3f\n", worst_normalised,
              worst_ratio);
}

// A warm-up, dw_k = A exp(-t / tau) from the start (simulator.h TransientDrift), in gyro 1 of the
// paper's flight (C2 part of the displacements 0, their C1 as three free case-fixed terms per gyro
// as above): three free exponential_decay terms of gyro 1 with the true tau (basis_term.h; epoch
// the first frame) calibrate to A, each within 3 sigma, sigma well below the 0.2 deg/h prior. A
// session stopped half-way, checkpointed and resumed (session.h FromCheckpoint) ends with the same
// terms, bit for bit: the checkpoint carries the terms' values, the configuration the rest.
TEST(SessionBasis, FreeExponentialDecayTermsCalibrateAWarmUpAndResumeFromACheckpoint) {
  SimulationSpec spec = PaperFlight(7, 8.0);
  for (GyroTruth& g : spec.gyros) g.c20_per_m = 0.0;
  const Eigen::Vector3d A = DegPerHourToRadPerSec(1.0) * Eigen::Vector3d(0.1, -0.08, 0.06);
  const double tau_s = 3.0 * 3600.0;
  TransientDrift warm_up;
  warm_up.amplitude_k_rad_s = A;
  warm_up.time_constant_s = tau_s;
  spec.gyros[0].transient_drift = warm_up;
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const std::vector<TelemetryFrame>& frames = sim->recording.frames;
  SpacecraftConfig config = testing::PaperConfig(/*estimate_c=*/false);
  const double prior = DegPerHourToRadPerSec(0.1);
  for (GyroConfig& g : config.gyros) g.basis_terms = CaseFixedTerms(Eigen::Vector3d::Zero(), prior);
  for (int m = 1; m <= 3; ++m) {
    BasisTerm t;
    t.kind = BasisKind::kExponentialDecay;
    t.axis = m;
    t.time_constant = tau_s;
    t.epoch = frames.front().time;
    t.sigma = DegPerHourToRadPerSec(0.2);
    config.gyros[0].basis_terms.push_back(t);
  }
  ASSERT_THAT(ValidateConfig(config), IsOk());
  const SessionOptions options = Options("10+11");
  auto whole = EstimationSession::Create(config, options);
  auto first = EstimationSession::Create(config, options);
  ASSERT_THAT(whole, IsOk());
  ASSERT_THAT(first, IsOk());
  const size_t half = frames.size() / 2;
  for (size_t i = 0; i < frames.size(); ++i) {
    ASSERT_THAT(whole->AddFrame(frames[i]), IsOk());
    if (i < half) ASSERT_THAT(first->AddFrame(frames[i]), IsOk());
  }
  auto resumed = EstimationSession::FromCheckpoint(config, options, first->ExportCheckpoint());
  ASSERT_THAT(resumed, IsOk());
  for (size_t i = half; i < frames.size(); ++i) ASSERT_THAT(resumed->AddFrame(frames[i]), IsOk());
  const GyroEstimate e = whole->Gyros().front();
  const GyroEstimate r = resumed->Gyros().front();
  ASSERT_EQ(e.id, 1);
  ASSERT_EQ(e.basis_terms.size(), 6u);
  ASSERT_EQ(r.basis_terms.size(), 6u);
  for (int m = 0; m < 3; ++m) {
    const double value = e.basis_terms[3 + m].value, sigma = e.basis_sigma[3 + m];
    EXPECT_EQ(e.basis_terms[3 + m].kind, BasisKind::kExponentialDecay);
    EXPECT_NEAR(value, A(m), 3.0 * sigma)
        << "axis " << m + 1 << ": " << RadPerSecToDegPerHour(value) << " +- "
        << RadPerSecToDegPerHour(sigma) << " deg/h, truth " << RadPerSecToDegPerHour(A(m));
    EXPECT_GT(sigma, 0.0);
    EXPECT_LT(sigma, 0.3 * DegPerHourToRadPerSec(0.2)) << "axis " << m + 1;
    EXPECT_EQ(r.basis_terms[3 + m].value, value) << "axis " << m + 1;
    EXPECT_EQ(r.basis_sigma[3 + m], sigma) << "axis " << m + 1;
  }
}

// A drift that follows a temperature through a 40 min lag (simulator.h ChannelDrift), in gyro 1
// of the paper's flight, the temperature telemetered as channel T_gyro1: three free channel terms
// of gyro 1 in the lag form with the true time constant and reference (basis_term.h kChannel)
// calibrate to the gain, each within 3 sigma, sigma well below the prior; a session checkpointed
// half-way (version 9: the held channel and its lag) and resumed ends with the same terms, bit
// for bit. The same terms without the channel in the frames stay at their prior (s = 0).
TEST(SessionBasis, FreeChannelLagTermsCalibrateADriftFollowingATemperatureAndResume) {
  SimulationSpec spec = PaperFlight(7, 8.0);
  for (GyroTruth& g : spec.gyros) g.c20_per_m = 0.0;
  const Eigen::Vector3d gain = DegPerHourToRadPerSec(1.0) * Eigen::Vector3d(-0.03, 0.03, 0.025);
  ChannelDrift drift;
  drift.channel = "T_gyro1";
  drift.gain_k_rad_s_per_unit = gain;
  drift.lag_s = 2400.0;
  drift.correlation_time_s = 2.0 * 3600.0;
  spec.gyros[0].channel_drift = drift;
  ChannelConfig declared;
  declared.name = "T_gyro1";
  declared.unit = "K";
  declared.valid_min = 250.0;
  declared.valid_max = 350.0;
  declared.max_age = absl::Minutes(10);
  spec.config.channels.push_back(declared);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const std::vector<TelemetryFrame>& frames = sim->recording.frames;
  ASSERT_NE(frames[10].channels.Find("T_gyro1"), nullptr);
  SpacecraftConfig config = testing::PaperConfig(/*estimate_c=*/false);
  config.channels.push_back(declared);
  const double prior = DegPerHourToRadPerSec(0.1);
  for (GyroConfig& g : config.gyros) g.basis_terms = CaseFixedTerms(Eigen::Vector3d::Zero(), prior);
  for (int m = 1; m <= 3; ++m) {
    BasisTerm t;
    t.kind = BasisKind::kChannel;
    t.axis = m;
    t.channel = "T_gyro1";
    t.form = ChannelForm::kLag;
    t.time_constant = drift.lag_s;
    t.reference = drift.mean;
    t.sigma = DegPerHourToRadPerSec(0.1);
    config.gyros[0].basis_terms.push_back(t);
  }
  ASSERT_THAT(ValidateConfig(config), IsOk());
  const SessionOptions options = Options("10+11");
  auto whole = EstimationSession::Create(config, options);
  auto first = EstimationSession::Create(config, options);
  auto blind = EstimationSession::Create(config, options);
  ASSERT_THAT(whole, IsOk());
  ASSERT_THAT(first, IsOk());
  ASSERT_THAT(blind, IsOk());
  const size_t half = frames.size() / 2;
  for (size_t i = 0; i < frames.size(); ++i) {
    ASSERT_THAT(whole->AddFrame(frames[i]), IsOk());
    if (i < half) ASSERT_THAT(first->AddFrame(frames[i]), IsOk());
    TelemetryFrame without = frames[i];
    without.channels = Channels();
    ASSERT_THAT(blind->AddFrame(without), IsOk());
  }
  const SessionCheckpoint checkpoint = first->ExportCheckpoint();
  EXPECT_EQ(checkpoint.version, 10);
  auto resumed = EstimationSession::FromCheckpoint(config, options, checkpoint);
  ASSERT_THAT(resumed, IsOk());
  for (size_t i = half; i < frames.size(); ++i) ASSERT_THAT(resumed->AddFrame(frames[i]), IsOk());
  const GyroEstimate e = whole->Gyros().front();
  const GyroEstimate r = resumed->Gyros().front();
  const GyroEstimate b = blind->Gyros().front();
  ASSERT_EQ(e.basis_terms.size(), 6u);
  ASSERT_EQ(r.basis_terms.size(), 6u);
  for (int m = 0; m < 3; ++m) {
    const double value = e.basis_terms[3 + m].value, sigma = e.basis_sigma[3 + m];
    EXPECT_EQ(e.basis_terms[3 + m].kind, BasisKind::kChannel);
    EXPECT_NEAR(value, gain(m), 3.0 * sigma)
        << "axis " << m + 1 << ": " << RadPerSecToDegPerHour(value) << " +- "
        << RadPerSecToDegPerHour(sigma) << " deg/h per K, truth " << RadPerSecToDegPerHour(gain(m));
    EXPECT_GT(sigma, 0.0);
    EXPECT_LT(sigma, 0.3 * DegPerHourToRadPerSec(0.1)) << "axis " << m + 1;
    EXPECT_EQ(r.basis_terms[3 + m].value, value) << "axis " << m + 1;
    EXPECT_EQ(r.basis_sigma[3 + m], sigma) << "axis " << m + 1;
    // Without the channel the term's regressor is 0: nothing to calibrate it.
    EXPECT_EQ(b.basis_terms[3 + m].value, 0.0) << "axis " << m + 1;
    EXPECT_NEAR(b.basis_sigma[3 + m], DegPerHourToRadPerSec(0.1), 1e-12) << "axis " << m + 1;
  }
}

// A held term propagates like the eq. (10) term it equals: C1 = c held, against C1 = 0 and three
// held degree-0 terms of values -c ((h h^T - I) c and -c differ only along h, which does not move
// the spin axis). Same attitude output at every frame to 1e-12.
TEST(SessionBasis, HeldCaseFixedTermsPropagateAsTheEquivalentC1) {
  SimulationSpec spec = PaperFlight(11, 2.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const Eigen::Vector3d c =
      DegPerHourToRadPerSec(1.0) * Eigen::Vector3d(0.08, -0.05, 0.12);  // case axes
  SpacecraftConfig with_c1 = testing::PaperConfig(/*estimate_c=*/false);
  SpacecraftConfig with_basis = with_c1;
  with_c1.gyros[0].model.C1 = c;
  with_basis.gyros[0].basis_terms = CaseFixedTerms(-c, /*sigma=*/0.0);
  auto a = EstimationSession::Create(with_c1, Options("10+11"));
  auto b = EstimationSession::Create(with_basis, Options("10+11"));
  ASSERT_THAT(a, IsOk());
  ASSERT_THAT(b, IsOk());
  ASSERT_EQ(a->state_size(), 0);
  double largest = 0.0;
  for (const TelemetryFrame& f : sim->recording.frames) {
    auto ra = a->AddFrame(f);
    auto rb = b->AddFrame(f);
    ASSERT_THAT(ra, IsOk());
    ASSERT_THAT(rb, IsOk());
    ASSERT_EQ(ra->attitude.valid, rb->attitude.valid);
    EXPECT_THAT(rb->attitude.q_in_b, testing::IsNearQuaternion(ra->attitude.q_in_b, 1e-12))
        << absl::FormatTime(f.time);
    largest = std::max(largest, ra->attitude.q_in_b.angularDistance(rb->attitude.q_in_b));
  }
  EXPECT_EQ(a->state_size(), b->state_size());
  // Not vacuous: the term moves the attitude against a session without it.
  SpacecraftConfig without = testing::PaperConfig(/*estimate_c=*/false);
  auto z = EstimationSession::Create(without, Options("10+11"));
  ASSERT_THAT(z, IsOk());
  StepReport last;
  for (const TelemetryFrame& f : sim->recording.frames) last = *z->AddFrame(f);
  EXPECT_GT(last.attitude.q_in_b.angularDistance(a->CurrentAttitude().q_in_b), 1e-9);
  EXPECT_LT(largest, 1e-12);
}

// Readings distorted by h_meas = normalise((I + D) h_k) and a configuration that states D give
// the session the undistorted readings: same outputs as the undistorted recording with D = 0.
TEST(SessionBasis, ReadoutDistortionIsUndoneWhereReadingsEnter) {
  SimulationSpec spec = PaperFlight(5, 1.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  Eigen::Matrix3d D;
  D << 2e-3, 5e-4, -1e-3, 5e-4, -3e-3, 8e-4, -1e-3, 8e-4, 1e-3;
  std::vector<TelemetryFrame> distorted = sim->recording.frames;
  for (TelemetryFrame& f : distorted) {
    if (f.gyros[1].has_value()) {
      f.gyros[1]->h_k = ((Eigen::Matrix3d::Identity() + D) * f.gyros[1]->h_k).normalized();
    }
  }
  SpacecraftConfig config = testing::PaperConfig();
  SpacecraftConfig config_d = config;
  config_d.gyros[1].readout_distortion = D;
  auto plain = EstimationSession::Create(config, Options("10+11"));
  auto corrected = EstimationSession::Create(config_d, Options("10+11"));
  auto uncorrected = EstimationSession::Create(config, Options("10+11"));
  ASSERT_THAT(plain, IsOk());
  ASSERT_THAT(corrected, IsOk());
  ASSERT_THAT(uncorrected, IsOk());
  double worst = 0.0, uncorrected_worst = 0.0;
  for (size_t k = 0; k < distorted.size(); ++k) {
    auto rp = plain->AddFrame(sim->recording.frames[k]);
    auto rc = corrected->AddFrame(distorted[k]);
    auto ru = uncorrected->AddFrame(distorted[k]);
    ASSERT_THAT(rp, IsOk());
    ASSERT_THAT(rc, IsOk());
    ASSERT_THAT(ru, IsOk());
    worst = std::max(worst, rp->attitude.q_in_b.angularDistance(rc->attitude.q_in_b));
    uncorrected_worst =
        std::max(uncorrected_worst, rp->attitude.q_in_b.angularDistance(ru->attitude.q_in_b));
  }
  EXPECT_LT(worst, 1e-12);
  EXPECT_GT(uncorrected_worst, ArcsecToRad(10));  // the distortion matters when not undone
}

// Inputs of the terms in propagation: a suspension-voltage term drifts with the frames'
// u_k_mv (mV -> V), held while frames lack it, and its free coefficient is a state after the
// free eq. (1) coefficients (state_layout.h).
TEST(SessionBasis, FreeTermsAreStatesOfTheirGyrosBlockAfterTheFreeCoefficients) {
  SpacecraftConfig config = testing::PaperConfig();
  BasisTerm voltage;
  voltage.kind = BasisKind::kSuspensionVoltage;
  voltage.axis = 1;
  voltage.index = {2, 1};
  voltage.sigma = DegPerHourToRadPerSec(0.01);
  BasisTerm held = voltage;
  held.sigma = 0.0;
  held.value = DegPerHourToRadPerSec(0.02);
  config.gyros[1].basis_terms = {held, voltage};
  SimulationSpec spec = PaperFlight(3, 0.5);
  spec.config = config;
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  auto with_terms = EstimationSession::Create(config, Options("10+11"));
  auto without = EstimationSession::Create(testing::PaperConfig(), Options("10+11"));
  ASSERT_THAT(with_terms, IsOk());
  ASSERT_THAT(without, IsOk());
  for (const TelemetryFrame& f : sim->recording.frames) {
    ASSERT_THAT(with_terms->AddFrame(f), IsOk());
    ASSERT_THAT(without->AddFrame(f), IsOk());
  }
  // One state more: gyro 2's free voltage term.
  EXPECT_EQ(with_terms->state_size(), without->state_size() + 1);
  const std::vector<GyroEstimate> g = with_terms->Gyros();
  ASSERT_EQ(g[1].basis_terms.size(), 2u);
  EXPECT_EQ(g[1].basis_terms[0].value, held.value);  // held
  EXPECT_EQ(g[1].basis_sigma[0], 0.0);
  EXPECT_GT(g[1].basis_sigma[1], 0.0);
  EXPECT_LE(g[1].basis_sigma[1], voltage.sigma);
  EXPECT_TRUE(g[0].basis_terms.empty());
  EXPECT_EQ(BasisTermLabel(g[1].basis_terms[1]), "voltage[2] -> x");
}

}  // namespace
}  // namespace esg::estimator
