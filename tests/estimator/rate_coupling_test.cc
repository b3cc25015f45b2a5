// One physical term, one finding (estimator/discovery/rate_coupling.h, docs/discovery.md "One
// physical term, one finding"): three body-rate groups of one gyro whose gains are k I within
// their sigmas become one isotropic coupling with the test of the equality; gains that are not
// stay three terms, with the test in a note. And the whole diagnosis of the rate_coupling scenario
// (tests/testing/discovery_scenarios.h: dw_k = 0.68 deg/h per deg/s times w_k in one gyro).
#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "estimator/basis_term.h"
#include "estimator/discovery/diagnose.h"
#include "estimator/discovery/rate_coupling.h"
#include "estimator/simulator.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/discovery_scenarios.h"

namespace esg::estimator::discovery {
namespace {

using ::testing::HasSubstr;

// The basis's finding of group rate[i] of `gyro`: along x, y, z with gains `value` (deg/h per
// deg/s) and 1-sigma `sigma`, as basis_stage.cc writes it.
Finding RateFinding(int gyro, int i, const Eigen::Vector3d& value, double sigma,
                    double evidence) {
  Finding f;
  f.effect = kEffectBasisTerm;
  f.gyro = gyro;
  f.description = absl::StrCat("gyro ", gyro, ": drift proportional to the body rate about case axis ",
                               std::string(1, "xyz"[i - 1]));
  f.evidence.evidence = f.evidence.delta_deviance = evidence;
  f.evidence.parameters = 3;
  f.evidence.threshold = 19.0;
  for (int m = 1; m <= 3; ++m) {
    BasisTerm t;
    t.kind = BasisKind::kBodyRate;
    t.index = {i, i};
    t.axis = m;
    f.basis_terms.push_back(t);
    f.parameters.push_back(Parameter{absl::StrCat("basis[", BasisTermLabel(t), "]"),
                                     value(m - 1), sigma, "deg/h per deg/s"});
  }
  return f;
}

TEST(RateCoupling, ThreeGroupsWithGainsKIWithinTheirSigmasAreOneTerm) {
  Finding other;
  other.effect = kEffectBasisTerm;
  other.gyro = 2;
  other.description = "gyro 2: case-fixed drift";
  std::vector<Finding> findings = {
      RateFinding(2, 2, {0.01, 0.71, -0.02}, 0.02, 300.0), other,
      RateFinding(2, 1, {0.66, 0.0, 0.01}, 0.01, 900.0),
      RateFinding(2, 3, {-0.01, 0.02, 0.67}, 0.03, 200.0)};
  MergeIsotropicRateCoupling(findings);
  ASSERT_EQ(findings.size(), 2u);
  const Finding& f = findings.front();  // where the first of the three was
  EXPECT_EQ(findings.back().description, "gyro 2: case-fixed drift");
  const Parameter* k = FindParameter(f.parameters, "rateCouplingDegHPerDegS");
  ASSERT_NE(k, nullptr);
  // Inverse-variance mean of 0.66 (0.01), 0.71 (0.02), 0.67 (0.03).
  const double w1 = 1e4, w2 = 2500.0, w3 = 1e4 / 9.0;
  EXPECT_NEAR(k->value, (0.66 * w1 + 0.71 * w2 + 0.67 * w3) / (w1 + w2 + w3), 1e-12);
  EXPECT_NEAR(k->sigma, 1.0 / std::sqrt(w1 + w2 + w3), 1e-12);
  EXPECT_GT(FindParameter(f.parameters, "isotropyP")->value, kIsotropyP);
  EXPECT_EQ(f.basis_terms.size(), 9u);
  EXPECT_EQ(f.evidence.evidence, 1400.0);
  EXPECT_EQ(f.evidence.parameters, 9);
  EXPECT_THAT(f.explanation, HasSubstr("an isotropic coupling of the drift to the body rate"));
  EXPECT_THAT(f.explanation, HasSubstr("on 8 degrees of freedom"));
}

TEST(RateCoupling, GainsThatAreNotKIStayThreeTermsWithTheTestInANote) {
  // A coupling about x twice that about y and z: not one isotropic term.
  std::vector<Finding> findings = {RateFinding(1, 1, {1.4, 0.0, 0.0}, 0.01, 900.0),
                                   RateFinding(1, 2, {0.0, 0.7, 0.0}, 0.01, 300.0),
                                   RateFinding(1, 3, {0.0, 0.0, 0.7}, 0.01, 300.0)};
  MergeIsotropicRateCoupling(findings);
  ASSERT_EQ(findings.size(), 3u);
  EXPECT_EQ(FindParameter(findings[0].parameters, "rateCouplingDegHPerDegS"), nullptr);
  ASSERT_FALSE(findings[0].evidence.notes.empty());
  EXPECT_THAT(findings[0].evidence.notes.back(), HasSubstr("not one isotropic coupling"));
  // Two groups only, or of two gyros: nothing to merge.
  std::vector<Finding> two = {RateFinding(1, 1, {0.7, 0.0, 0.0}, 0.01, 900.0),
                              RateFinding(1, 2, {0.0, 0.7, 0.0}, 0.01, 300.0),
                              RateFinding(3, 3, {0.0, 0.0, 0.7}, 0.01, 300.0)};
  MergeIsotropicRateCoupling(two);
  EXPECT_EQ(two.size(), 3u);
  for (const Finding& f : two) EXPECT_TRUE(f.evidence.notes.empty());
}

// The diagnosis of a drift proportional to the body rate with one coefficient (seed 101, gyro 3):
// one finding, the isotropic coupling, k within 3 sigma of the true 0.68 deg/h per deg/s.
TEST(RateCoupling, ADriftProportionalToTheBodyRateIsFoundAsOneIsotropicCoupling) {
  const uint64_t seed = 101;
  const int gyro = ::esg::testing::AffectedGyro(seed);
  const SimulationSpec spec = ::esg::testing::DiscoveryScenario("rate_coupling", seed);
  auto sim = Simulate(spec);
  ASSERT_TRUE(sim.ok()) << sim.status();
  auto report = Diagnose(spec.config, sim->recording.frames, DiagnoseOptions{});
  ASSERT_TRUE(report.ok()) << report.status();
  std::string text = report->verdict;
  for (const Finding& f : report->findings) absl::StrAppend(&text, "\n", f.explanation);
  EXPECT_TRUE(::esg::testing::DiscoveryVerdictCorrect("rate_coupling", gyro, *report, seed))
      << text;
  ASSERT_EQ(report->findings.size(), 1u) << text;
  EXPECT_THAT(report->findings.front().explanation,
              HasSubstr("an isotropic coupling of the drift to the body rate"));
  EXPECT_LE(report->after.gap_drift_rate_deg_h, report->before.gap_drift_rate_deg_h) << text;
}

}  // namespace
}  // namespace esg::estimator::discovery
