// A verdict no stronger than its evidence (docs/discovery.md): the held-out point-prediction
// guard (estimator/discovery/point_prediction.h), the consistency tests of the model with the
// findings (consistency.h) on constructed runs with known statistics, and on a simulated
// recording whose mismatch the library cannot express (the star tracker's mount misalignment
// cycling with the orbit, a thermo-elastic effect outside the library): no finding may make the
// held-out gap drift worse.
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "estimator/discovery/apply_findings.h"
#include "estimator/discovery/consistency.h"
#include "estimator/discovery/diagnose.h"
#include "estimator/discovery/held_out.h"
#include "estimator/discovery/point_prediction.h"
#include "estimator/rotation.h"
#include "estimator/simulator.h"
#include "estimator/statistics.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/discovery_scenarios.h"
#include "tests/testing/scenario_orbit.h"

namespace esg::estimator::discovery {
namespace {

using ::testing::HasSubstr;

HeldOutResult HeldOut(double rate_deg_h, double nees, int dof) {
  HeldOutResult r;
  r.rate_rms_deg_h = rate_deg_h;
  r.nees = nees;
  r.dof = dof;
  return r;
}

// The case: a walk that lowers the held-out NEES 92 -> 4.4 by widening its covariance
// while the gap drift goes 0.0094 -> 0.027 deg/h.
TEST(PointPredictionGuard, AGapDriftMoreThanFivePercentWorseIsRefusedWhateverTheNees) {
  const HeldOutResult before = HeldOut(0.0094, 92.0, 12);
  EXPECT_TRUE(WorsensPointPrediction(before, HeldOut(0.027, 4.4, 12)));
  EXPECT_TRUE(WorsensPointPrediction(before, HeldOut(0.0094 * 1.06, 4.4, 12)));
  EXPECT_FALSE(WorsensPointPrediction(before, HeldOut(0.0094 * 1.04, 4.4, 12)));
  EXPECT_FALSE(WorsensPointPrediction(before, HeldOut(0.002, 400.0, 12)));
  // Nothing to compare without a rated held-out span.
  EXPECT_FALSE(WorsensPointPrediction(HeldOut(0.0, 0.0, 0), HeldOut(0.027, 4.4, 12)));
  EXPECT_THAT(PointPredictionNote("random_walk_drift", before, HeldOut(0.027, 4.4, 12)),
              HasSubstr("gap drift 0.0094 -> 0.0270 deg/h"));
}

HeldOutResult HeldOutWithSigma(double rate_deg_h, double sigma_deg_h) {
  HeldOutResult r = HeldOut(rate_deg_h, 0.0, 12);
  r.rate_rms_sigma_deg_h = sigma_deg_h;
  return r;
}

// The guard allows for the two gap drifts' sampling uncertainty: a worsening beyond 5% must be
// shown at one-sided 5% (z > 1.645, z = (R_after - 1.05 R_before) / sqrt(s_after^2 + 1.05^2
// s_before^2)). Issue 37's random_walk_drift seed 102: 0.0039 -> 0.0042 deg/h is 7.7% worse,
// z = 0.24 with 1-sigma 0.0003 deg/h each, not shown; the walk, 0.0094 -> 0.027 deg/h,
// is refused at any plausible sigma.
TEST(PointPredictionGuard, AWorseningWithinTheGapDriftsSamplingUncertaintyIsNotRefused) {
  EXPECT_FALSE(WorsensPointPrediction(HeldOutWithSigma(0.0039, 0.0003),
                                      HeldOutWithSigma(0.0042, 0.0003)));
  EXPECT_NEAR(
      GapDriftWorseningZ(HeldOutWithSigma(0.0039, 0.0003), HeldOutWithSigma(0.0042, 0.0003)),
      (0.0042 - 1.05 * 0.0039) / std::hypot(0.0003, 1.05 * 0.0003), 1e-12);
  EXPECT_TRUE(WorsensPointPrediction(HeldOutWithSigma(0.0094, 0.002),
                                     HeldOutWithSigma(0.027, 0.004)));
  // The same 7.7% with ten times smaller sigmas is shown (z = 2.4).
  EXPECT_TRUE(WorsensPointPrediction(HeldOutWithSigma(0.0039, 0.00003),
                                     HeldOutWithSigma(0.0042, 0.00003)));
  // About the threshold: z = 1.6 is not beyond it, z = 1.7 is.
  const double s = 0.001 / std::hypot(1.0, 1.05);
  EXPECT_FALSE(WorsensPointPrediction(HeldOutWithSigma(0.01, s),
                                      HeldOutWithSigma(0.0105 + 0.0016, s)));
  EXPECT_TRUE(WorsensPointPrediction(HeldOutWithSigma(0.01, s),
                                     HeldOutWithSigma(0.0105 + 0.0017, s)));
  EXPECT_THAT(PointPredictionNote("random_walk_drift", HeldOutWithSigma(0.0094, 0.002),
                                  HeldOutWithSigma(0.027, 0.004)),
              HasSubstr("1-sigma 0.0020 and 0.0040 from the held-out line fits"));
}

// Held-out spans of 3 h at 60 s whose attitude error grows along a fixed inertial line at
// `rate_deg_h` (per axis direction `axis_in`) under white noise of `noise_arcsec` per axis.
ModelRun HeldOutLines(const std::vector<TelemetryFrame>& frames, const std::vector<Gap>& gaps,
                      double rate_deg_h, double noise_arcsec, std::mt19937_64& rng) {
  std::normal_distribution<double> normal;
  const Eigen::Vector3d axis_in = Eigen::Vector3d(0.6, -0.5, 0.62).normalized();
  ModelRun run;
  for (size_t k = 0; k < gaps.size(); ++k) {
    for (int f = gaps[k].first; f <= gaps[k].last; ++f) {
      HeldOutSample s;
      s.frame = f;
      s.span = static_cast<int>(k);
      s.seconds = absl::ToDoubleSeconds(frames[f].time - frames[gaps[k].first].time);
      s.error_in = DegPerHourToRadPerSec(rate_deg_h) * s.seconds * axis_in;
      for (int i = 0; i < 3; ++i) s.error_in(i) += ArcsecToRad(noise_arcsec) * normal(rng);
      run.held_out.push_back(s);
    }
  }
  return run;
}

// The gap drift's 1-sigma (HeldOutResult::rate_rms_sigma_deg_h) is the scatter of the gap drift
// over recordings: two 3 h spans at 60 s, 5 arcsec white noise, a true 0.004 deg/h (the noise
// gives each axis' slope a 1-sigma of 5 arcsec / sqrt(181 x (3 h)^2 / 12) = 0.00012 deg/h, R one
// of about 0.00008 deg/h, so 5% of R is 2.4 sigma). Over 400 noise draws the standard deviation
// of R has a relative sampling error of 1/sqrt(800) = 3.5%, so the mean reported sigma must be
// within 12% of it (3.4 sigma). And the guard's size: a candidate that is exactly 5% worse, with
// noise of its own, is refused at most at about 5% (400 draws, binomial 1-sigma 1.1%: at most
// 9%), one that is not worse far less often.
TEST(PointPredictionGuard, TheGapDriftSigmaIsItsScatterAndTheGuardRefusesAtItsStatedLevel) {
  std::vector<TelemetryFrame> frames(600);
  const absl::Time t0 = absl::FromUnixSeconds(1551398400);  // 2019-03-01T00:00:00Z
  for (size_t i = 0; i < frames.size(); ++i) frames[i].time = t0 + absl::Seconds(60.0 * i);
  const std::vector<Gap> gaps = {{-1, 200, 380}, {-1, 420, 600 - 1}};
  const std::vector<RegimeSpan> spans;
  std::mt19937_64 rng(37);
  const int draws = 400;
  double sum = 0.0, sum2 = 0.0, sigma_sum = 0.0;
  int refused_equal = 0, refused_at_edge = 0, refused_at_edge_bare = 0;
  for (int d = 0; d < draws; ++d) {
    const HeldOutResult before =
        SummariseHeldOut(HeldOutLines(frames, gaps, 0.004, 5.0, rng), gaps, spans, frames);
    const HeldOutResult same =
        SummariseHeldOut(HeldOutLines(frames, gaps, 0.004, 5.0, rng), gaps, spans, frames);
    const HeldOutResult worse =
        SummariseHeldOut(HeldOutLines(frames, gaps, 1.05 * 0.004, 5.0, rng), gaps, spans, frames);
    sum += before.rate_rms_deg_h;
    sum2 += before.rate_rms_deg_h * before.rate_rms_deg_h;
    sigma_sum += before.rate_rms_sigma_deg_h;
    refused_equal += WorsensPointPrediction(before, same);
    refused_at_edge += WorsensPointPrediction(before, worse);
    refused_at_edge_bare += WorsensPointPrediction(HeldOut(before.rate_rms_deg_h, 0.0, 12),
                                                   HeldOut(worse.rate_rms_deg_h, 0.0, 12));
  }
  const double mean = sum / draws;
  const double scatter = std::sqrt(sum2 / draws - mean * mean);
  const double reported = sigma_sum / draws;
  EXPECT_NEAR(mean, 0.004, 3.0 * scatter / std::sqrt(draws));
  EXPECT_NEAR(reported / scatter, 1.0, 0.12) << "reported " << reported << ", scatter " << scatter;
  EXPECT_LE(refused_at_edge, 0.09 * draws);
  EXPECT_GE(refused_at_edge, 0.01 * draws);  // the test has power at its edge
  EXPECT_LE(refused_equal, refused_at_edge);
  // Without the sigmas (the bare 5% bound) about half the candidates at the edge are refused.
  EXPECT_GE(refused_at_edge_bare, 0.35 * draws);
}

// A run whose three gyros' normalised star-tracker differences follow u_k = phi u_(k-1) + e_k
// (unit variance), n steps.
ModelRun RunWithInnovations(double phi, int n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  ModelRun run;
  std::vector<Eigen::Vector2d> u(3, Eigen::Vector2d::Zero());
  const double scale = std::sqrt(1.0 - phi * phi);
  for (int k = 0; k < n; ++k) {
    StepRecord s;
    s.frame = k;
    s.star_tracker_present = s.nis_formed = s.accepted = true;
    for (int id = 1; id <= 3; ++id) {
      for (int i = 0; i < 2; ++i) u[id - 1](i) = phi * u[id - 1](i) + scale * normal(rng);
      GyroInnovation g;
      g.id = id;
      g.sigma = Eigen::Vector2d(ArcsecToRad(5.0), ArcsecToRad(5.0));
      g.z = g.sigma.cwiseProduct(u[id - 1]);
      s.innovations.push_back(g);
    }
    s.m = 6;
    run.steps.push_back(s);
  }
  return run;
}

// Box-Pierce at lag 1 over the six series: chi-square with 6 dof for white innovations; a lag-1
// autocorrelation of 0.2 over 1000 steps gives n r^2 = 40 per series.
TEST(ModelConsistency, WhitenessPassesWhiteInnovationsAndFailsCorrelatedOnes) {
  const double level = 1.0 - 0.01 / 3;
  int white_failed = 0;
  for (uint64_t seed = 1; seed <= 20; ++seed) {
    const ConsistencyTest t = WhitenessTest(RunWithInnovations(0.0, 1000, seed), level);
    EXPECT_EQ(t.dof, 6);
    EXPECT_NEAR(t.bound, ChiSquareQuantile(level, 6), 1e-9);
    white_failed += !t.passed;
  }
  EXPECT_LE(white_failed, 1);  // 20 draws at a size of 0.33%
  const ConsistencyTest red = WhitenessTest(RunWithInnovations(0.2, 1000, 7), level);
  EXPECT_FALSE(red.passed) << red.statistic;
  EXPECT_GT(red.statistic, 100.0);
}

// The held-out NEES of the k0-step case (62 -> 28 on 6 dof: the 0.99667 quantile is 19.7) fails;
// the shares explained are those of the excess over the chi-square expectation.
TEST(ModelConsistency, AHeldOutNeesAboveItsChiSquareBoundFailsAndTheSharesAreOfTheExcess) {
  const ModelRun run = RunWithInnovations(0.0, 500, 3);
  ProfiledDeviance before, after;
  before.components = after.components = 3000;
  before.dispersion = 1.5;   // NIS excess 1500
  after.dispersion = 1.0;    // none: NIS 3000 within its bound
  const ModelConsistency c =
      CheckConsistency(run, before, after, HeldOut(0.01, 62.0, 6), HeldOut(0.006, 28.0, 6), 0.01);
  ASSERT_EQ(c.tests.size(), 3u);
  EXPECT_EQ(c.tests[0].name, "held-out NEES");
  EXPECT_FALSE(c.tests[0].passed);
  EXPECT_NEAR(c.tests[0].bound, ChiSquareQuantile(1.0 - 0.01 / 3, 6), 1e-9);
  EXPECT_EQ(c.tests[1].name, "in-sample NIS");
  EXPECT_TRUE(c.tests[1].passed);
  // Material: beyond kMaterialDispersion per component and its chi-square bound.
  ProfiledDeviance noisy = after;
  noisy.dispersion = 1.2;
  EXPECT_TRUE(CheckConsistency(run, before, noisy, HeldOut(0.01, 62.0, 6), HeldOut(0.006, 5.0, 6),
                               0.01).passed);
  noisy.dispersion = 1.6;
  EXPECT_FALSE(CheckConsistency(run, before, noisy, HeldOut(0.01, 62.0, 6),
                                HeldOut(0.006, 5.0, 6), 0.01).passed);
  EXPECT_FALSE(c.passed);
  EXPECT_NEAR(c.held_out_explained, 1.0 - (28.0 - 6.0) / (62.0 - 6.0), 1e-12);
  EXPECT_NEAR(c.in_sample_explained, 1.0, 1e-12);
  // What remains is located at the held-out span that misses most.
  HeldOutResult held = HeldOut(0.006, 28.0, 6);
  GapSummary quiet, missed;
  quiet.dof = missed.dof = 6;
  quiet.nees = 3.0;
  missed.nees = 25.0;
  missed.regime = "inertial";
  missed.gyro_drift_rate_deg_h = {{1, 0.001}, {2, 0.02}, {3, 0.003}};
  held.gaps = {quiet, missed};
  const Unexplained rest = RemainingAfterFindings(c, held, Mismatch{});
  EXPECT_EQ(rest.finding.effect, kVerdictUnexplained);
  EXPECT_EQ(rest.finding.gyro, 2);
  EXPECT_EQ(rest.where.regime, "inertial");
  EXPECT_THAT(rest.finding.explanation, HasSubstr("held-out NEES 28.0 on 6 dof"));
}

// `esg model apply` of a partly explained diagnosis applies the findings that map and lists the
// unexplained rest as not applied, saying what it is.
TEST(ApplyPartlyExplained, TheFindingsAreAppliedAndTheRestIsListedAsNotApplied) {
  const SpacecraftConfig config = ::esg::testing::DiscoveryConfig();
  DiagnosisReport report;
  report.verdict = kVerdictPartlyExplained;
  Finding latency;
  latency.effect = "star_tracker_latency";
  latency.parameters.push_back({"latencyMs", 250.0, 5.0, "ms"});
  Finding rest;
  rest.effect = kVerdictUnexplained;
  rest.gyro = 2;
  report.findings = {latency, rest};
  const AppliedFindings applied = WithFindings(config, report);
  ASSERT_EQ(applied.applied.size(), 1u);
  EXPECT_THAT(applied.applied.front(), HasSubstr("starTracker.latencyS = 0.25"));
  EXPECT_NEAR(applied.config.star_tracker.latency, 0.25, 1e-12);
  ASSERT_EQ(applied.not_applied.size(), 1u);
  EXPECT_THAT(applied.not_applied.front(),
              HasSubstr("unexplained (gyro 2): what the other findings leave unexplained (verdict "
                        "partly_explained)"));
}

// The star tracker's mount misalignment cycling with the orbit, 30 arcsec about a tilted body
// axis, common to all gyros, diagnosed without the effect that describes it
// (star_tracker_orbital_misalignment left out of the effects tried): physics outside what is
// tried. A raised random walk absorbs part of it by widening its own covariance; whatever the
// diagnosis takes, no finding makes the held-out gap drift worse by more than 5%, and a random
// walk is named only when it does not.
TEST(DiagnoseVerdict, AMountMisalignmentCyclingWithTheOrbitGetsNoFindingThatWorsensTheGapDrift) {
  const uint64_t seed = 101;
  SimulationSpec spec = ::esg::testing::DiscoveryScenario("none", seed, 30.0);
  auto sim = Simulate(spec);
  ASSERT_TRUE(sim.ok()) << sim.status();
  const double period_s = spec.profile->OrbitalPeriod().value_or(5400.0);
  const Eigen::Vector3d axis_b = Eigen::Vector3d(0.6, -0.5, 0.62).normalized();
  std::vector<TelemetryFrame> frames = sim->recording.frames;
  const absl::Time t0 = frames.front().time;
  for (TelemetryFrame& f : frames) {
    if (!f.star_tracker.has_value()) continue;
    const double t_s = absl::ToDoubleSeconds(f.time - t0);
    const double angle_rad = ArcsecToRad(30.0) * std::sin(2.0 * kPi * t_s / period_s + 0.4);
    f.star_tracker->q_in_b = (f.star_tracker->q_in_b * ExpQuaternion(angle_rad * axis_b)).normalized();
  }
  DiagnoseOptions options;
  for (int e = 0; e < static_cast<int>(Effect::kStarTrackerCycle); ++e) {
    options.effects.push_back(static_cast<Effect>(e));
  }
  auto report = Diagnose(spec.config, frames, options);
  ASSERT_TRUE(report.ok()) << report.status();
  const DiagnosisReport& r = *report;
  std::string text = absl::StrCat("verdict ", r.verdict, "; gap drift ",
                                  r.before.gap_drift_rate_deg_h, " -> ",
                                  r.after.gap_drift_rate_deg_h, "; NEES ", r.before.held_out_nees,
                                  " -> ", r.after.held_out_nees, " on ", r.after.held_out_dof);
  int model_findings = 0;
  for (const Finding& f : r.findings) {
    absl::StrAppend(&text, "\n", f.effect, "[", f.gyro, "]: ", f.explanation);
    for (const std::string& n : f.evidence.notes) absl::StrAppend(&text, "\n  ", n);
    model_findings += f.effect != kVerdictUnexplained;
  }
  absl::StrAppend(&text, "\n", r.consistency.summary);
  ASSERT_GT(r.before.gap_drift_rate_deg_h, 0.0) << text;
  EXPECT_LE(r.after.gap_drift_rate_deg_h,
            std::pow(1.0 + kMaxGapDriftWorsening, model_findings) * r.before.gap_drift_rate_deg_h)
      << text;
  // The raised walk of all gyros, which a held-out predictive density alone would take (NEES
  // 86.9 -> 10.9 on this seed), makes the gap drift four times worse: refused by the guard, and
  // named nowhere as a finding.
  // The refusal is said in a finding's notes or, when nothing was taken, in the unexplained
  // finding's explanation.
  const std::string refusal =
      "random_walk_drift is not taken: it makes the held-out point prediction worse";
  bool refused = false;
  for (const Finding& f : r.findings) {
    EXPECT_NE(f.effect, "random_walk_drift") << text;
    refused |= f.explanation.find(refusal) != std::string::npos;
    for (const std::string& n : f.evidence.notes) refused |= n.find(refusal) != std::string::npos;
  }
  EXPECT_TRUE(refused) << text;
  // The model with what was taken still fails its held-out NEES bound: partly explained when
  // something was taken, unexplained when nothing was; the rest located either way.
  EXPECT_EQ(r.verdict, model_findings > 0 ? kVerdictPartlyExplained : kVerdictUnexplained) << text;
  ASSERT_FALSE(r.findings.empty());
  EXPECT_EQ(r.findings.back().effect, kVerdictUnexplained) << text;
  if (model_findings > 0) {
    // The consistency tests run on a model with findings.
    ASSERT_TRUE(r.consistency.checked) << text;
    EXPECT_FALSE(r.consistency.passed) << text;
    EXPECT_THAT(r.consistency.summary, HasSubstr("what remains is unexplained")) << text;
  }
}

// The same mount, now with the effect that describes it tried (docs/discovery.md, "The star
// tracker's side"): the mismatch common to all gyros is the star tracker's. The first finding is
// star_tracker_orbital_misalignment, located to no gyro, each of its six coefficients within 3
// sigma of the truth; no gyro is named unexplained for it, no random walk is raised, and the
// held-out gap drift does not get worse.
TEST(DiagnoseVerdict, AMountTurningWithTheOrbitIsFoundAsTheStarTrackersWithItsAmplitudes) {
  const uint64_t seed = 101;
  const SimulationSpec spec = ::esg::testing::DiscoveryScenario("star_tracker_cycle", seed, 30.0);
  auto sim = Simulate(spec);
  ASSERT_TRUE(sim.ok()) << sim.status();
  auto report = Diagnose(spec.config, sim->recording.frames, DiagnoseOptions{});
  ASSERT_TRUE(report.ok()) << report.status();
  const DiagnosisReport& r = *report;
  std::string text = absl::StrCat("verdict ", r.verdict, "; gap drift ",
                                  r.before.gap_drift_rate_deg_h, " -> ",
                                  r.after.gap_drift_rate_deg_h);
  for (const Finding& f : r.findings) {
    absl::StrAppend(&text, "\n", f.effect, "[", f.gyro, "]: ", f.explanation);
  }
  for (const CandidateScore& c : r.candidates) {
    absl::StrAppend(&text, "\n  round ", c.round, " ", c.effect, "[", c.gyro, "] 2 ln B ", c.score,
                    " dD ", c.delta_deviance, " pen ", c.penalty, c.selected ? " selected" : "",
                    c.homogeneous ? "" : " inhomogeneous", " ", c.not_fitted);
  }
  ASSERT_FALSE(r.findings.empty()) << text;
  EXPECT_TRUE(::esg::testing::DiscoveryVerdictCorrect(
      "star_tracker_cycle", ::esg::testing::AffectedGyro(seed), r, seed))
      << text;
  const Parameter* amplitude = FindParameter(r.findings.front().parameters, "cycleAmplitudeArcsec");
  ASSERT_NE(amplitude, nullptr) << text;
  EXPECT_LE(std::abs(amplitude->value - ::esg::testing::kStarTrackerCycleArcsec),
            3.0 * amplitude->sigma)
      << text;
  EXPECT_THAT(r.findings.front().explanation,
              HasSubstr("the star tracker's mount turns with the orbit"));
  for (const Finding& f : r.findings) {
    EXPECT_NE(f.effect, "random_walk_drift") << text;
    EXPECT_NE(f.effect, kVerdictUnexplained) << text;
  }
  EXPECT_LE(r.after.gap_drift_rate_deg_h, r.before.gap_drift_rate_deg_h) << text;
}

// A step must carry its gain (docs/discovery.md): on this effect-free recording with its orbit
// (the false-alarm bench's seed 1141, ESG_FALSE_ALARM_ORBIT=1), releasing gyro 1's k0 at the
// end of a star-tracker outage (5.85 h) lowered -2 log L by 42.6 with a step of -0.0067 +-
// 0.0077 deg/h: the released variance widened a covariance too small there, no coefficient
// changed: held from the onset without the release, the step found improves -2 log L by less
// than its chi-square bound. The search's result is refused (the row says why) and the verdict
// is `none`.
TEST(DiagnoseVerdict, AStepThatDoesNotCarryItsGainIsNotFittedWhateverTheReleaseGains) {
  const uint64_t seed = 1141;
  const SimulationSpec spec = ::esg::testing::DiscoveryScenario("none", seed, 30.0);
  auto sim = Simulate(spec);
  ASSERT_TRUE(sim.ok()) << sim.status();
  DiagnoseOptions options;
  auto orbit = ::esg::testing::ScenarioOrbit(spec, seed);
  ASSERT_TRUE(orbit.ok()) << orbit.status();
  options.orbit = *orbit;
  auto report = Diagnose(spec.config, sim->recording.frames, options);
  ASSERT_TRUE(report.ok()) << report.status();
  std::string findings;
  for (const Finding& f : report->findings) findings += "\n" + f.effect + ": " + f.explanation;
  SCOPED_TRACE(findings);
  EXPECT_EQ(report->verdict, kVerdictNone);
  bool refused = false;
  for (const CandidateScore& c : report->candidates) {
    if (c.effect != "coefficient_step" || c.gyro != 1 || c.not_fitted.empty()) continue;
    refused = true;
    RecordProperty("not_fitted", c.not_fitted);
    EXPECT_EQ(c.parameters, 0);
    EXPECT_FALSE(c.significant);
    EXPECT_THAT(c.not_fitted, HasSubstr("a step of k0 not fitted"));
    EXPECT_THAT(c.not_fitted, HasSubstr("with the step found held from it"));
  }
  EXPECT_TRUE(refused) << "gyro 1's coefficient step was not refused by the held-step run";
}

// Housekeeping channels that drive nothing (the scenario none_with_channels: the three gyros'
// temperatures wandering by 2 K and gyro 1's heater state, declared and telemetered, no effect):
// each channel is tried as a cause of each running gyro's drift, and none is taken.
TEST(DiagnoseVerdict, HousekeepingChannelsThatDriveNothingAreTriedAndNoneIsTaken) {
  const SimulationSpec spec = ::esg::testing::DiscoveryScenario("none_with_channels", 1001, 30.0);
  ASSERT_EQ(spec.config.channels.size(), 4u);
  auto sim = Simulate(spec);
  ASSERT_TRUE(sim.ok()) << sim.status();
  auto report = Diagnose(spec.config, sim->recording.frames, DiagnoseOptions{});
  ASSERT_TRUE(report.ok()) << report.status();
  const DiagnosisReport& r = *report;
  int channel_candidates = 0;
  std::string text = absl::StrCat("verdict ", r.verdict);
  for (const CandidateScore& c : r.candidates) {
    if (c.effect.rfind("channel_drift", 0) != 0) continue;
    ++channel_candidates;
    absl::StrAppend(&text, "\n", c.effect, "[", c.gyro, "] 2lnB ", c.score,
                    c.significant ? " significant" : "");
  }
  for (const Finding& f : r.findings) absl::StrAppend(&text, "\n", f.effect, "[", f.gyro, "]");
  // Three running gyros, four channels each.
  EXPECT_GE(channel_candidates, 12) << text;
  EXPECT_EQ(r.verdict, kVerdictNone) << text;
}

}  // namespace
}  // namespace esg::estimator::discovery
