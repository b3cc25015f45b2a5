// A drift that follows the sun (estimator/discovery/sun_regressors.h, sun_terms.h;
// docs/discovery.md "A drift that follows the sun"): the lag filter against its closed form, the
// averaged evidence, and on simulated recordings (tests/testing/discovery_scenarios.h
// "sun_face_drift": simulator.h SunFaceDrift, the real sun at the recording's UTC) the diagnosis
// the open-ended stage selects the sun's group on the gyro, the face and the lag within its
// interval and the amplitude within 3 sigma; on an effect-free recording it selects nothing. The
// sun as a candidate of every selection round (sun_terms.h FitSunCandidate, SunCandidate.*): its
// count in the round's M and its fit on one recording of each kind. The whole diagnosis is
// measured by scripts/sun_drift_rate.sh (DISABLED_ManySeeds).
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/attitude_profile.h"
#include "estimator/basis_term.h"
#include "estimator/discovery/candidates.h"
#include "estimator/discovery/deviation.h"
#include "estimator/discovery/diagnose.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/open_ended.h"
#include "estimator/discovery/regimes.h"
#include "estimator/discovery/sun_regressors.h"
#include "estimator/discovery/sun_terms.h"
#include "estimator/simulator.h"
#include "estimator/statistics.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/discovery_scenarios.h"
#include "tests/testing/scenario_orbit.h"

namespace esg::estimator::discovery {
namespace {


TEST(SunRegressors, LagOfAStepOfIlluminationIsTheFirstOrderResponse) {
  // u = 0 for 100 substeps of 60 s, then 1: y at the midpoints is 1 - exp(-(t - t_on) / tau).
  std::vector<double> u(400, 0.0), dt(400, 60.0);
  for (int i = 100; i < 400; ++i) u[i] = 1.0;
  const double tau_s = 3600.0;
  const std::vector<double> y = LaggedIllumination(u, dt, tau_s);
  ASSERT_EQ(y.size(), u.size());
  EXPECT_DOUBLE_EQ(y[50], 0.0);
  for (int i : {100, 160, 250, 399}) {
    const double t = (i - 100 + 0.5) * 60.0;
    EXPECT_NEAR(y[i], 1.0 - std::exp(-t / tau_s), 1e-12) << i;
  }
  // Starts in equilibrium with the first illumination.
  const std::vector<double> lit = LaggedIllumination(std::vector<double>(10, 0.7), dt, tau_s);
  for (double v : lit) EXPECT_DOUBLE_EQ(v, 0.7);
}

TEST(SunRegressors, FacesGridAndAveragedEvidence) {
  const Eigen::Vector3d s_b = Eigen::Vector3d(0.6, -0.8, 0.0);
  EXPECT_DOUBLE_EQ(FaceIllumination(s_b, 0), 0.6);  // +x
  EXPECT_DOUBLE_EQ(FaceIllumination(s_b, 1), 0.0);  // -x, in shadow
  EXPECT_DOUBLE_EQ(FaceIllumination(s_b, 3), 0.8);  // -y
  EXPECT_EQ(SunFaceName(3), "-y");
  const std::vector<double> grid = SunLagGridHours();
  ASSERT_EQ(grid.size(), 41u);
  EXPECT_DOUBLE_EQ(grid.front(), 0.1);
  EXPECT_NEAR(grid.back(), 10.0, 1e-12);
  // 2 ln of the mean Bayes factor: B = e^(x/2).
  const std::vector<double> e = {10.0, 2.0, -4.0};
  const double mean_b = (std::exp(5.0) + std::exp(1.0) + std::exp(-2.0)) / 3.0;
  EXPECT_NEAR(AverageEvidence(e), 2.0 * std::log(mean_b), 1e-12);
  EXPECT_LT(AverageEvidence(e), 10.0);
}

TEST(SunRegressors, LagIntervalIsWhereTheEvidenceStaysWithin384OfItsMaximum) {
  SelectedGroup g;
  g.lag_hours = {0.5, 1.0, 2.0, 4.0};
  g.lag_evidence = {10.0, 20.0, 18.0, 10.0};
  const LagInterval lag = SunLagInterval(g);
  EXPECT_DOUBLE_EQ(lag.best, 1.0);
  // Level 16.16: between 0.5 (10) and 1.0 (20), and between 2.0 (18) and 4.0 (10), in log(lag).
  EXPECT_NEAR(lag.lower, std::exp(std::log(1.0) + (20.0 - 16.16) / 10.0 * std::log(0.5)), 1e-12);
  EXPECT_NEAR(lag.upper, std::exp(std::log(2.0) + (18.0 - 16.16) / 8.0 * std::log(2.0)), 1e-12);
}

const Parameter* Find(const Finding& f, const std::string& name) {
  for (const Parameter& p : f.parameters) {
    if (p.name == name) return &p;
  }
  return nullptr;
}

// The diagnosis options for a scenario: with the orbit when the recording has the Earth's shadow
// (eclipse_drift), as `esg diagnose --orbit` would be given it.
absl::StatusOr<DiagnoseOptions> SunDiagnoseOptions(const SimulationSpec& spec, uint64_t seed) {
  DiagnoseOptions options;
  if (absl::Status s = ::esg::testing::AddScenarioOrbit(spec, seed, options); !s.ok()) return s;
  return options;
}

// The diagnosis of a sun_face_drift (or eclipse_drift) recording of `seed` at `hours`.
struct SunDiagnosis {
  std::string effect;
  SimulationSpec spec;
  DiagnosisReport report;
  // The affected gyro's true illumination u over the recording's frames (simulator.h
  // GyroTruthSample::sun_illumination): on a steady orbital orientation a face along the orbit
  // normal is lit at a constant level or never.
  double illumination_min = 0.0, illumination_max = 0.0;
};
// `profile`, when not empty, names the attitude profile (attitude_profile.h MakeNamedProfile, drawn
// from the seed) instead of the scenario's mostly orbital one.
absl::StatusOr<SunDiagnosis> DiagnoseSun(const std::string& effect, uint64_t seed, double hours,
                                         const std::string& profile = "") {
  SunDiagnosis out;
  out.effect = effect;
  out.spec = ::esg::testing::DiscoveryScenario(effect, seed, hours);
  if (!profile.empty()) {
    auto named = MakeNamedProfile(profile, out.spec.duration, seed);
    if (!named.ok()) return named.status();
    out.spec.profile = *std::move(named);
  }
  auto sim = Simulate(out.spec);
  if (!sim.ok()) return sim.status();
  const int g = ::esg::testing::AffectedGyro(seed) - 1;
  out.illumination_min = 1.0;
  for (const TruthSample& t : sim->truth) {
    if (!t.gyros[g]) continue;
    out.illumination_min = std::min(out.illumination_min, t.gyros[g]->sun_illumination);
    out.illumination_max = std::max(out.illumination_max, t.gyros[g]->sun_illumination);
  }
  auto options = SunDiagnoseOptions(out.spec, seed);
  if (!options.ok()) return options.status();
  auto report = Diagnose(out.spec.config, sim->recording.frames, *options);
  if (!report.ok()) return report.status();
  out.report = std::move(*report);
  return out;
}

// The report's findings in short: "gyro_misalignment[3] basis_term[2](follows_sun) ...".
std::string Findings(const DiagnosisReport& r) {
  std::string out = r.verdict;
  for (const Finding& f : r.findings) {
    absl::StrAppend(&out, " ", f.effect, "[", f.gyro, "](", f.time.kind, ")");
  }
  return out;
}

// What a sun finding of a sun_face_drift or eclipse_drift recording gets wrong, in words (""
// when nothing). A face the sun never lights in the recording gives no drift: then any finding
// of the affected gyro is wrong, and none is right.
std::string SunFindingWrong(const SunDiagnosis& d, uint64_t seed) {
  const int gyro = ::esg::testing::AffectedGyro(seed);
  const int face = ::esg::testing::SunFamilyOf(d.effect, seed);
  const double lag_h = ::esg::testing::SunLagHoursOf(seed);
  const DiagnosisReport& r = d.report;
  if (d.illumination_max == 0.0) {
    for (const Finding& f : r.findings) {
      if (f.gyro == gyro) return absl::StrCat("a finding on an unlit face: ", Findings(r));
    }
    return "";
  }
  const Finding* sun = nullptr;
  for (const Finding& f : r.findings) {
    if (f.effect == kEffectBasisTerm && f.time.kind == kTimeFollowsSun && sun == nullptr) sun = &f;
  }
  if (sun == nullptr) return absl::StrCat("no sun finding: ", Findings(r));
  const Finding& f = *sun;
  std::string wrong;
  if (f.gyro != gyro) absl::StrAppend(&wrong, "gyro ", f.gyro, " not ", gyro, "; ");
  const Eigen::Vector3d n_b = SunFaceNormal_b(face);
  for (int i = 0; i < 3; ++i) {
    const Parameter* p = Find(f, absl::StrCat("sunFaceNormalB[", i, "]"));
    if (p == nullptr || p->value != n_b(i)) {
      absl::StrAppend(&wrong, "face not ", SunFaceName(face), "; ");
      break;
    }
  }
  const Parameter* lower = Find(f, "sunLagLowerHours");
  const Parameter* upper = Find(f, "sunLagUpperHours");
  if (lower == nullptr || upper == nullptr || lag_h < lower->value || lag_h > upper->value) {
    absl::StrAppend(&wrong, "lag ", lag_h, " h outside its interval; ");
  }
  const Eigen::Vector3d a_deg_h =
      RadPerSecToDegPerHour(1.0) * d.spec.gyros[gyro - 1].sun_face_drift->amplitude_k_rad_s;
  for (int i = 0; i < 3; ++i) {
    const Parameter* p = Find(f, absl::StrCat("sunDriftDegH[", i, "]"));
    if (p == nullptr || !(std::abs(p->value - a_deg_h(i)) <= 3.0 * p->sigma)) {
      absl::StrAppend(&wrong, "amplitude ", i, " beyond 3 sigma; ");
    }
  }
  if (!wrong.empty()) absl::StrAppend(&wrong, f.description);
  return wrong;
}

// 30 h, the length of the confusion matrix (the lag and the face need several orbits of each
// regime).
constexpr double kHours = 30.0;

// The open-ended stage alone on the user's model's deviation (as OpenEnded.* in
// open_ended_test.cc): the basis with the sun's regressors of every running gyro.
absl::StatusOr<OpenEndedResult> SunStage(const std::string& effect, uint64_t seed,
                                         SimulationSpec& spec) {
  auto m = ::esg::testing::MeasureUserModelDeviations(effect, seed, kHours, {1, 2, 3});
  if (!m.ok()) return m.status();
  spec = m->spec;
  OpenEndedOptions o;
  o.orbital_period_s = 5640.0;
  o.epoch = m->frames.front().time;
  o.free_coefficients = FreeCoefficientsOf(m->config);
  std::string note;
  o.sun = SunRegressorsOf(m->series, m->config, m->run.gyros, &note);
  if (o.sun.size() != 3) return absl::InternalError(note);
  const std::vector<double> rw(3, m->config.random_walk), w0(3, DegPerHourToRadPerSec(0.01));
  return RunOpenEnded(m->series, rw, w0, o);
}

// The tabulated signatures the open-ended stage takes its columns from (open_ended.h
// BasisColumn::scalar_table, sun_regressors.h TabulatedSignatures) are the same bits as the
// signature of the term evaluated substep by substep (deviation.h Signature) and as one axis at
// a time: the basis computes each regressor once for its three axes, and its columns must not
// change by it. On a 6 h recording's deviation: a spin-axis harmonic, an orbital harmonic and a
// sun face's lagged illumination.
TEST(SunRegressors, ATermsTabulatedSignaturesAreItsSignaturesBitForBit) {
  auto measured = ::esg::testing::MeasureUserModelDeviations("none", 101, 6.0, {2});
  ASSERT_TRUE(measured.ok()) << measured.status();
  const DeviationSeries& d = measured->series.front();
  const auto& frames = measured->frames;
  ASSERT_GT(d.steps.size(), d.sample_end.size());

  BasisTerm harmonic;
  harmonic.kind = BasisKind::kSpinAxisHarmonic;
  harmonic.exponents = {2, 1, 0};
  BasisTerm orbital;
  orbital.kind = BasisKind::kOrbitalHarmonic;
  orbital.harmonic = 1;
  orbital.period = 5640.0;
  orbital.sine = true;
  orbital.epoch = frames.front().time;
  for (const BasisTerm& term : {harmonic, orbital}) {
    std::vector<double> table;
    for (const TrajectoryStep& st : d.steps) table.push_back(BasisScalar(term, st.inputs));
    const auto together = TabulatedSignatures(d, table);
    for (int m = 1; m <= 3; ++m) {
      BasisTerm t = term;
      t.axis = m;
      const std::vector<Eigen::Vector2d> evaluated =
          Signature(d, [&t](const BasisInputs& in) -> Eigen::Vector3d {
            return BasisScalar(t, in) * Eigen::Vector3d::Unit(t.axis - 1);
          });
      const std::vector<Eigen::Vector2d> one_axis =
          TabulatedSignature(d, table, Eigen::Vector3d::Unit(m - 1));
      ASSERT_EQ(evaluated.size(), d.sample_end.size());
      ASSERT_EQ(together[m - 1].size(), evaluated.size());
      for (size_t k = 0; k < evaluated.size(); ++k) {
        ASSERT_EQ(one_axis[k], evaluated[k]) << BasisTermLabel(t) << " sample " << k;
        ASSERT_EQ(together[m - 1][k], evaluated[k]) << BasisTermLabel(t) << " sample " << k;
      }
    }
    EXPECT_NE(together[0].back(), Eigen::Vector2d::Zero()) << BasisTermLabel(term);
  }
  std::string note;
  const std::vector<SunRegressors> sun =
      SunRegressorsOf(measured->series, measured->config, measured->run.gyros, &note);
  ASSERT_EQ(sun.size(), 1u) << note;
  const std::vector<double>* lit = nullptr;  // the face lit most, at the longest lag
  for (const auto& face : sun.front().values) {
    if (lit == nullptr || TabulatedRms(d, face.back()) > TabulatedRms(d, *lit)) lit = &face.back();
  }
  ASSERT_GT(TabulatedRms(d, *lit), 0.0);
  const auto together = TabulatedSignatures(d, *lit);
  for (int m = 0; m < 3; ++m) {
    const std::vector<Eigen::Vector2d> one = TabulatedSignature(d, *lit, Eigen::Vector3d::Unit(m));
    for (size_t k = 0; k < one.size(); ++k) ASSERT_EQ(together[m][k], one[k]) << m << " " << k;
  }
}

// The first group the stage selects is the sun on the right face of the right gyro, its lag
// interval holds the truth and its amplitude is within 3 sigma per case axis (seeds fixed before
// the first run).
TEST(SunStage, ADriftThatFollowsTheSunIsSelectedWithItsGyroFaceLagAndAmplitude) {
  for (uint64_t seed : {7, 9}) {
    SimulationSpec spec;
    auto r = SunStage("sun_face_drift", seed, spec);
    ASSERT_TRUE(r.ok()) << r.status();
    ASSERT_FALSE(r->selected.empty()) << "seed " << seed;
    const SelectedGroup& g = r->selected.front();
    const int gyro = ::esg::testing::AffectedGyro(seed);
    EXPECT_EQ(g.gyro, gyro) << "seed " << seed;
    EXPECT_EQ(g.sun_face, ::esg::testing::SunFaceOf(seed)) << g.label;
    EXPECT_GT(g.evidence, g.threshold);
    const LagInterval lag = SunLagInterval(g);
    EXPECT_LE(lag.lower, ::esg::testing::SunLagHoursOf(seed)) << DescribeSunGroup(g);
    EXPECT_GE(lag.upper, ::esg::testing::SunLagHoursOf(seed)) << DescribeSunGroup(g);
    const Eigen::Vector3d a = SunAmplitude_k(g);
    const Eigen::Matrix3d P = SunAmplitudeCovariance_k(g);
    const Eigen::Vector3d truth = spec.gyros[gyro - 1].sun_face_drift->amplitude_k_rad_s;
    for (int i = 0; i < 3; ++i) {
      EXPECT_LE(std::abs(a(i) - truth(i)), 3.0 * std::sqrt(P(i, i))) << i << " " << DescribeSunGroup(g);
    }
  }
}

TEST(SunStage, AnEffectFreeRecordingSelectsNothingWithTheSunsRegressors) {
  SimulationSpec spec;
  auto r = SunStage("none", 101, spec);
  ASSERT_TRUE(r.ok()) << r.status();
  EXPECT_TRUE(r->selected.empty()) << r->best_label;
  EXPECT_LT(r->best_evidence, r->best_threshold);
}

// The sun is a candidate of every selection round, one per gyro, counted once per family it may
// try in the round's M (D101): six faces, with the orbit `sunlit` as a seventh, fewer when the
// model holds some of them already.
TEST(SunCandidate, EveryRoundOffersTheSunOfEachGyroCountingEachFaceOnce) {
  ModelState model;
  model.config = ::esg::testing::DiscoveryScenario("none", 101, kHours).config;
  for (const bool with_orbit : {false, true}) {
    const std::vector<Candidate> candidates = ListCandidates(model, {1, 2, 3}, {}, with_orbit);
    int sun = 0;
    for (const Candidate& c : candidates) {
      if (c.effect != Effect::kSunDrift) {
        EXPECT_EQ(CandidateComparisons(c, model, with_orbit), 1) << CandidateName(c);
        continue;
      }
      ++sun;
      EXPECT_EQ(CandidateComparisons(c, model, with_orbit), with_orbit ? 7 : 6)
          << CandidateName(c);
    }
    EXPECT_EQ(sun, 3);
  }
  EXPECT_TRUE(EffectFromId("sun_drift") == Effect::kSunDrift);
  // Gyro 2 holds face -y (taken by a round or by the open-ended stage: the same name).
  model.added.push_back(HeldSunGroupName(2, SunGroupLabel(3, 1.26)));
  EXPECT_EQ(HeldSunFaces(model, 2), std::vector<int>{3});
  EXPECT_TRUE(HeldSunFaces(model, 1).empty());
  EXPECT_EQ(CandidateComparisons({Effect::kSunDrift, 2}, model, false), 5);
  EXPECT_EQ(CandidateComparisons({Effect::kSunDrift, 2}, model, true), 6);
  for (int face = 0; face < kSunFaces; ++face) {
    model.added.push_back(HeldSunGroupName(2, SunGroupLabel(face, 0.5)));
  }
  auto offers_gyro_2 = [&](bool with_orbit) {
    for (const Candidate& c : ListCandidates(model, {1, 2, 3}, {}, with_orbit)) {
      if (c.effect == Effect::kSunDrift && c.gyro == 2) return true;
    }
    return false;
  };
  EXPECT_FALSE(offers_gyro_2(false)) << "every face of gyro 2 is held";
  // With the orbit the eclipses are still open to gyro 2: one comparison.
  EXPECT_TRUE(offers_gyro_2(true));
  EXPECT_EQ(CandidateComparisons({Effect::kSunDrift, 2}, model, true), 1);
  model.added.push_back(HeldSunGroupName(2, SunGroupLabel(kSunlitFamily, 0.5)));
  EXPECT_FALSE(offers_gyro_2(true)) << "every family of gyro 2 is held";
}

// The sun candidate of one gyro fitted on the user's model (FitSunCandidate: the regression over
// the faces, the drift held at the best lag, the filter's refit): on sun_face_drift seed 7 (a
// seed of SunStage.*, fixed before the first run) the candidate of the affected gyro names the
// face, holds the true lag in its interval, the amplitude within 3 sigma per case axis, and its
// evidence (the refit's improvement less the Occam term and the lag's cost) passes the round's
// threshold; on the effect-free seed 101 it does not.
struct SunCandidateResult {
  SimulationSpec spec;
  CandidateFit fit;
  double evidence = 0.0;   // 2 ln B: the refit's improvement less fit.occam
  double threshold = 0.0;  // 2 ln(M / alpha), M the round's comparisons
};
absl::StatusOr<SunCandidateResult> SunCandidateOn(const std::string& effect, uint64_t seed) {
  SunCandidateResult out;
  out.spec = ::esg::testing::DiscoveryScenario(effect, seed, kHours);
  auto options = SunDiagnoseOptions(out.spec, seed);
  if (!options.ok()) return options.status();
  auto fitting = ::esg::testing::PrepareCandidateFit(out.spec, *std::move(options));
  if (!fitting.ok()) return fitting.status();
  const ModelState& model = (*fitting)->model;
  const DiagnoseOptions& options_used = (*fitting)->options;
  const FitContext ctx = (*fitting)->Context();
  int family = 0;
  const bool with_orbit = options_used.orbit != nullptr;
  for (const Candidate& c : ListCandidates(model, ctx.gyros, options_used.effects, with_orbit)) {
    family += CandidateComparisons(c, model, with_orbit);
  }
  out.threshold = EvidenceThreshold(options_used.alpha, family);
  auto fit = FitCandidate({Effect::kSunDrift, ::esg::testing::AffectedGyro(seed)}, ctx);
  if (!fit.ok()) return fit.status();
  out.fit = std::move(*fit);
  out.evidence = Profile((*fitting)->run).value - Profile(out.fit.run).value - out.fit.occam;
  return out;
}

// The sun candidate of the affected gyro on `effect`'s recording of `seed`: the scenario's family
// (its face's normal; zero for `sunlit`) with evidence above the round's threshold; with
// `parameters` also the true lag inside its interval and each case axis of the amplitude within 3
// sigma.
void ExpectSunCandidateRight(const std::string& effect, uint64_t seed, bool parameters) {
  auto r = SunCandidateOn(effect, seed);
  ASSERT_TRUE(r.ok()) << r.status();
  const CandidateFit& fit = r->fit;
  ASSERT_EQ(fit.parameters, 3) << absl::StrJoin(fit.notes, "\n");
  EXPECT_EQ(fit.time.kind, kTimeFollowsSun);
  EXPECT_GT(r->evidence, r->threshold) << absl::StrJoin(fit.notes, "\n");
  Finding f;
  f.parameters = fit.fitted;
  const Eigen::Vector3d n_b = SunFaceNormal_b(::esg::testing::SunFamilyOf(effect, seed));
  for (int i = 0; i < 3; ++i) {
    const Parameter* p = Find(f, absl::StrCat("sunFaceNormalB[", i, "]"));
    ASSERT_NE(p, nullptr);
    EXPECT_EQ(p->value, n_b(i)) << fit.description;
  }
  if (!parameters) return;
  const double lag_h = ::esg::testing::SunLagHoursOf(seed);
  ASSERT_NE(Find(f, "sunLagLowerHours"), nullptr);
  ASSERT_NE(Find(f, "sunLagUpperHours"), nullptr);
  EXPECT_LE(Find(f, "sunLagLowerHours")->value, lag_h) << fit.description;
  EXPECT_GE(Find(f, "sunLagUpperHours")->value, lag_h) << fit.description;
  const Eigen::Vector3d a_deg_h =
      RadPerSecToDegPerHour(1.0) *
      r->spec.gyros[::esg::testing::AffectedGyro(seed) - 1].sun_face_drift->amplitude_k_rad_s;
  for (int i = 0; i < 3; ++i) {
    const Parameter* p = Find(f, absl::StrCat("sunDriftDegH[", i, "]"));
    ASSERT_NE(p, nullptr);
    EXPECT_LE(std::abs(p->value - a_deg_h(i)), 3.0 * p->sigma) << i << " " << fit.description;
  }
}

TEST(SunCandidate, TheRoundsSunCandidateNamesTheFaceLagAndAmplitudeAndPassesTheThreshold) {
  ExpectSunCandidateRight("sun_face_drift", 7, /*parameters=*/true);
}

// With the orbit, a drift that follows the eclipses (eclipse_drift seed 1, fixed before the first
// run: gyro 2, a 0.5 h lag) is the `sunlit` family's, whatever the face the sun lights, above the
// threshold of a round that counts seven families per gyro in M, with the true lag inside its
// interval and the amplitude within 3 sigma. Before the model's free k0 was refitted beside the
// family (open_ended.h OpenEndedOptions::free_coefficients), the lag came out 0.45 h (95%
// interval 0.44-0.48 h) and the amplitude 0.0839 +- 0.0008 deg/h against 0.088.
TEST(SunCandidate, WithTheOrbitTheRoundsSunCandidateNamesTheEclipses) {
  ExpectSunCandidateRight("eclipse_drift", 1, /*parameters=*/true);
}

TEST(SunCandidate, OnAnEffectFreeRecordingTheSunCandidateStaysBelowTheThreshold) {
  auto r = SunCandidateOn("none", 101);
  ASSERT_TRUE(r.ok()) << r.status();
  // Either no fit (the sun's best face is not the basis's first choice: a note says so) or one
  // below the threshold.
  if (r->fit.parameters == 0) {
    ASSERT_FALSE(r->fit.notes.empty());
    EXPECT_THAT(r->fit.notes.back(),
                ::testing::HasSubstr("not the open-ended basis's first choice"));
    return;
  }
  EXPECT_LT(r->evidence, r->threshold) << absl::StrJoin(r->fit.notes, "\n");
}

// A face the sun lights at a constant level (sun_face_drift seed 3 on the orbital profile: face
// -y, along minus the orbit normal, lit 0.741-0.755 over the 30 h; gyro 1, a 1.4 h lag) gives a
// constant drift, which the recording cannot tell from a case-fixed drift: the sun's best face
// and the basis's case-fixed groups are within the ambiguity of each other on the deviation. The
// sun is fitted all the same (readout_candidate.h FitSunCandidate, D132) and named with the
// constant it cannot be told from, its lag interval spanning what the recording cannot resolve
// and its amplitude within 3 sigma. Before D132 the sun was not fitted ("h2^2" had 2 ln B 0.7
// more on the deviation) and a gyro_misalignment of gyro 1 was named with no word of the sun.
TEST(SunDiagnosis, AFaceLitAtAConstantLevelIsNamedWithTheConstantItCannotBeToldFrom) {
  auto d = DiagnoseSun("sun_face_drift", 3, kHours, "orbital");
  ASSERT_TRUE(d.ok()) << d.status();
  ASSERT_GT(d->illumination_min, 0.7);
  ASSERT_LT(d->illumination_max - d->illumination_min, 0.02);
  EXPECT_EQ(SunFindingWrong(*d, 3), "");
  const Finding* sun = nullptr;
  for (const Finding& f : d->report.findings) {
    if (f.time.kind == kTimeFollowsSun) sun = &f;
  }
  ASSERT_NE(sun, nullptr) << Findings(d->report);
  EXPECT_THAT(sun->description, ::testing::HasSubstr("cannot tell it from a constant"));
  // The lag is not resolved: its interval spans most of the grid (0.1-10 h).
  const Parameter* lower = Find(*sun, "sunLagLowerHours");
  const Parameter* upper = Find(*sun, "sunLagUpperHours");
  ASSERT_NE(lower, nullptr);
  ASSERT_NE(upper, nullptr);
  EXPECT_LT(lower->value, 0.5);
  EXPECT_GT(upper->value, 5.0);
}

// The many-seed measurement of docs/discovery.md (scripts/sun_drift_rate.sh): ESG_SUN_SEEDS
// recordings from ESG_SUN_FIRST_SEED, one line each, on the attitude profile ESG_SUN_PROFILE
// (MakeNamedProfile's names; unset: the scenario's mostly orbital one); not part of CI.
TEST(SunDiagnosis, DISABLED_ManySeeds) {
  const char* n_env = std::getenv("ESG_SUN_SEEDS");
  const char* first_env = std::getenv("ESG_SUN_FIRST_SEED");
  const char* effect_env = std::getenv("ESG_SUN_EFFECT");
  const int n = n_env != nullptr ? std::atoi(n_env) : 10;
  const uint64_t first = first_env != nullptr ? std::strtoull(first_env, nullptr, 10) : 101;
  const std::string effect = effect_env != nullptr ? effect_env : "sun_face_drift";
  const char* profile_env = std::getenv("ESG_SUN_PROFILE");
  const std::string profile = profile_env != nullptr ? profile_env : "";
  int right = 0;
  for (int i = 0; i < n; ++i) {
    const uint64_t seed = first + i;
    auto d = DiagnoseSun(effect, seed, kHours, profile);
    ASSERT_TRUE(d.ok()) << d.status();
    std::string line;
    if (effect == "sun_face_drift" || effect == "eclipse_drift") {
      line = SunFindingWrong(*d, seed);
    } else {
      for (const Finding& f : d->report.findings) absl::StrAppend(&line, f.effect, " ");
    }
    right += line.empty() ? 1 : 0;
    std::string sun_text;
    for (const Finding& f : d->report.findings) {
      if (f.time.kind == kTimeFollowsSun) absl::StrAppend(&sun_text, " | ", f.description);
    }
    std::printf("seed %llu gyro %d face %s (lit %.3f-%.3f) lag %.1f h: %s [%s]%s\n",
                static_cast<unsigned long long>(seed), ::esg::testing::AffectedGyro(seed),
                SunFaceName(::esg::testing::SunFamilyOf(effect, seed)).c_str(),
                d->illumination_min, d->illumination_max,
                ::esg::testing::SunLagHoursOf(seed), line.empty() ? "right" : line.c_str(),
                Findings(d->report).c_str(), sun_text.c_str());
    // A miss: the candidates of the affected gyro in each round, to see what the sun lost to.
    if (!line.empty()) {
      for (const CandidateScore& c : d->report.candidates) {
        if (c.gyro != ::esg::testing::AffectedGyro(seed)) continue;
        std::printf("  round %d %s: 2 ln B %.1f%s%s%s\n", c.round, c.effect.c_str(), c.score,
                    c.significant ? " significant" : "", c.selected ? " selected" : "",
                    c.not_fitted.empty() ? "" : absl::StrCat(" (", c.not_fitted, ")").c_str());
      }
    }
    std::fflush(stdout);
  }
  std::printf("%s: %d of %d right\n", effect.c_str(), right, n);
}

}  // namespace
}  // namespace esg::estimator::discovery
