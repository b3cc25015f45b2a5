// The discovery (estimator/discovery/, docs/discovery.md) on simulated recordings where an effect
// is concealed as the issue describes (tests/testing/discovery_scenarios.h): mostly orbital
// orientation, outliers and an outage, the effect in one gyro only. Checks the verdict names the
// effect and the gyro, the fitted physics against the truth, the held-out drift rate before and
// after, `none` on a recording the model explains, `unexplained` for a fault the library does not
// hold, two effects in one recording; and the pieces: distribution functions, regimes from the body
// rate, the model-free latency estimate, the star-tracker correction.
#include <algorithm>
#include <atomic>
#include <cmath>
#include <random>
#include <thread>

#include "absl/strings/str_format.h"
#include "estimator/discovery/apply_findings.h"
#include "estimator/discovery/candidates.h"
#include "estimator/discovery/deviation.h"
#include "estimator/discovery/diagnose.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/regimes.h"
#include "estimator/statistics.h"
#include "estimator/discovery/time_behaviour.h"
#include "estimator/basis_term.h"
#include "estimator/drift_model.h"
#include "estimator/rotation.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/discovery_scenarios.h"
#include "tests/testing/quaternion_matchers.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator::discovery {
namespace {

using ::esg::testing::DiscoveryScenario;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;

// Recording length of the diagnosis tests [h]: long enough for the regimes of the scenario
// (orbital 6.4 h, hold 2.4 h, ...), short enough for the unit suite.
constexpr double kHours = 24.0;

const Parameter* FindParameter(const Finding& f, const std::string& name) {
  for (const Parameter& p : f.parameters) {
    if (p.name == name) return &p;
  }
  return nullptr;
}

absl::StatusOr<DiagnosisReport> DiagnoseScenario(const std::string& effect, uint64_t seed,
                                                 SimulationResult* sim_out = nullptr,
                                                 const DiagnoseOptions& options = {}) {
  const SimulationSpec spec = DiscoveryScenario(effect, seed, kHours);
  auto sim = Simulate(spec);
  if (!sim.ok()) return sim.status();
  auto report = Diagnose(spec.config, sim->recording.frames, options);
  if (sim_out != nullptr) *sim_out = std::move(*sim);
  return report;
}

// Every finding's effect, explanation and notes, one per line: what a failing test shows.
std::string FindingsText(const DiagnosisReport& report) {
  std::string text;
  for (const Finding& f : report.findings) {
    text += "\n" + f.effect + ": " + f.explanation;
    for (const std::string& note : f.evidence.notes) text += "\n  " + note;
  }
  return text;
}

TEST(DiscoveryStatistics, ChiSquareQuantilesMatchTables) {
  EXPECT_NEAR(ChiSquareQuantile(0.95, 1), 3.8415, 1e-3);
  EXPECT_NEAR(ChiSquareQuantile(0.99, 6), 16.812, 1e-2);
  EXPECT_NEAR(ChiSquareQuantile(0.9999, 6), 27.856, 1e-2);
  for (double k : {1.0, 3.0, 12.0, 1000.0}) {
    for (double p : {0.01, 0.5, 0.999}) {
      EXPECT_NEAR(ChiSquareCdf(ChiSquareQuantile(p, k), k), p, 1e-8) << "k " << k << " p " << p;
    }
  }
  // The far tail from Q directly, not 1 - P.
  EXPECT_GT(ChiSquareSurvival(200.0, 6), 0.0);
  EXPECT_LT(ChiSquareSurvival(200.0, 6), 1e-35);
  // F(d, d) has median 1; F(1, d2) = t^2.
  EXPECT_NEAR(FSurvival(1.0, 7, 7), 0.5, 1e-9);
  EXPECT_NEAR(NormalSurvival(1.959964), 0.025, 1e-6);
}

// The evidence currency (docs/discovery.md "Evidence"): a Bayes factor's threshold 2 ln(M /
// alpha) holds the false-alarm rate below alpha / M whatever the model (Markov's inequality,
// E[B] = 1 without the effect). Checked on the simplest case with a closed form: the mean of n
// unit-variance samples, effect-free, against a mean with prior N(0, 1).
TEST(DiscoveryStatistics, EvidenceThresholdBoundsTheFalseAlarmRate) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> unit(0.0, 1.0);
  const int n = 50, trials = 200000;
  const double v0 = 1.0 / n, v1 = 1.0 / n + 1.0;  // variance of the mean without / with
  const double threshold = EvidenceThreshold(0.01, 5);
  EXPECT_NEAR(threshold, 2.0 * std::log(500.0), 1e-12);
  int alarms = 0;
  for (int t = 0; t < trials; ++t) {
    const double mean = unit(rng) * std::sqrt(v0);
    const double evidence = std::log(v0 / v1) + mean * mean * (1.0 / v0 - 1.0 / v1);  // 2 ln B
    alarms += evidence > threshold ? 1 : 0;
  }
  EXPECT_LE(static_cast<double>(alarms) / trials, 0.01 / 5);
  EXPECT_NEAR(EvidenceBound(2.0 * std::log(500.0)), 1.0 / 500.0, 1e-12);
  EXPECT_EQ(EvidenceBound(-3.0), 1.0);
}

TEST(DiscoveryStatistics, EvidenceOverAPriorAveragesTheBayesFactors) {
  // B = 0.5 * 3 + 0.5 * 1 = 2.
  EXPECT_NEAR(EvidenceOverPrior({{0.5, 2.0 * std::log(3.0)}, {0.5, 0.0}}), 2.0 * std::log(2.0),
              1e-12);
  // No overflow at the evidence of a large effect; one point is that point.
  EXPECT_NEAR(EvidenceOverPrior({{1.0, 9000.0}}), 9000.0, 1e-9);
  EXPECT_NEAR(EvidenceOverPrior({{0.25, 9000.0}, {0.75, 10.0}}), 9000.0 + 2.0 * std::log(0.25),
              1e-9);
  EXPECT_TRUE(std::isinf(EvidenceOverPrior({})));
}

TEST(DiscoveryStatistics, RobustLineIgnoresOutliers) {
  std::vector<double> t, y;
  for (int i = 0; i < 50; ++i) {
    t.push_back(i);
    y.push_back(2.0 + 0.5 * i + ((i % 2) ? 0.01 : -0.01));
  }
  y[10] += 100.0;
  y[30] -= 80.0;
  const RobustLine line = FitRobustLine(t, y);
  EXPECT_NEAR(line.slope, 0.5, 1e-3);
  EXPECT_NEAR(line.intercept, 2.0, 1e-2);
  EXPECT_EQ(line.used, 48);
}

TEST(DiscoveryRegimes, FindsOrbitalHoldAndRotationFromTheData) {
  SimulationSpec spec = DiscoveryScenario("none", 4, 15.0);  // orbital 4 h, hold 1.5 h, ...
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const auto& frames = sim->recording.frames;
  const BodyRates rates = MeasureBodyRates(spec.config, frames);
  const std::vector<RegimeSpan> spans = FindRegimes(frames, rates);
  auto regime_at = [&](double hours) {
    const int i = static_cast<int>(hours * 60.0);
    const int k = SpanOfFrame(spans, i);
    return k >= 0 ? spans[k].regime : Regime::kSlew;
  };
  EXPECT_EQ(regime_at(2.0), Regime::kOrbital);
  EXPECT_EQ(regime_at(4.9), Regime::kInertialHold);
  EXPECT_EQ(regime_at(8.0), Regime::kOrbital);
  EXPECT_EQ(regime_at(10.4), Regime::kRotation);
  EXPECT_EQ(regime_at(13.0), Regime::kOrbital);
  for (const RegimeSpan& s : spans) {
    if (s.regime == Regime::kOrbital)
      EXPECT_NEAR(s.mean_rate, 2 * kPi / 5640.0, 0.01 * 2 * kPi / 5640.0);
    if (s.regime == Regime::kRotation)
      EXPECT_NEAR(s.mean_rate, 2 * kPi / 3600.0, 0.01 * 2 * kPi / 3600.0);
  }
  // Every frame belongs to exactly one span, in order.
  EXPECT_EQ(spans.front().first_frame, 0);
  EXPECT_EQ(spans.back().last_frame, static_cast<int>(frames.size()) - 1);
  for (size_t k = 1; k < spans.size(); ++k)
    EXPECT_EQ(spans[k].first_frame, spans[k - 1].last_frame + 1);
}

// The body rate of gyro k's regressors (basis_term.h kBodyRate) comes from two other gyros'
// spin axes, never from gyro k's readings or the star tracker, whose noise gyro k's deviation
// carries (errors in variables: on an orbital profile a body-rate column differenced from the
// star tracker fitted the star tracker's noise at 2 ln B ~ 1600 on effect-free gyros). Perturbing
// every star-tracker sample and every reading of gyro 1 by ~10 arcsec changes gyro 1's
// deviations but not one body rate of its trajectory.
TEST(DiscoveryDeviation, TheBodyRateOfAGyrosRegressorsCarriesNoneOfItsDeviationsNoise) {
  SimulationSpec spec = DiscoveryScenario("none", 4, 4.0);
  spec.profile = *Orbital(OrbitalOptions{});
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const std::vector<TelemetryFrame>& frames = sim->recording.frames;
  SessionOptions options;
  options.model.parts = kModelPart1;
  options.model.random_walk = true;
  auto run = RunModel(spec.config, options, frames);
  ASSERT_THAT(run, IsOk());
  std::vector<TelemetryFrame> perturbed = frames;
  std::mt19937_64 rng(11);
  std::normal_distribution<double> arcsec(0.0, ArcsecToRad(10.0));
  auto turn = [&] { return ExpQuaternion(Eigen::Vector3d(arcsec(rng), arcsec(rng), arcsec(rng))); };
  for (TelemetryFrame& f : perturbed) {
    if (f.star_tracker.has_value()) {
      f.star_tracker->q_in_b = (f.star_tracker->q_in_b * turn()).normalized();
    }
    if (f.gyros[0].has_value()) f.gyros[0]->h_k = (turn() * f.gyros[0]->h_k).normalized();
  }
  auto rates_of = [&](const std::vector<TelemetryFrame>& fs) {
    return MeasureBodyRates(spec.config, fs);
  };
  auto before = MeasureDeviations(spec.config, run->gyros, frames, rates_of(frames), *run, {1});
  auto after = MeasureDeviations(spec.config, run->gyros, perturbed, rates_of(perturbed), *run, {1});
  ASSERT_THAT(before, IsOk());
  ASSERT_THAT(after, IsOk());
  // The rate of each frame step, once per step (a step's substeps share it; their number follows
  // the star tracker's turn, which the perturbation changes).
  auto step_rates = [](const DeviationSeries& d) {
    std::vector<Eigen::Vector3d> w;
    for (const TrajectoryStep& s : d.steps) {
      if (w.empty() || s.inputs.w_k != w.back()) w.push_back(s.inputs.w_k);
    }
    return w;
  };
  const std::vector<Eigen::Vector3d> w_before = step_rates(before->front());
  const std::vector<Eigen::Vector3d> w_after = step_rates(after->front());
  ASSERT_GT(w_before.size(), 200u);
  ASSERT_EQ(w_after.size(), w_before.size());
  for (size_t i = 0; i < w_before.size(); ++i) EXPECT_EQ(w_after[i], w_before[i]) << "step " << i;
  // The perturbation reached the deviations.
  double moved = 0.0;
  for (size_t k = 0; k < before->front().y.size(); ++k) {
    moved = std::max(moved, (after->front().y[k] - before->front().y[k]).norm());
  }
  EXPECT_GT(moved, ArcsecToRad(10.0));
}

TEST(DiscoveryLatency, ModelFreeEstimateFromRateChanges) {
  for (double latency : {0.0, 0.3}) {
    SimulationSpec spec = DiscoveryScenario("none", 5, 15.0);
    spec.star_tracker.latency = latency;
    auto sim = Simulate(spec);
    ASSERT_THAT(sim, IsOk());
    const BodyRates rates = MeasureBodyRates(spec.config, sim->recording.frames);
    const LatencyEstimate e = LatencyFromRates(sim->recording.frames, rates, spec.config);
    ASSERT_TRUE(e.observable);
    EXPECT_LT(e.sigma, 0.02);
    // First order in the rate change: within 3 sigma plus 5% of the latency.
    EXPECT_NEAR(e.latency, latency, 3 * e.sigma + 0.05 * latency) << "latency " << latency;
  }
}

TEST(DiscoveryLatency, SteadyRotationAloneDoesNotObserveLatency) {
  SimulationSpec spec = DiscoveryScenario("none", 6, 4.0);
  spec.profile = *Orbital(OrbitalOptions{});
  spec.star_tracker.latency = 0.3;
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const BodyRates rates = MeasureBodyRates(spec.config, sim->recording.frames);
  EXPECT_FALSE(LatencyFromRates(sim->recording.frames, rates, spec.config).observable);
}

TEST(DiscoveryModelRun, StarTrackerCorrectionUndoesMisalignment) {
  const Eigen::Vector3d m(ArcsecToRad(20), ArcsecToRad(-25), ArcsecToRad(10));
  const Eigen::Quaterniond q_true = Eigen::Quaterniond(0.6, 0.2, -0.3, 0.7).normalized();
  std::vector<TelemetryFrame> frames(1);
  frames[0].star_tracker = StarTrackerReading{q_true * ExpQuaternion(m), true};
  BodyRates rates;
  rates.best = {Eigen::Vector3d(0.001, -0.002, 0.0005)};
  StarTrackerCorrection c;
  c.misalignment_b = m;
  const auto corrected = CorrectStarTracker(frames, rates, c);
  EXPECT_LT(RotationAngle(corrected[0].star_tracker->q_in_b, q_true), 1e-12);
  // Latency: the body turned by w tau since the stamped attitude.
  c = StarTrackerCorrection{};
  c.latency = 0.4;
  const auto late = CorrectStarTracker(frames, rates, c);
  EXPECT_NEAR(RotationAngle(late[0].star_tracker->q_in_b, frames[0].star_tracker->q_in_b),
              rates.best[0].norm() * 0.4, 1e-12);
}

// The drift step's onset search continues runs from checkpoints (time_behaviour.h FitDriftStep): a
// run continued from a checkpoint taken before frame k, with the first run's steps before k,
// gives the same steps and deviance as the one run.
TEST(DiscoveryModelRun, RunContinuedFromACheckpointEqualsOneRun) {
  const SimulationSpec spec = DiscoveryScenario("none", 8, 6.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const auto& frames = sim->recording.frames;
  SessionOptions options;
  options.model.parts = kModelPart1;
  options.model.random_walk = true;
  ModelRunOptions with_checkpoint;
  const int k = static_cast<int>(frames.size()) / 2;
  with_checkpoint.checkpoint_frames = {k};
  auto whole = RunModel(spec.config, options, frames, with_checkpoint);
  ASSERT_THAT(whole, IsOk());
  ASSERT_EQ(whole->checkpoints.size(), 1u);
  ModelRunOptions continued;
  continued.start = &whole->checkpoints[0];
  continued.start_frame = k;
  auto tail = RunModel(spec.config, options, frames, continued);
  ASSERT_THAT(tail, IsOk());
  ModelRun joined;
  for (const StepRecord& s : whole->steps) {
    if (s.frame < k) joined.steps.push_back(s);
  }
  joined.steps.insert(joined.steps.end(), tail->steps.begin(), tail->steps.end());
  ASSERT_EQ(joined.steps.size(), whole->steps.size());
  for (size_t i = 0; i < joined.steps.size(); ++i) {
    EXPECT_EQ(joined.steps[i].frame, whole->steps[i].frame);
    EXPECT_EQ(joined.steps[i].nis, whole->steps[i].nis) << "step " << i;
  }
  EXPECT_EQ(ComputeDeviance(joined).value, ComputeDeviance(*whole).value);
}

// A coefficient release (session.h CoefficientRelease) adds its variance at the first frame at or
// after its time, and only to free coefficients of that gyro.
TEST(DiscoveryModelRun, CoefficientReleaseWidensOnlyAfterItsTime) {
  const SimulationSpec spec = DiscoveryScenario("none", 8, 6.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const auto& frames = sim->recording.frames;
  SpacecraftConfig config = spec.config;
  config.gyros[1].model_sigma.C1 = Eigen::Vector3d::Constant(DegPerHourToRadPerSec(1e-6));
  SessionOptions options;
  options.model.parts = kModelPart10;
  options.model.random_walk = true;
  const int k = static_cast<int>(frames.size()) / 2;
  options.coefficient_releases.push_back(
      {2, kThetaC1, 3, frames[k].time, DegPerHourToRadPerSec(0.1)});
  ModelRunOptions before;
  before.stop_frame = k - 1;
  auto held = RunModel(config, options, frames, before);
  ASSERT_THAT(held, IsOk());
  ModelRunOptions after;
  after.stop_frame = k;
  auto released = RunModel(config, options, frames, after);
  ASSERT_THAT(released, IsOk());
  auto sigma_c1 = [](const ModelRun& r) {
    for (const GyroEstimate& g : r.gyros) {
      if (g.id == 2) return RadPerSecToDegPerHour(g.sigma.C1.norm());
    }
    return -1.0;
  };
  EXPECT_LT(sigma_c1(*held), 1e-5);
  EXPECT_GT(sigma_c1(*released), 0.05);
}

// eq. (3) over time: a rotor displacement growing by 0.3 um/h along case x (10 mV/h of offset
// voltage with k = 200, U0 = 200 V, d0 = 30 um) is read from the voltages' trend; a constant one
// shows none.
TEST(DiscoveryRotorDisplacement, VoltageTrendGivesTheDisplacementRate) {
  SimulationSpec spec = DiscoveryScenario("rotor_displacement", 1, 6.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const int gyro = ::esg::testing::AffectedGyro(1);
  std::vector<TelemetryFrame> growing = sim->recording.frames;
  const absl::Time t0 = growing.front().time;
  for (TelemetryFrame& f : growing) {
    auto& r = f.gyros[gyro - 1];
    ASSERT_TRUE(r.has_value() && r->u_k_mv.has_value());
    (*r->u_k_mv)(0) += 10.0 * absl::ToDoubleHours(f.time - t0);
  }
  auto rate = [&](const std::vector<TelemetryFrame>& frames, int axis) {
    CandidateFit fit;
    DescribeVoltageTrend(spec.config, frames, gyro, fit);
    for (const Parameter& p : fit.fitted) {
      if (p.name == absl::StrFormat("displacementRateUmPerH[%d]", axis)) return p;
    }
    return Parameter{};
  };
  const Parameter x = rate(growing, 0);
  ASSERT_GT(x.sigma, 0.0);
  EXPECT_NEAR(x.value, 0.3, 3.0 * x.sigma);
  EXPECT_LT(x.sigma, 0.01);
  for (int axis = 0; axis < 3; ++axis) {
    const Parameter c = rate(sim->recording.frames, axis);
    ASSERT_GT(c.sigma, 0.0);
    EXPECT_NEAR(c.value, 0.0, 3.0 * c.sigma) << "axis " << axis;
  }
}

// The voltage check that decides (eq. (3)): a simulated rotor displacement of 0.6 um (|C1| 0.039
// deg/h at the simulator's 0.065 deg/h per um) is seen in its voltages; the same |C1| over voltages
// that show no displacement is refused; without voltages, or with voltages too noisy to show the
// floor (|C1| / 0.067 deg/h per um / 10), nothing is decided.
TEST(DiscoveryRotorDisplacement, SuspensionVoltagesDecideWhereTheyCanShowTheDisplacement) {
  SimulationSpec spec = DiscoveryScenario("rotor_displacement", 1, 6.0);
  const int gyro = ::esg::testing::AffectedGyro(1);
  spec.gyros[gyro - 1].rotor_displacement_k = Eigen::Vector3d(0.6, 0.0, 0.0) * kMetresPerUm;
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const Eigen::Vector3d C1_k_rad_s = Eigen::Vector3d(DegPerHourToRadPerSec(0.039), 0.0, 0.0);
  const VoltageAgreement seen =
      CheckDisplacementAgainstVoltages(spec.config, sim->recording.frames, gyro, C1_k_rad_s);
  EXPECT_TRUE(seen.informative) << seen.note;
  EXPECT_TRUE(seen.agrees) << seen.note;
  EXPECT_NEAR(seen.voltage_um, 0.6, 3.0 * seen.voltage_sigma_um + 1e-9) << seen.note;
  EXPECT_NEAR(seen.drift_implied_um, 0.039 / (0.2 / 3.0), 1e-9);
  EXPECT_NEAR(seen.floor_um, seen.drift_implied_um / 10.0, 1e-12);
  EXPECT_THAT(seen.note, HasSubstr("they agree"));

  // The other gyros' voltages show no displacement.
  const int other = gyro % 3 + 1;
  const VoltageAgreement unseen =
      CheckDisplacementAgainstVoltages(spec.config, sim->recording.frames, other, C1_k_rad_s);
  EXPECT_TRUE(unseen.informative) << unseen.note;
  EXPECT_FALSE(unseen.agrees) << unseen.note;
  EXPECT_LT(unseen.voltage_um + kVoltageZ * unseen.voltage_sigma_um, unseen.floor_um);
  EXPECT_THAT(unseen.note, HasSubstr("not a rotor displacement"));

  // No voltages telemetered; voltages with 1 V of noise (the mean's sigma ~ 0.5 um).
  std::vector<TelemetryFrame> without = sim->recording.frames, noisy = sim->recording.frames;
  std::mt19937_64 rng(7);
  std::normal_distribution<double> volt_mv(0.0, 1000.0);
  for (size_t i = 0; i < without.size(); ++i) {
    if (without[i].gyros[other - 1].has_value()) without[i].gyros[other - 1]->u_k_mv.reset();
    if (auto& r = noisy[i].gyros[other - 1]; r.has_value() && r->u_k_mv.has_value()) {
      *r->u_k_mv = Eigen::Vector3d(volt_mv(rng), volt_mv(rng), volt_mv(rng));
    }
  }
  for (const auto* frames : {&without, &noisy}) {
    const VoltageAgreement v =
        CheckDisplacementAgainstVoltages(spec.config, *frames, other, C1_k_rad_s);
    EXPECT_FALSE(v.informative) << v.note;
    EXPECT_TRUE(v.agrees) << v.note;
  }
}

TEST(Diagnose, RejectsBadInput) {
  const SpacecraftConfig config = ::esg::testing::DiscoveryConfig();
  EXPECT_THAT(Diagnose(config, {}, DiagnoseOptions{}),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("frames")));
  SimulationSpec spec = DiscoveryScenario("none", 1, 6.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  DiagnoseOptions bad_model;
  bad_model.model = "12";
  EXPECT_THAT(Diagnose(config, sim->recording.frames, bad_model),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("model")));
  std::vector<TelemetryFrame> swapped = sim->recording.frames;
  std::swap(swapped[3], swapped[4]);
  EXPECT_THAT(Diagnose(config, swapped, DiagnoseOptions{}),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("frame 4")));
}

TEST(Diagnose, NothingMissingGivesNone) {
  auto report = DiagnoseScenario("none", 7);
  ASSERT_THAT(report, IsOk());
  EXPECT_EQ(report->verdict, "none");
  EXPECT_TRUE(report->findings.empty());
  EXPECT_EQ(report->before.residual_rms_arcsec, report->after.residual_rms_arcsec);
  EXPECT_FALSE(report->mismatch.found);
  // Every candidate of the library the model lacks was tried once (3 gyros x 3, k0 being free, + 4
  // common: the star tracker's misalignment, latency and orbital misalignment, the common random
  // walk; + a drift step, a warm-up, a coefficient step, a transient, a turning displacement and
  // a random walk per gyro), and the basis's readout group and sun families per gyro
  // (readout_candidate.h), and none is significant: no warm-up, coefficient step, transient or
  // turning displacement either.
  EXPECT_EQ(report->candidates.size(), 37u);
  int warm_ups = 0, coefficient_steps = 0, transients = 0, turning = 0;
  for (const CandidateScore& c : report->candidates) {
    EXPECT_FALSE(c.significant) << c.effect << " " << c.gyro;
    warm_ups += c.effect == "warm_up" ? 1 : 0;
    coefficient_steps += c.effect == "coefficient_step" ? 1 : 0;
    transients += c.effect == "transient" ? 1 : 0;
    turning += c.effect == "turning_displacement" ? 1 : 0;
  }
  EXPECT_EQ(warm_ups, 3);
  EXPECT_EQ(coefficient_steps, 3);
  EXPECT_EQ(transients, 3);
  EXPECT_EQ(turning, 3);
  EXPECT_GE(report->before.gaps.size(), 2u);  // held-out spans in the hold and the rotation
}

TEST(Diagnose, ConcealedRotorDisplacementInOneGyroIsFoundAndExplained) {
  SimulationResult sim;
  const uint64_t seed = 2;
  auto report = DiagnoseScenario("rotor_displacement", seed, &sim);
  ASSERT_THAT(report, IsOk());
  const int gyro = ::esg::testing::AffectedGyro(seed);
  EXPECT_EQ(report->verdict, "rotor_displacement");
  ASSERT_FALSE(report->findings.empty());
  const Finding& f = report->findings.front();
  EXPECT_EQ(f.gyro, gyro);
  EXPECT_EQ(report->mismatch.gyro, gyro);
  // Fitted C1, C2 against the truth (the configured model has none).
  const DriftCoefficients& truth = *sim.true_coefficients[gyro - 1];
  for (int i = 0; i < 3; ++i) {
    const Parameter* c1 = FindParameter(f, absl::StrFormat("c1DegH[%d]", i));
    const Parameter* c2 = FindParameter(f, absl::StrFormat("c2DegH[%d]", i));
    ASSERT_NE(c1, nullptr);
    ASSERT_NE(c2, nullptr);
    EXPECT_NEAR(c1->value, RadPerSecToDegPerHour(truth.C1(i)), 0.01);
    EXPECT_NEAR(c2->value, RadPerSecToDegPerHour(truth.C2(i)), 0.015);
  }
  // A displaced rotor: C1 and C2 collinear, along the displacement the voltages show (eq. (3)).
  EXPECT_LT(FindParameter(f, "lineAngleDeg")->value, 10.0);
  // One physical term: lambda, C10 and C20 of eq. (8)-(9) within 3 sigma of the truth's, where
  // C1 = (C10 + C20) lambda and C2 = -5 C20 lambda with C1 . lambda > 0.
  const Eigen::Vector3d lambda_true = truth.C1.normalized();
  const double C20_true = RadPerSecToDegPerHour(-truth.C2.dot(lambda_true) / 5.0);
  const double C10_true = RadPerSecToDegPerHour(truth.C1.dot(lambda_true)) - C20_true;
  const Parameter* c10 = FindParameter(f, "c10DegH");
  const Parameter* c20 = FindParameter(f, "c20DegH");
  const Parameter* lambda_sigma = FindParameter(f, "lambdaSigmaDeg");
  ASSERT_NE(c10, nullptr);
  ASSERT_NE(c20, nullptr);
  ASSERT_NE(lambda_sigma, nullptr);
  EXPECT_GT(c10->sigma, 0.0);
  EXPECT_NEAR(c10->value, C10_true, 3.0 * c10->sigma);
  EXPECT_NEAR(c20->value, C20_true, 3.0 * c20->sigma);
  Eigen::Vector3d lambda;
  for (int i = 0; i < 3; ++i) {
    lambda(i) = FindParameter(f, absl::StrFormat("lambda[%d]", i))->value;
  }
  const double lambda_error_deg =
      RadToDeg(std::acos(std::clamp(lambda.normalized().dot(lambda_true), -1.0, 1.0)));
  EXPECT_LT(lambda_error_deg, 3.0 * lambda_sigma->value);
  EXPECT_GT(FindParameter(f, "collinearityP")->value, kCollinearityP);
  EXPECT_THAT(f.explanation, HasSubstr("one displaced rotor (eq. (8)-(10)) along lambda"));
  EXPECT_LT(FindParameter(f, "lambdaToVoltageAngleDeg")->value, 10.0);
  EXPECT_NEAR(FindParameter(f, "displacementSizeUm")->value, std::sqrt(0.64 + 1.0 + 0.36), 0.05);
  // The paper's measure: held-out attitude drift at least 2x smaller with the effect added.
  EXPECT_GT(report->before.gap_drift_rate_deg_h, 0.0);
  EXPECT_LT(report->after.gap_drift_rate_deg_h, 0.5 * report->before.gap_drift_rate_deg_h);
  EXPECT_LT(report->after.residual_rms_arcsec, report->before.residual_rms_arcsec);
  EXPECT_THAT(f.explanation, HasSubstr("displaced rotor"));
}

TEST(Diagnose, StarTrackerLatencyIsFoundWithItsSize) {
  auto report = DiagnoseScenario("star_tracker_latency", 3);
  ASSERT_THAT(report, IsOk());
  EXPECT_EQ(report->verdict, "star_tracker_latency");
  ASSERT_FALSE(report->findings.empty());
  const Parameter* tau = FindParameter(report->findings.front(), "latencyMs");
  ASSERT_NE(tau, nullptr);
  EXPECT_NEAR(tau->value, 300.0, 30.0);
}

TEST(Diagnose, TwoEffectsInOneRecordingAreBothFound) {
  const uint64_t seed = 1;
  auto report = DiagnoseScenario("two", seed);
  ASSERT_THAT(report, IsOk());
  bool rotor = false, star_tracker = false;
  for (const Finding& f : report->findings) {
    rotor |= f.effect == "rotor_displacement" && f.gyro == ::esg::testing::AffectedGyro(seed);
    star_tracker |= f.effect == "star_tracker_misalignment";
  }
  EXPECT_TRUE(rotor);
  EXPECT_TRUE(star_tracker);
  EXPECT_NE(report->verdict, "unexplained");
}

// A jump of one gyro's readings (60 arcsec at 40% of the recording) is neither a drift nor a
// mounting that holds throughout: outside the library, it is reported unexplained in that gyro
// (D43: the drift step and the per-gyro walk fit it only in part; a jump of the gyro's readings
// at the onset, no physics, explains it at least as well).
TEST(Diagnose, FaultOutsideTheLibraryIsUnexplainedNotForced) {
  const uint64_t seed = 2;
  auto report = DiagnoseScenario("readout_jump", seed);
  ASSERT_THAT(report, IsOk());
  SCOPED_TRACE(FindingsText(*report));
  EXPECT_EQ(report->verdict, "unexplained");
  ASSERT_FALSE(report->findings.empty());
  EXPECT_EQ(report->findings.back().gyro, ::esg::testing::AffectedGyro(seed));
  // Candidates fit it only in part of the recording.
  bool any_inhomogeneous = false;
  for (const CandidateScore& c : report->candidates)
    any_inhomogeneous |= c.significant && !c.homogeneous;
  EXPECT_TRUE(any_inhomogeneous);
}

// Time behaviour (docs/discovery.md): a drift constant in case axes switched on at 40% of the
// recording (9.6 h of 24 h; 0.041 deg/h, discovery_scenarios.h) is named a drift step of that
// gyro, with its onset interval holding the true onset and the step vector within 3 of its
// stated sigma of the truth. Seed 2 (gyro 3), fixed before the first run.
TEST(Diagnose, DriftStepIsFoundWithItsOnsetAndSize) {
  const uint64_t seed = 2;
  SimulationResult sim;
  auto report = DiagnoseScenario("drift_step", seed, &sim);
  ASSERT_THAT(report, IsOk());
  const int gyro = ::esg::testing::AffectedGyro(seed);
  EXPECT_EQ(report->verdict, "drift_step");
  ASSERT_EQ(report->findings.size(), 1u) << report->findings.back().effect;
  const Finding& f = report->findings.front();
  EXPECT_EQ(f.gyro, gyro);
  EXPECT_EQ(f.time.kind, "step");
  const double true_onset_hours = 0.4 * kHours;
  std::string evidence = f.explanation;
  for (const std::string& note : f.evidence.notes) evidence += "\n  " + note;
  SCOPED_TRACE(evidence);
  EXPECT_LE(f.time.onset_lower_hours, true_onset_hours);
  EXPECT_GE(f.time.onset_upper_hours, true_onset_hours);
  EXPECT_LT(f.time.onset_upper_hours - f.time.onset_lower_hours, 2.0);
  const Eigen::Vector3d truth_deg_h(0.02, -0.03, 0.02);
  for (int i = 0; i < 3; ++i) {
    const Parameter* d = FindParameter(f, absl::StrFormat("driftStepDegH[%d]", i));
    ASSERT_NE(d, nullptr);
    ASSERT_GT(d->sigma, 0.0);
    EXPECT_NEAR(d->value, truth_deg_h(i), 3.0 * d->sigma) << "component " << i;
  }
  EXPECT_THAT(f.explanation, HasSubstr(absl::StrFormat("in gyro %d at ", gyro)));
  EXPECT_THAT(f.explanation, HasSubstr("drift step of"));
  EXPECT_LT(report->after.residual_rms_arcsec, report->before.residual_rms_arcsec);
}

// A warm-up (docs/discovery.md, "Time behaviour"): a case-fixed drift of 0.1 deg/h decaying from
// the start with tau = 4 h (discovery_scenarios.h) is found in its gyro as three exponential_decay
// terms, tau's 95% interval holding 4 h, the amplitude within 3 of its stated sigma of the truth
// per case axis; `esg model apply` adds the terms to a configuration that validates. Seed 2
// (gyro 3), fixed before the first run.
TEST(Diagnose, WarmUpIsFoundWithItsTimeConstantAndAmplitude) {
  const uint64_t seed = 2;
  auto report = DiagnoseScenario("warm_up", seed);
  ASSERT_THAT(report, IsOk());
  const int gyro = ::esg::testing::AffectedGyro(seed);
  SCOPED_TRACE(FindingsText(*report));
  ASSERT_FALSE(report->findings.empty());
  const Finding& f = report->findings.front();
  EXPECT_EQ(f.effect, kEffectBasisTerm);
  EXPECT_EQ(f.gyro, gyro);
  EXPECT_EQ(f.time.kind, kTimeWarmUp);
  EXPECT_THAT(f.explanation, HasSubstr(absl::StrFormat("warm-up of gyro %d: ", gyro)));
  const Parameter* lower = FindParameter(f, "tauLowerHours");
  const Parameter* upper = FindParameter(f, "tauUpperHours");
  ASSERT_NE(lower, nullptr);
  ASSERT_NE(upper, nullptr);
  EXPECT_LE(lower->value, ::esg::testing::kWarmUpTauHours);
  EXPECT_GE(upper->value, ::esg::testing::kWarmUpTauHours);
  const Eigen::Vector3d truth_deg_h = ::esg::testing::WarmUpAmplitudeDegH();
  for (int i = 0; i < 3; ++i) {
    const Parameter* a = FindParameter(f, absl::StrFormat("warmUpDegH[%d]", i));
    ASSERT_NE(a, nullptr);
    ASSERT_GT(a->sigma, 0.0);
    EXPECT_NEAR(a->value, truth_deg_h(i), 3.0 * a->sigma) << "component " << i;
  }
  ASSERT_EQ(f.basis_terms.size(), 3u);
  for (const BasisTerm& t : f.basis_terms) EXPECT_EQ(t.kind, BasisKind::kExponentialDecay);
  const SpacecraftConfig config = ::esg::testing::DiscoveryScenario("warm_up", seed, kHours).config;
  const AppliedFindings applied = WithFindings(config, *report);
  const GyroConfig* g = applied.config.FindGyro(gyro);
  ASSERT_NE(g, nullptr);
  ASSERT_GE(g->basis_terms.size(), 3u);
  EXPECT_EQ(g->basis_terms.front().kind, BasisKind::kExponentialDecay);
  EXPECT_THAT(ValidateConfig(applied.config), IsOk());
  EXPECT_LT(report->after.residual_rms_arcsec, report->before.residual_rms_arcsec);
}

// The basis terms of a coefficient step (D110) move the spin axis as the step of eq. (1), (10)
// does: for every coefficient, the terms' drift across h equals the regressor's column times the
// step at spin axes in every octant, and is zero before the onset.
TEST(DiscoveryCoefficientStep, BasisTermsMoveTheSpinAxisAsTheStepOfEachCoefficient) {
  const absl::Time onset = absl::FromUnixSeconds(1551398400);
  std::mt19937 rng(37);
  std::normal_distribution<double> normal;
  for (int i = 0; i < kNumDriftCoefficients; ++i) {
    const Eigen::VectorXd step = Eigen::VectorXd::Constant(1, DegPerHourToRadPerSec(0.07));
    const std::vector<BasisTerm> terms = CoefficientStepTerms(i, step, onset, 0.0);
    ASSERT_FALSE(terms.empty()) << "coefficient " << i;
    for (int trial = 0; trial < 8; ++trial) {
      BasisInputs in;
      in.h_k = Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
      const Eigen::Matrix3d across =
          Eigen::Matrix3d::Identity() - in.h_k * in.h_k.transpose();
      const Eigen::Vector3d want = across * DriftRegressor(in.h_k).col(i) * step(0);
      in.time = onset + absl::Minutes(1);
      const Eigen::Vector3d got = across * BasisDriftSum_k(terms, in);
      EXPECT_LT((got - want).norm(), 1e-12 * DegPerHourToRadPerSec(1.0))
          << "coefficient " << i << ", h " << in.h_k.transpose();
      in.time = onset - absl::Minutes(1);
      EXPECT_EQ(BasisDriftSum_k(terms, in), Eigen::Vector3d::Zero()) << "coefficient " << i;
    }
  }
}

// A step of k0 (eq. (1)) by 0.1 deg/h at 40% of the recording (discovery_scenarios.h k0_step) is
// found in its gyro as a coefficient step of k0, the onset's 95% interval holding the true onset
// and the step within 3 of its stated sigma of the truth; `esg model apply` adds the three
// switched spin_axis_harmonic terms to a configuration that validates. Seed 2 (gyro 3), fixed
// before the first run.
TEST(Diagnose, K0StepIsFoundWithItsOnsetAndSize) {
  const uint64_t seed = 2;
  auto report = DiagnoseScenario("k0_step", seed);
  ASSERT_THAT(report, IsOk());
  const int gyro = ::esg::testing::AffectedGyro(seed);
  SCOPED_TRACE(FindingsText(*report));
  ASSERT_FALSE(report->findings.empty());
  const Finding& f = report->findings.front();
  EXPECT_EQ(f.effect, kEffectBasisTerm);
  EXPECT_EQ(f.gyro, gyro);
  EXPECT_EQ(f.time.kind, kTimeCoefficientStep);
  EXPECT_THAT(f.explanation, HasSubstr(absl::StrFormat("a step of k0 of gyro %d", gyro)));
  const double true_onset_hours = ::esg::testing::kK0StepOnsetFraction * kHours;
  EXPECT_LE(f.time.onset_lower_hours, true_onset_hours);
  EXPECT_GE(f.time.onset_upper_hours, true_onset_hours);
  const Parameter* k0 = FindParameter(f, "k0StepDegH");
  ASSERT_NE(k0, nullptr);
  ASSERT_GT(k0->sigma, 0.0);
  EXPECT_NEAR(k0->value, ::esg::testing::kK0StepDegH, 3.0 * k0->sigma);
  ASSERT_EQ(f.basis_terms.size(), 3u);
  for (const BasisTerm& t : f.basis_terms) {
    EXPECT_EQ(t.kind, BasisKind::kSpinAxisHarmonic);
    EXPECT_EQ(t.epoch, f.time.onset);
  }
  const SpacecraftConfig config = DiscoveryScenario("k0_step", seed, kHours).config;
  const AppliedFindings applied = WithFindings(config, *report);
  const GyroConfig* g = applied.config.FindGyro(gyro);
  ASSERT_NE(g, nullptr);
  ASSERT_GE(g->basis_terms.size(), 3u);
  EXPECT_EQ(g->basis_terms.front().epoch, f.time.onset);
  EXPECT_THAT(ValidateConfig(applied.config), IsOk());
  EXPECT_LT(report->after.residual_rms_arcsec, report->before.residual_rms_arcsec);
}

// A step of C2 (eq. (10)) that the user's model holds at its bench value (discovery_scenarios.h
// c2_step: +(0.04, -0.05, 0.03) deg/h at 40% of the recording) is found in its gyro as a
// coefficient step of C2, each component within 3 of its stated sigma and the onset's 95%
// interval holding the true onset. Its drift turns with the spin axis, so a case-fixed step does
// not describe it: the test of a drift that returns to its mean weighs it against a step of C2
// itself (wander.h), which a stationary drift does not beat. Seed 2 (gyro 3), fixed before the
// first run; the candidates are the time behaviours it competes with, so that the test stays
// short.
TEST(Diagnose, C2StepIsFoundAsAStepOfC2NotAsADriftThatReturnsToItsMean) {
  const uint64_t seed = 2;
  DiagnoseOptions options;
  options.effects = {Effect::kCoefficientStep, Effect::kDriftStep, Effect::kWarmUp,
                     Effect::kRandomWalkDrift};
  auto report = DiagnoseScenario("c2_step", seed, nullptr, options);
  ASSERT_THAT(report, IsOk());
  const int gyro = ::esg::testing::AffectedGyro(seed);
  SCOPED_TRACE(FindingsText(*report));
  ASSERT_FALSE(report->findings.empty());
  const Finding& f = report->findings.front();
  EXPECT_EQ(f.effect, kEffectBasisTerm);
  EXPECT_EQ(f.gyro, gyro);
  EXPECT_EQ(f.time.kind, kTimeCoefficientStep);
  EXPECT_THAT(f.explanation, HasSubstr(absl::StrFormat("a step of C2 of gyro %d", gyro)));
  const double true_onset_hours = ::esg::testing::kK0StepOnsetFraction * kHours;
  EXPECT_LE(f.time.onset_lower_hours, true_onset_hours);
  EXPECT_GE(f.time.onset_upper_hours, true_onset_hours);
  const Eigen::Vector3d truth = ::esg::testing::CoefficientStepDegH("c2_step");
  for (int i = 0; i < 3; ++i) {
    const Parameter* c2 = FindParameter(f, absl::StrFormat("c2StepDegH[%d]", i));
    ASSERT_NE(c2, nullptr);
    ASSERT_GT(c2->sigma, 0.0);
    EXPECT_NEAR(c2->value, truth(i), 3.0 * c2->sigma) << "component " << i;
  }
  EXPECT_LT(report->after.gap_drift_rate_deg_h, report->before.gap_drift_rate_deg_h);
}

// A transient from an onset (discovery_scenarios.h transient: the warm_up scenario's 0.1 deg/h
// with tau = 4 h, from 40% of the recording on) is found in its gyro as three exponential_decay
// terms switched on at the onset, the onset's and tau's 95% intervals holding the truth and the
// amplitude within 3 of its stated sigma per case axis. Seed 2 (gyro 3), fixed before the first
// run. The candidates are the time behaviours a transient competes with (the full library's
// rows are the confusion bench's), so that the test stays short.
TEST(Diagnose, TransientFromAnOnsetIsFoundWithItsOnsetAndTimeConstant) {
  const uint64_t seed = 2;
  DiagnoseOptions options;
  options.effects = {Effect::kTransient, Effect::kWarmUp, Effect::kDriftStep,
                     Effect::kCoefficientStep};
  auto report = DiagnoseScenario("transient", seed, nullptr, options);
  ASSERT_THAT(report, IsOk());
  const int gyro = ::esg::testing::AffectedGyro(seed);
  SCOPED_TRACE(FindingsText(*report));
  ASSERT_FALSE(report->findings.empty());
  const Finding& f = report->findings.front();
  EXPECT_EQ(f.effect, kEffectBasisTerm);
  EXPECT_EQ(f.gyro, gyro);
  EXPECT_EQ(f.time.kind, kTimeTransient);
  const double true_onset_hours = 0.4 * kHours;
  EXPECT_LE(f.time.onset_lower_hours, true_onset_hours);
  EXPECT_GE(f.time.onset_upper_hours, true_onset_hours);
  const Parameter* lower = FindParameter(f, "tauLowerHours");
  const Parameter* upper = FindParameter(f, "tauUpperHours");
  ASSERT_NE(lower, nullptr);
  ASSERT_NE(upper, nullptr);
  EXPECT_LE(lower->value, ::esg::testing::kWarmUpTauHours);
  EXPECT_GE(upper->value, ::esg::testing::kWarmUpTauHours);
  const Eigen::Vector3d truth_deg_h = ::esg::testing::WarmUpAmplitudeDegH();
  for (int i = 0; i < 3; ++i) {
    const Parameter* a = FindParameter(f, absl::StrFormat("transientDegH[%d]", i));
    ASSERT_NE(a, nullptr);
    ASSERT_GT(a->sigma, 0.0);
    EXPECT_NEAR(a->value, truth_deg_h(i), 3.0 * a->sigma) << "component " << i;
  }
  ASSERT_EQ(f.basis_terms.size(), 3u);
  for (const BasisTerm& t : f.basis_terms) {
    EXPECT_EQ(t.kind, BasisKind::kExponentialDecay);
    EXPECT_EQ(t.epoch, f.time.onset);
  }
}

// A random walk raised in one gyro only (the library's 0.006 deg/h/sqrt(h), 4x the configured
// one) is that gyro's intensity, not the common one; seed 3 (gyro 1), fixed before the first run.
TEST(Diagnose, RandomWalkInOneGyroIsThatGyrosIntensity) {
  const uint64_t seed = 3;
  auto report = DiagnoseScenario("random_walk_one_gyro", seed);
  ASSERT_THAT(report, IsOk());
  EXPECT_EQ(report->verdict, "random_walk_drift");
  ASSERT_EQ(report->findings.size(), 1u) << report->findings.back().effect;
  const Finding& f = report->findings.front();
  EXPECT_EQ(f.gyro, ::esg::testing::AffectedGyro(seed));
  EXPECT_EQ(f.time.kind, "random_walk");
  const Parameter* q = FindParameter(f, "randomWalkDegHSqrtH");
  ASSERT_NE(q, nullptr);
  // The search grid's resolution (factors of 2, candidates.h).
  EXPECT_GT(q->value, 0.006 / 2.0);
  EXPECT_LT(q->value, 0.006 * 2.0);
}

// A random walk 15 times the configured intensity in every gyro is a raised common intensity,
// tested as an intensity (not by the homogeneity test); seed 4, fixed before the first run.
TEST(Diagnose, RandomWalkFifteenTimesConfiguredIsFoundAsAnIntensity) {
  const uint64_t seed = 4;
  auto report = DiagnoseScenario("random_walk_15x", seed);
  ASSERT_THAT(report, IsOk());
  EXPECT_EQ(report->verdict, "random_walk_drift");
  ASSERT_EQ(report->findings.size(), 1u) << report->findings.back().effect;
  EXPECT_EQ(report->findings.front().gyro, 0);
  const Parameter* q = FindParameter(report->findings.front(), "randomWalkDegHSqrtH");
  ASSERT_NE(q, nullptr);
  EXPECT_GT(q->value, 15 * 0.0015 / 2.0);
  EXPECT_LT(q->value, 15 * 0.0015 * 2.0);
  for (const CandidateScore& c : report->candidates) {
    if (c.effect == "random_walk_drift") {
      EXPECT_EQ(c.time_behaviour, "random_walk");
      EXPECT_TRUE(c.homogeneous);  // exempt: tested as an intensity
    }
  }
}

// The estimator starts no threads (options.h): the caller's runner gets at most options.threads
// tasks at once, and the report is the same with or without it.
TEST(Diagnose, ReportDoesNotDependOnTheCallersRunner) {
  const SimulationSpec spec = DiscoveryScenario("rotor_displacement", 1, 12.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  auto sequential = Diagnose(spec.config, sim->recording.frames, DiagnoseOptions{});
  ASSERT_THAT(sequential, IsOk());
  DiagnoseOptions options;
  options.threads = 3;
  std::atomic<int> calls{0}, most_tasks{0};
  options.run_parallel = [&](int count, const std::function<void(int)>& task) {
    ++calls;
    most_tasks = std::max(most_tasks.load(), count);
    std::vector<std::thread> helpers;
    for (int i = 1; i < count; ++i) helpers.emplace_back(task, i);
    task(0);
    for (std::thread& t : helpers) t.join();
  };
  auto parallel = Diagnose(spec.config, sim->recording.frames, options);
  ASSERT_THAT(parallel, IsOk());
  EXPECT_GT(calls.load(), 0);
  EXPECT_LE(most_tasks.load(), options.threads);
  EXPECT_EQ(parallel->verdict, sequential->verdict);
  EXPECT_EQ(parallel->filter_runs, sequential->filter_runs);
  EXPECT_EQ(parallel->before.deviance, sequential->before.deviance);
  EXPECT_EQ(parallel->after.deviance, sequential->after.deviance);
  EXPECT_EQ(parallel->after.held_out_nees, sequential->after.held_out_nees);
  ASSERT_EQ(parallel->findings.size(), sequential->findings.size());
  for (size_t i = 0; i < parallel->findings.size(); ++i) {
    EXPECT_EQ(parallel->findings[i].effect, sequential->findings[i].effect);
    EXPECT_EQ(parallel->findings[i].explanation, sequential->findings[i].explanation);
    ASSERT_EQ(parallel->findings[i].parameters.size(), sequential->findings[i].parameters.size());
    for (size_t k = 0; k < parallel->findings[i].parameters.size(); ++k) {
      EXPECT_EQ(parallel->findings[i].parameters[k].value,
                sequential->findings[i].parameters[k].value);
    }
  }
  ASSERT_EQ(parallel->candidates.size(), sequential->candidates.size());
  for (size_t i = 0; i < parallel->candidates.size(); ++i) {
    EXPECT_EQ(parallel->candidates[i].effect, sequential->candidates[i].effect);
    EXPECT_EQ(parallel->candidates[i].delta_deviance, sequential->candidates[i].delta_deviance);
  }
}

}  // namespace
}  // namespace esg::estimator::discovery
