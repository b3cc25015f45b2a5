// The open-ended stage (estimator/discovery/open_ended.h, basis_stage.h; docs/discovery.md "The
// open-ended stage"): the closed-form evidence of the whitened regression against the direct
// Gaussian marginal likelihood; nothing selected on an effect-free recording; and on simulated
// recordings of physics outside the library (tests/testing/discovery_scenarios.h) the diagnosis
// names it with the right gyro and time behaviour and its fitted size against the truth.
#include <array>
#include <cmath>
#include <random>
#include <utility>

#include "Eigen/Cholesky"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/discovery/deviation.h"
#include "estimator/discovery/deviation_filter.h"
#include "estimator/discovery/diagnose.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/open_ended.h"
#include "estimator/discovery/regimes.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/discovery_scenarios.h"

namespace esg::estimator::discovery {
namespace {

using ::testing::Contains;
using ::testing::HasSubstr;

// Recording length [h], as the other diagnosis tests.
constexpr double kHours = 24.0;

// -2 ln N(y; 0, phi I + X D^2 X^T) computed directly (Cholesky of the full covariance).
double DirectDeviance(const Eigen::VectorXd& y, const Eigen::MatrixXd& X,
                      const Eigen::VectorXd& prior_sigma, double phi) {
  const int m = static_cast<int>(y.size());
  const Eigen::MatrixXd C = phi * Eigen::MatrixXd::Identity(m, m) +
                            X * prior_sigma.cwiseAbs2().asDiagonal() * X.transpose();
  const Eigen::LLT<Eigen::MatrixXd> llt(C);
  const Eigen::MatrixXd L = llt.matrixL();
  double log_det = 0.0;
  for (int i = 0; i < m; ++i) log_det += 2.0 * std::log(L(i, i));
  return log_det + y.dot(llt.solve(y));
}

TEST(OpenEndedRegression, ClosedFormEqualsTheDirectMarginalLikelihoodAtItsDispersion) {
  std::mt19937_64 rng(11);
  std::normal_distribution<double> unit(0.0, 1.0);
  const int m = 60;
  Eigen::MatrixXd X(m, 2);
  Eigen::VectorXd y(m);
  for (int i = 0; i < m; ++i) {
    X(i, 0) = std::sin(0.1 * i);
    X(i, 1) = 0.01 * i;
    y(i) = 0.7 * X(i, 0) - 0.3 * X(i, 1) + 0.2 * unit(rng);
  }
  const Eigen::VectorXd col0 = X.col(0), col1 = X.col(1);
  const Eigen::VectorXd prior = Eigen::Vector2d(1.0, 2.0);
  const RegressionFit fit = FitRegression(y, {&col0, &col1}, prior);
  EXPECT_NEAR(fit.deviance, DirectDeviance(y, X, prior, fit.dispersion), 1e-8);
  // The dispersion is the profile's minimum: moving it either way costs.
  EXPECT_GT(DirectDeviance(y, X, prior, 1.1 * fit.dispersion), fit.deviance);
  EXPECT_GT(DirectDeviance(y, X, prior, 0.9 * fit.dispersion), fit.deviance);
  // The posterior mean is near the truth; no regressor: phi = y'y / m.
  EXPECT_NEAR(fit.mean(0), 0.7, 5.0 * fit.sigma(0));
  EXPECT_NEAR(fit.mean(1), -0.3, 5.0 * fit.sigma(1));
  const RegressionFit none = FitRegression(y, {}, Eigen::VectorXd());
  EXPECT_NEAR(none.dispersion, y.squaredNorm() / m, 1e-12);
  EXPECT_NEAR(none.deviance, DirectDeviance(y, Eigen::MatrixXd::Zero(m, 0), Eigen::VectorXd(),
                                            none.dispersion),
              1e-8);
}

// The coefficients the model leaves free (model (1): k0 of each gyro, prior 0.3 deg/h) are one
// nuisance group of each gyro's basis, in every model: a column per coefficient, its regressor
// the coefficient's column of eq. (1) along the measured trajectory, its prior the configured
// 1-sigma; a coefficient the model holds (sigma 0) has none.
TEST(OpenEnded, TheModelsFreeCoefficientsAreANuisanceGroupWithTheirConfiguredPriors) {
  auto m = ::esg::testing::MeasureUserModelDeviations("none", 101, 6.0, {1});
  ASSERT_TRUE(m.ok()) << m.status();
  SpacecraftConfig config = m->config;
  config.gyros[0].model_sigma.C1 = Eigen::Vector3d(0.0, DegPerHourToRadPerSec(0.1), 0.0);
  OpenEndedOptions o;
  o.free_coefficients = FreeCoefficientsOf(config);
  ASSERT_EQ(o.free_coefficients.size(), 5u);  // k0 of the four gyros, C12 of gyro 1
  const DeviationSeries& series = m->series.front();
  const GyroBasis basis = EnumerateBasis(series, o);
  const BasisGroup* group = nullptr;
  for (const BasisGroup& g : basis.groups) {
    if (g.label == "the model's free coefficients") group = &g;
  }
  ASSERT_NE(group, nullptr);
  EXPECT_TRUE(group->nuisance);
  ASSERT_EQ(group->columns.size(), 2u);
  const BasisColumn& k0 = basis.columns[group->columns[0]];
  const BasisColumn& c12 = basis.columns[group->columns[1]];
  EXPECT_TRUE(k0.nuisance);
  EXPECT_EQ(k0.theta, kThetaK0);
  EXPECT_EQ(k0.prior_sigma, DegPerHourToRadPerSec(0.3));
  EXPECT_EQ(c12.theta, kThetaC1 + 1);
  EXPECT_EQ(c12.prior_sigma, DegPerHourToRadPerSec(0.1));
  // Its signature is the coefficient's drift integrated along the measured trajectory.
  const std::vector<Eigen::Vector2d> x = ColumnSignature(series, k0);
  const std::vector<Eigen::Vector2d> expected = Signature(series, [](const BasisInputs& in) {
    return Eigen::Vector3d(DriftRegressor(in.h_k).col(kThetaK0));
  });
  ASSERT_EQ(x.size(), expected.size());
  for (size_t k = 0; k < x.size(); ++k) EXPECT_EQ(x[k], expected[k]) << k;
  EXPECT_GT(expected.back().norm(), 0.0);
  // Without free coefficients, no such group.
  for (const BasisGroup& g : EnumerateBasis(series, OpenEndedOptions{}).groups) {
    EXPECT_NE(g.label, "the model's free coefficients");
  }
}

// The stage alone on the user's model of an effect-free recording: no group reaches the
// threshold 2 ln(M / alpha).
TEST(OpenEnded, EffectFreeRecordingSelectsNothing) {
  auto m = ::esg::testing::MeasureUserModelDeviations("none", 101, kHours, {1, 2, 3});
  ASSERT_TRUE(m.ok()) << m.status();
  OpenEndedOptions o;
  o.orbital_period_s = 5640.0;
  o.epoch = m->frames.front().time;
  o.free_coefficients = FreeCoefficientsOf(m->config);
  const std::vector<double> rw(3, m->config.random_walk), w0(3, DegPerHourToRadPerSec(0.01));
  const OpenEndedResult r = RunOpenEnded(m->series, rw, w0, o);
  EXPECT_TRUE(r.selected.empty());
  EXPECT_GT(r.groups_tested, 100);
  EXPECT_LT(r.best_evidence, r.best_threshold);
  ASSERT_EQ(r.residual_drift.size(), 3u);
}

const Parameter* FindParameter(const Finding& f, const std::string& name) {
  for (const Parameter& p : f.parameters) {
    if (p.name == name) return &p;
  }
  return nullptr;
}

// A diagnosis of a discovery scenario (tests/testing/discovery_scenarios.h) at kHours.
struct ScenarioDiagnosis {
  SimulationSpec spec;
  DiagnosisReport report;
};
absl::StatusOr<ScenarioDiagnosis> DiagnoseScenario(const std::string& effect, uint64_t seed,
                                                   double hours = kHours,
                                                   const DiagnoseOptions& options = {}) {
  ScenarioDiagnosis out;
  out.spec = ::esg::testing::DiscoveryScenario(effect, seed, hours);
  auto sim = Simulate(out.spec);
  if (!sim.ok()) return sim.status();
  auto report = Diagnose(out.spec.config, sim->recording.frames, options);
  if (!report.ok()) return report.status();
  out.report = std::move(*report);
  return out;
}

// A case-fixed drift cycling with the orbit (0.049 deg/h along (0.61, -0.61, 0.51)), which the
// library's random walk of that gyro absorbs in part: named as the orbital harmonic of the right
// gyro, with its amplitude and direction.
// `refused`: a note the finding must carry (a library effect refused by its physics check).
void ExpectOrbitalDriftNamed(uint64_t seed, double hours, const std::string& refused = "",
                             const DiagnoseOptions& options = {}) {
  auto d = DiagnoseScenario("orbital_drift", seed, hours, options);
  ASSERT_TRUE(d.ok()) << d.status();
  const SimulationSpec& spec = d->spec;
  const DiagnosisReport* r = &d->report;
  const int gyro = ::esg::testing::AffectedGyro(seed);
  ASSERT_EQ(r->verdict, kEffectBasisTerm);
  const Finding& f = r->findings.front();
  EXPECT_EQ(f.gyro, gyro);
  EXPECT_EQ(f.time.kind, "orbital_cycle");
  EXPECT_TRUE(::esg::testing::DiscoveryVerdictCorrect("orbital_drift", gyro, *r));
  // Truth: A cos(2 pi t / P + phase); the fit C cos + S sin (deg/h per case axis).
  const Eigen::Vector3d A = spec.gyros[gyro - 1].orbital_drift->amplitude_k_rad_s;
  Eigen::Vector3d C = Eigen::Vector3d::Zero(), S = Eigen::Vector3d::Zero();
  for (int m = 0; m < 3; ++m) {
    const char axis = "xyz"[m];
    const Parameter* c = FindParameter(f, absl::StrCat("basis[orbit cos 1 -> ", std::string(1, axis), "]"));
    const Parameter* s = FindParameter(f, absl::StrCat("basis[orbit sin 1 -> ", std::string(1, axis), "]"));
    ASSERT_NE(c, nullptr) << f.explanation;
    ASSERT_NE(s, nullptr) << f.explanation;
    C(m) = c->value;
    S(m) = s->value;
  }
  const double amplitude_deg_h = std::sqrt(C.squaredNorm() + S.squaredNorm());
  EXPECT_NEAR(amplitude_deg_h, RadPerSecToDegPerHour(A.norm()), 0.1 * RadPerSecToDegPerHour(A.norm()));
  // Both phases lie along the truth's direction.
  const Eigen::Vector3d dir = A.normalized();
  const Eigen::Vector3d fitted = (C.norm() > S.norm() ? C : S).normalized();
  EXPECT_GT(std::abs(fitted.dot(dir)), std::cos(DegToRad(10.0))) << f.explanation;
  EXPECT_THAT(f.explanation, HasSubstr("varying with the orbital phase"));
  EXPECT_FALSE(f.basis_terms.empty());
  EXPECT_FALSE(r->residual_drift.empty());
  // The configuration with the terms found is valid and frees them for esg calibrate.
  const SpacecraftConfig with = WithBasisFindings(spec.config, *r);
  EXPECT_TRUE(ValidateConfig(with).ok()) << ValidateConfig(with);
  EXPECT_EQ(with.FindGyro(gyro)->basis_terms.size(), f.basis_terms.size());
  for (const BasisTerm& t : with.FindGyro(gyro)->basis_terms) EXPECT_GT(t.sigma, 0.0);
  if (!refused.empty()) {
    EXPECT_THAT(f.evidence.notes, Contains(HasSubstr(refused))) << f.explanation;
  }
}

TEST(OpenEndedDiagnosis, OrbitalDriftIsNamedWithItsAmplitudeAndDirection) {
  ExpectOrbitalDriftNamed(101, kHours);
}

// Seed 102 at 30 h: unequal stiffness of the gyro fits part of the orbital drift and topped the
// first round (the verdict before the physics checks); a drift that returns to its mean describes
// the gyro's deviation decisively better, the effect adds nothing on top of it, and the open-ended
// stage names the orbital harmonic instead. The library's constant effects and the basis only:
// with every candidate, the turning displacement's twelve terms (which fit part of any drift of
// the gyro that changes in time) top that round instead, add nothing significant on top of the
// raised random walk, and the harmonic is named the same (the test below).
TEST(OpenEndedDiagnosis, UnequalStiffnessFittingPartOfAnOrbitalDriftGivesWayToTheHarmonic) {
  DiagnoseOptions options;
  for (int e = 0; e <= static_cast<int>(kLastEffect); ++e) {
    if (static_cast<Effect>(e) != Effect::kTurningDisplacement) {
      options.effects.push_back(static_cast<Effect>(e));
    }
  }
  ExpectOrbitalDriftNamed(102, 30.0, "unequal_stiffness[1] fits part of gyro 1's drift", options);
}

TEST(OpenEndedDiagnosis, ATurningDisplacementFittingPartOfAnOrbitalDriftGivesWayToTheHarmonic) {
  ExpectOrbitalDriftNamed(102, 30.0);
}

// A drift cycling with a 94 min orbit on a spacecraft flying the paper's calibration profile (a
// 60 min rotation, no orbital orientation): the recording alone gives no orbital period, so the
// basis has no orbital-phase terms and the cycle is not named; with the period the user knows
// (--orbital-period), it is named as the orbital harmonic of the right gyro.
TEST(OpenEndedDiagnosis, AnOrbitalCycleOutsideOrbitalOrientationIsNamedWithTheGivenPeriod) {
  const uint64_t seed = 101;
  const double period_s = 94.0 * 60.0;
  SimulationSpec spec = ::esg::testing::DiscoveryScenario("orbital_drift", seed, kHours);
  auto profile = MakeNamedProfile("calibration", spec.duration, seed);
  ASSERT_TRUE(profile.ok()) << profile.status();
  spec.profile = std::move(*profile);
  const int gyro = ::esg::testing::AffectedGyro(seed);
  spec.gyros[gyro - 1].orbital_drift->period_s = period_s;
  auto sim = Simulate(spec);
  ASSERT_TRUE(sim.ok()) << sim.status();
  auto orbital_cycle_named = [&](const DiagnosisReport& r) {
    for (const Finding& f : r.findings) {
      if (f.effect == kEffectBasisTerm && f.time.kind == "orbital_cycle") return true;
    }
    return false;
  };

  auto without = Diagnose(spec.config, sim->recording.frames, DiagnoseOptions{});
  ASSERT_TRUE(without.ok()) << without.status();
  EXPECT_FALSE(orbital_cycle_named(*without)) << without->verdict;

  DiagnoseOptions options;
  options.orbital_period_s = period_s;
  auto with = Diagnose(spec.config, sim->recording.frames, options);
  ASSERT_TRUE(with.ok()) << with.status();
  ASSERT_EQ(with->verdict, kEffectBasisTerm);
  const Finding& f = with->findings.front();
  EXPECT_EQ(f.gyro, gyro);
  EXPECT_EQ(f.time.kind, "orbital_cycle");
  EXPECT_THAT(f.explanation, HasSubstr("(period 94.0 min"));
  ASSERT_FALSE(f.basis_terms.empty());
  EXPECT_EQ(f.basis_terms.front().period, period_s);

  options.orbital_period_s = -1.0;
  EXPECT_EQ(Diagnose(spec.config, sim->recording.frames, options).status().code(),
            absl::StatusCode::kInvalidArgument);
}

// A rotor displacement growing from 0 to 1.4 um: named as a growing displacement with its rate
// and direction (through the suspension voltages' trend, eq. (3)), the drift following it.
TEST(OpenEndedDiagnosis, GrowingRotorDisplacementIsNamedWithItsRate) {
  const uint64_t seed = 101;
  auto d = DiagnoseScenario("growing_displacement", seed);
  ASSERT_TRUE(d.ok()) << d.status();
  const SimulationSpec& spec = d->spec;
  const DiagnosisReport* r = &d->report;
  const int gyro = ::esg::testing::AffectedGyro(seed);
  ASSERT_EQ(r->verdict, kEffectBasisTerm);
  const Finding& f = r->findings.front();
  EXPECT_EQ(f.gyro, gyro);
  EXPECT_EQ(f.time.kind, "linear");
  EXPECT_THAT(f.explanation, HasSubstr("rotor displacement growing at"));
  const Eigen::Vector3d rate_um_h =
      spec.gyros[gyro - 1].rotor_displacement_rate_k_m_s * 3600.0 / kMetresPerUm;
  Eigen::Vector3d fitted = Eigen::Vector3d::Zero();
  for (int i = 0; i < 3; ++i) {
    const Parameter* p = FindParameter(f, absl::StrCat("displacementRateUmPerH[", i, "]"));
    ASSERT_NE(p, nullptr) << f.explanation;
    fitted(i) = p->value;
  }
  EXPECT_NEAR(fitted.norm(), rate_um_h.norm(), 0.1 * rate_um_h.norm());
  EXPECT_GT(fitted.normalized().dot(rate_um_h.normalized()), std::cos(DegToRad(5.0)));
  EXPECT_FALSE(f.displacement_trend.samples.empty());
}

// A symmetric distortion of one gyro's direction-cosine readout (up to 300 ppm), which the
// library's unequal stiffness, misalignment and random walk absorbed in part when it was left to
// the end: the basis's readout group competes in the first round and is the one finding, its
// traceless part within 3 sigma of the truth's (a common scale factor is not observable), and
// the model with it is a valid configuration that corrects the readings.
TEST(OpenEndedDiagnosis, ReadoutDistortionIsTheOneFindingWithItsTracelessPart) {
  const uint64_t seed = 102;
  auto d = DiagnoseScenario("readout_scale", seed);
  ASSERT_TRUE(d.ok()) << d.status();
  const DiagnosisReport& r = d->report;
  const int gyro = ::esg::testing::AffectedGyro(seed);
  ASSERT_EQ(r.findings.size(), 1u) << r.findings.back().explanation;
  const Finding& f = r.findings.front();
  EXPECT_EQ(f.effect, kEffectBasisTerm);
  EXPECT_EQ(f.gyro, gyro);
  EXPECT_EQ(f.time.kind, "constant");
  EXPECT_THAT(f.explanation, HasSubstr("readout distortion of the direction cosines"));
  EXPECT_TRUE(::esg::testing::DiscoveryVerdictCorrect("readout_scale", gyro, r));
  const Eigen::Matrix3d D = d->spec.gyros[gyro - 1].readout_distortion_k;
  const Eigen::Matrix3d truth = D - D.trace() / 3.0 * Eigen::Matrix3d::Identity();
  static constexpr std::array<std::pair<int, int>, 6> kEntries = {
      {{0, 0}, {1, 1}, {2, 2}, {0, 1}, {1, 2}, {2, 0}}};
  for (const auto& [i, j] : kEntries) {
    const Parameter* p = FindParameter(
        f, absl::StrCat("basis[readout E_", std::string(1, "xyz"[i]), std::string(1, "xyz"[j]), "]"));
    ASSERT_NE(p, nullptr) << f.explanation;
    EXPECT_EQ(p->unit, "ppm");
    EXPECT_GT(p->sigma, 0.0);
    EXPECT_NEAR(p->value, truth(i, j) * 1e6, 3.0 * p->sigma) << "E(" << i << ", " << j << ")";
  }
  EXPECT_NEAR(f.readout_distortion.trace(), 0.0, 1e-12);
  const SpacecraftConfig with = WithBasisFindings(d->spec.config, r);
  EXPECT_TRUE(ValidateConfig(with).ok()) << ValidateConfig(with);
  EXPECT_TRUE(with.FindGyro(gyro)->readout_distortion.isApprox(f.readout_distortion));
}

// Drifts the basis cannot explain, which must stay `unexplained` and located: one switching at
// random between two levels (mean dwell 4 h), one driven by a quantity the telemetry does not
// carry (a Gauss-Markov process of 3 h correlation time). Neither is one step nor a random walk:
// a drift that returns to its mean describes each gyro's deviation decisively better (wander.h),
// so the library's time behaviour is not taken, and the basis's deterministic terms do not
// describe it as well either. On the confusion matrix's 30 h recordings (docs/discovery.md); at
// 24 h, seed 101 of the switching drift, a constant misalignment of the gyro is taken first
// (docs/discovery.md, "Limits").
void ExpectUnexplainedWanderingDrift(const std::string& effect, uint64_t seed,
                                     const std::string& refused = "") {
  auto d = DiagnoseScenario(effect, seed, 30.0);
  ASSERT_TRUE(d.ok()) << d.status();
  const DiagnosisReport& r = d->report;
  const int gyro = ::esg::testing::AffectedGyro(seed);
  std::string findings;
  for (const Finding& f : r.findings) {
    absl::StrAppend(&findings, "\n", f.effect, "[", f.gyro, "]: ", f.explanation);
    for (const std::string& n : f.evidence.notes) absl::StrAppend(&findings, "\n  ", n);
  }
  ASSERT_EQ(r.verdict, kVerdictUnexplained) << findings;
  ASSERT_EQ(r.findings.size(), 1u);
  const Finding& u = r.findings.front();
  EXPECT_EQ(u.gyro, gyro);
  EXPECT_TRUE(r.mismatch.found);
  EXPECT_EQ(r.mismatch.gyro, gyro);
  EXPECT_THAT(u.explanation, HasSubstr(absl::StrCat("the drift of gyro ", gyro,
                                                    " returns to its mean")));
  if (!refused.empty()) EXPECT_THAT(u.explanation, HasSubstr(refused)) << findings;
  EXPECT_TRUE(::esg::testing::DiscoveryVerdictCorrect(effect, gyro, r));
}

TEST(OpenEndedDiagnosis, DriftSwitchingAtRandomStaysUnexplainedInItsGyro) {
  ExpectUnexplainedWanderingDrift("switching_drift", 101);
}

// The physics check that decides (docs/discovery.md): a constant effect of the library that fits
// part of a wandering drift is refused. Seed 105 at 30 h: a rotor displacement, then a
// misalignment of the gyro (the verdict before the check), each described decisively better by a
// drift that returns to its mean and adding nothing significant on top of it.
TEST(OpenEndedDiagnosis, ConstantEffectsFittingPartOfASwitchingDriftAreNotTaken) {
  ExpectUnexplainedWanderingDrift("switching_drift", 105, "not taken as a constant effect");
}

// The suspension voltages decide (eq. (3), docs/discovery.md "Physics checks that decide"): on
// seed 108 a rotor displacement of the gyro (the verdict before the check) has |C1| implying about
// 0.5 um while the gyro's offset voltages show none.
TEST(OpenEndedDiagnosis, ARotorDisplacementTheSuspensionVoltagesDoNotShowIsNotTaken) {
  ExpectUnexplainedWanderingDrift("switching_drift", 108, "the rotor is not displaced that far");
}

TEST(OpenEndedDiagnosis, DriftOfAnUntelemeteredDriverStaysUnexplainedInItsGyro) {
  ExpectUnexplainedWanderingDrift("hidden_driver", 102);
}

// A drift that returns to its mean does not hide an effect of the library in another gyro
// (docs/discovery.md, "Time behaviour"): the switching drift of `switching_drift` and a 39 arcsec
// misalignment of the next gyro. Its round is left unresolved, selection goes on with the other
// gyros (the wandering gyro's walk raised standing in for its drift), and the misalignment is
// found with its rotation. Before (the confusion row `switching_and_gyro_misalignment`): a
// random walk of every gyro, which the commonality check now refuses, or the wandering drift
// alone. Seed 101, the confusion matrix's first, at its 30 h.
TEST(OpenEndedDiagnosis, AMisalignmentOfAnotherGyroIsFoundBesideADriftThatReturnsToItsMean) {
  auto d = DiagnoseScenario("switching_and_gyro_misalignment", 101, 30.0);
  ASSERT_TRUE(d.ok()) << d.status();
  const DiagnosisReport& r = d->report;
  const int wandering = ::esg::testing::AffectedGyro(101);
  const int misaligned = wandering % 3 + 1;
  std::string findings;
  for (const Finding& f : r.findings) {
    absl::StrAppend(&findings, "\n", f.effect, "[", f.gyro, "]: ", f.explanation);
    for (const std::string& n : f.evidence.notes) absl::StrAppend(&findings, "\n  ", n);
  }
  ASSERT_EQ(r.findings.size(), 2u) << findings;
  const Finding& m = r.findings.front();
  EXPECT_EQ(m.effect, "gyro_misalignment") << findings;
  EXPECT_EQ(m.gyro, misaligned) << findings;
  const Eigen::Vector3d truth_b = d->spec.gyros[misaligned - 1].misalignment_b;
  for (int i = 0; i < 3; ++i) {
    const Parameter* p = FindParameter(m, absl::StrFormat("misalignmentArcsec[%d]", i));
    ASSERT_NE(p, nullptr) << findings;
    EXPECT_NEAR(p->value, RadToArcsec(truth_b(i)), 3.0 * p->sigma) << i;
  }
  const Finding& u = r.findings.back();
  EXPECT_EQ(u.effect, kVerdictUnexplained);
  EXPECT_EQ(u.gyro, wandering);
  EXPECT_THAT(u.explanation, HasSubstr(absl::StrCat("the drift of gyro ", wandering,
                                                    " returns to its mean")));
  bool stood_in = false;
  for (const std::string& n : u.evidence.notes) {
    stood_in |= n.find("selection went on with the other gyros") != std::string::npos;
  }
  EXPECT_TRUE(stood_in) << findings;
  EXPECT_TRUE(::esg::testing::DiscoveryVerdictCorrect("switching_and_gyro_misalignment",
                                                      wandering, r));
  // The misalignment explains part of the mismatch, the wandering drift remains: the verdict is
  // partly explained, with what the finding explains and where the rest is (docs/discovery.md, "A
  // verdict no stronger than its evidence").
  EXPECT_EQ(r.verdict, kVerdictPartlyExplained) << findings;
  EXPECT_TRUE(r.consistency.checked);
  EXPECT_THAT(r.consistency.summary, HasSubstr("of the in-sample excess")) << findings;
  EXPECT_THAT(r.consistency.summary,
              HasSubstr(absl::StrCat("what remains is unexplained, in gyro ", wandering)))
      << r.consistency.summary;
  EXPECT_GT(r.consistency.in_sample_explained, 0.0) << r.consistency.summary;
}

}  // namespace
}  // namespace esg::estimator::discovery
