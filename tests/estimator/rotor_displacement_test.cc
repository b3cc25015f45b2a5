// One physical term, one finding, for a displaced rotor (estimator/discovery/candidates.h
// DescribeRotorDisplacement, docs/discovery.md "One physical term, one finding"): C1 and C2 of
// eq. (10) that are collinear within their covariance are reported as one displacement, lambda,
// C10 and C20 of eq. (8)-(9) with their sigmas and the test of the collinearity; C1 and C2 that
// are not collinear stay the six terms, with the test saying so.
#include <cmath>
#include <string>

#include "estimator/discovery/candidate.h"
#include "estimator/discovery/candidates.h"
#include "estimator/discovery/report.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace esg::estimator::discovery {
namespace {

using ::testing::HasSubstr;
using ::testing::Not;

constexpr double kSigmaDegH = 0.002;  // each component of C1 and C2, no correlation

// A fit of gyro 2 whose run ends with C1_deg_h and C2_deg_h (case axes), each component with
// 1-sigma kSigmaDegH; no frames, so no voltages to compare.
CandidateFit FitWith(const Eigen::Vector3d& C1_deg_h, const Eigen::Vector3d& C2_deg_h) {
  CandidateFit fit;
  GyroEstimate g;
  g.id = 2;
  g.coefficients.C1 = C1_deg_h * DegPerHourToRadPerSec(1.0);
  g.coefficients.C2 = C2_deg_h * DegPerHourToRadPerSec(1.0);
  g.sigma.C1 = Eigen::Vector3d::Constant(DegPerHourToRadPerSec(kSigmaDegH));
  g.sigma.C2 = g.sigma.C1;
  fit.run.gyros.push_back(g);
  DescribeRotorDisplacement(SpacecraftConfig{}, {}, 2, fit);
  return fit;
}

Finding FindingOf(const CandidateFit& fit) {
  Finding f;
  f.effect = "rotor_displacement";
  f.gyro = 2;
  f.parameters = fit.fitted;
  f.evidence.evidence = f.evidence.delta_deviance = 500.0;
  f.evidence.parameters = 6;
  f.evidence.threshold = 15.0;
  return f;
}

double Value(const CandidateFit& fit, const std::string& name) {
  const Parameter* p = FindParameter(fit.fitted, name);
  EXPECT_NE(p, nullptr) << name;
  return p == nullptr ? NAN : p->value;
}

double Sigma(const CandidateFit& fit, const std::string& name) {
  const Parameter* p = FindParameter(fit.fitted, name);
  EXPECT_NE(p, nullptr) << name;
  return p == nullptr ? NAN : p->sigma;
}

TEST(RotorDisplacementTerm, CollinearC1AndC2AreOneDisplacementWithItsSigmas) {
  // C10 = 0.07, C20 = 0.02 deg/h along lambda: C1 = 0.09 lambda, C2 = -0.1 lambda (eq. (8)-(10)).
  const Eigen::Vector3d lambda = Eigen::Vector3d(0.55, -0.72, 0.43).normalized();
  const double a = 0.07 + 0.02, b = -5.0 * 0.02;
  const CandidateFit fit = FitWith(a * lambda, b * lambda);
  EXPECT_NEAR(Value(fit, "c10DegH"), 0.07, 1e-6);
  EXPECT_NEAR(Value(fit, "c20DegH"), 0.02, 1e-6);
  for (int i = 0; i < 3; ++i) {
    EXPECT_NEAR(Value(fit, "lambda[" + std::to_string(i) + "]"), lambda(i), 1e-5);
  }
  // Independent sigmas s: a and b are the projections on lambda (variance s^2 each), so
  // sigma(C20) = s / 5 and sigma(C10) = s sqrt(1 + 1/25); each angle across lambda is seen by
  // both vectors, variance s^2 / (a^2 + b^2), and the two angles' variances sum.
  const double s = kSigmaDegH;
  EXPECT_NEAR(Sigma(fit, "c20DegH"), s / 5.0, 1e-3 * s);
  EXPECT_NEAR(Sigma(fit, "c10DegH"), s * std::sqrt(1.0 + 1.0 / 25.0), 1e-3 * s);
  EXPECT_NEAR(Value(fit, "lambdaSigmaDeg"),
              RadToDeg(std::sqrt(2.0) * s / std::sqrt(a * a + b * b)), 1e-3);
  EXPECT_NEAR(Value(fit, "collinearityChi2"), 0.0, 1e-6);
  EXPECT_EQ(Value(fit, "collinearityDof"), 2.0);
  EXPECT_GT(Value(fit, "collinearityP"), kCollinearityP);
  const std::string text = ExplainFinding(FindingOf(fit));
  EXPECT_THAT(text, HasSubstr("one displaced rotor (eq. (8)-(10)) along lambda = [0.55, -0.72, "
                              "0.43]"));
  EXPECT_THAT(text, HasSubstr("C10 = 0.0700 +- 0.0020 deg/h, C20 = 0.0200 +- 0.0004 deg/h"));
  EXPECT_THAT(text, HasSubstr("are this one displacement, collinear within their covariance "
                              "(chi2 = 0.0 on 2 dof"));
}

TEST(RotorDisplacementTerm, C1AndC2ThatAreNotCollinearStaySixTermsWithTheTest) {
  // C2 turned 30 deg away from C1's line: 0.1 deg/h against sigmas of 0.002 is far off one line.
  const Eigen::Vector3d lambda = Eigen::Vector3d(0.55, -0.72, 0.43).normalized();
  const Eigen::Vector3d across = lambda.unitOrthogonal();
  const double turn = DegToRad(30.0);
  const CandidateFit fit =
      FitWith(0.09 * lambda, -0.1 * (std::cos(turn) * lambda + std::sin(turn) * across));
  EXPECT_LT(Value(fit, "collinearityP"), kCollinearityP);
  EXPECT_GT(Value(fit, "collinearityChi2"), 100.0);
  const std::string text = ExplainFinding(FindingOf(fit));
  EXPECT_THAT(text, HasSubstr("drifts with odd harmonics of a displaced rotor"));
  EXPECT_THAT(text, HasSubstr("30 deg apart as lines; not collinear as one displacement makes "
                              "them"));
  EXPECT_THAT(text, HasSubstr("more acts on C1 and C2 than one displaced rotor"));
  EXPECT_THAT(text, Not(HasSubstr("one displaced rotor (eq.")));
}

TEST(RotorDisplacementTerm, ALineThatCannotBeTestedStatesNoSigmaAndNoTest) {
  // C1 and C2 both zero: no direction, so no information on lambda and no test to state.
  const CandidateFit fit = FitWith(Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero());
  EXPECT_EQ(FindParameter(fit.fitted, "lambdaSigmaDeg"), nullptr);
  EXPECT_EQ(Sigma(fit, "c10DegH"), 0.0);
  const std::string text = ExplainFinding(FindingOf(fit));
  EXPECT_THAT(text, Not(HasSubstr("one displaced rotor (eq.")));
}

}  // namespace
}  // namespace esg::estimator::discovery
