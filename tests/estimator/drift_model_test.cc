// Drift terms against the paper's printed component formulas, typed out independently
// (eq. (1), (8), (9), (10)), for many random unit h.
#include "estimator/drift_model.h"

#include <cmath>
#include <random>

#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

using Eigen::Vector3d;

std::vector<Vector3d> RandomUnitVectors(int n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  std::vector<Vector3d> out;
  for (int i = 0; i < n; ++i) out.push_back(Vector3d(normal(rng), normal(rng), normal(rng)).normalized());
  return out;
}

// eq. (1), k0 part, x component; y and z by cyclic permutation (1->2->3->1).
Vector3d PaperK0(const Vector3d& h, double k0) {
  auto x = [&](double a, double b, double c) {
    return a * (-(1 - a * a) * a * a + std::pow(b, 4) + std::pow(c, 4)) * k0;
  };
  return Vector3d(x(h(0), h(1), h(2)), x(h(1), h(2), h(0)), x(h(2), h(0), h(1)));
}

// eq. (10), C1 part: x = -(1-h1^2) C11 + h1 h2 C12 + h1 h3 C13 (as eq. (8) with C1 = C10 lambda).
Vector3d PaperC1(const Vector3d& h, const Vector3d& C) {
  const double h1 = h(0), h2 = h(1), h3 = h(2);
  return Vector3d(-(1 - h1 * h1) * C(0) + h1 * h2 * C(1) + h1 * h3 * C(2),
                  -(1 - h2 * h2) * C(1) + h2 * h3 * C(2) + h2 * h1 * C(0),
                  -(1 - h3 * h3) * C(2) + h3 * h1 * C(0) + h3 * h2 * C(1));
}

// eq. (10), C2 part: x = -(1-h1^2) h1^2 C21 + h1 h2^3 C22 + h1 h3^3 C23.
Vector3d PaperC2(const Vector3d& h, const Vector3d& C) {
  const double h1 = h(0), h2 = h(1), h3 = h(2);
  return Vector3d(-(1 - h1 * h1) * h1 * h1 * C(0) + h1 * std::pow(h2, 3) * C(1) + h1 * std::pow(h3, 3) * C(2),
                  -(1 - h2 * h2) * h2 * h2 * C(1) + h2 * std::pow(h3, 3) * C(2) + h2 * std::pow(h1, 3) * C(0),
                  -(1 - h3 * h3) * h3 * h3 * C(2) + h3 * std::pow(h1, 3) * C(0) + h3 * std::pow(h2, 3) * C(1));
}

// eq. (1), mu/nu part: x = h1 (mu12 h2^2 - mu31 h3^2) + h2 h3 nu23, cyclic.
Vector3d PaperMuNu(const Vector3d& h, double mu12, double mu23, double mu31, double nu23,
                   double nu31, double nu12) {
  const double h1 = h(0), h2 = h(1), h3 = h(2);
  return Vector3d(h1 * (mu12 * h2 * h2 - mu31 * h3 * h3) + h2 * h3 * nu23,
                  h2 * (mu23 * h3 * h3 - mu12 * h1 * h1) + h3 * h1 * nu31,
                  h3 * (mu31 * h1 * h1 - mu23 * h2 * h2) + h1 * h2 * nu12);
}

// eq. (8) + (9) with a displacement direction lambda, typed from the paper.
Vector3d PaperDisplacement(const Vector3d& h, const Vector3d& l, double C10, double C20) {
  const double h1 = h(0), h2 = h(1), h3 = h(2);
  const Vector3d eq8(-(1 - h1 * h1) * l(0) + h1 * h2 * l(1) + h1 * h3 * l(2),
                     -(1 - h2 * h2) * l(1) + h2 * h3 * l(2) + h2 * h1 * l(0),
                     -(1 - h3 * h3) * l(2) + h3 * h1 * l(0) + h3 * h2 * l(1));
  const Vector3d eq9(
      -(1 - h1 * h1) * (1 - 5 * h1 * h1) * l(0) + (1 - 5 * h2 * h2) * h1 * h2 * l(1) + (1 - 5 * h3 * h3) * h1 * h3 * l(2),
      -(1 - h2 * h2) * (1 - 5 * h2 * h2) * l(1) + (1 - 5 * h3 * h3) * h2 * h3 * l(2) + (1 - 5 * h1 * h1) * h2 * h1 * l(0),
      -(1 - h3 * h3) * (1 - 5 * h3 * h3) * l(2) + (1 - 5 * h1 * h1) * h3 * h1 * l(0) + (1 - 5 * h2 * h2) * h3 * h2 * l(1));
  return C10 * eq8 + C20 * eq9;
}

constexpr double kTol = 1e-15;

TEST(DriftModel, FourthHarmonicTermEqualsEq1) {
  for (const Vector3d& h : RandomUnitVectors(500, 1)) {
    EXPECT_TRUE(FourthHarmonicTerm(h, 0.7).isApprox(PaperK0(h, 0.7), 1e-12)) << h.transpose();
    EXPECT_LT((FourthHarmonicTerm(h, 0.7) - PaperK0(h, 0.7)).norm(), kTol * 10);
  }
}

TEST(DriftModel, C1TermEqualsEq10) {
  const Vector3d C1(0.3, -0.2, 0.11);
  for (const Vector3d& h : RandomUnitVectors(500, 2)) {
    EXPECT_LT((C1Term(h, C1) - PaperC1(h, C1)).norm(), 1e-14) << h.transpose();
  }
}

TEST(DriftModel, C2TermEqualsEq10) {
  const Vector3d C2(-0.15, 0.05, 0.4);
  for (const Vector3d& h : RandomUnitVectors(500, 3)) {
    EXPECT_LT((C2Term(h, C2) - PaperC2(h, C2)).norm(), 1e-14) << h.transpose();
  }
}

TEST(DriftModel, UnequalStiffnessTermEqualsEq1) {
  for (const Vector3d& h : RandomUnitVectors(500, 4)) {
    const Vector3d got = UnequalStiffnessTerm(h, Vector3d(0.1, 0.2, 0.3), Vector3d(0.4, 0.5, 0.6));
    EXPECT_LT((got - PaperMuNu(h, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6)).norm(), 1e-14);
  }
}

TEST(DriftModel, DisplacementTermsEqualEq8PlusEq9) {
  // A displacement (in any units) maps through DisplacementToC1C2 to the C1, C2 of eq. (10)
  // whose drift equals eq. (8) + eq. (9) with C10 and C20 scaled by the displacement size.
  const Vector3d displacement(0.6, -1.2, 0.4);
  const double c10_per_unit = 0.05, c20_per_unit = 0.02;
  const DisplacementTerms t = DisplacementToC1C2(displacement, c10_per_unit, c20_per_unit);
  const double size = displacement.norm();
  for (const Vector3d& h : RandomUnitVectors(300, 5)) {
    const Vector3d expected = PaperDisplacement(h, displacement / size, c10_per_unit * size, c20_per_unit * size);
    EXPECT_LT((C1Term(h, t.C1) + C2Term(h, t.C2) - expected).norm(), 1e-14);
  }
  EXPECT_NEAR(std::abs(t.C1.normalized().dot(t.C2.normalized())), 1.0, 1e-15);
}

TEST(DriftModel, ProjectedTermsArePerpendicularToSpinAxis) {
  for (const Vector3d& h : RandomUnitVectors(500, 6)) {
    EXPECT_NEAR(FourthHarmonicTerm(h, 1.0).dot(h), 0.0, 1e-15);
    EXPECT_NEAR(C1Term(h, Vector3d(1, -2, 3)).dot(h), 0.0, 1e-14);
    EXPECT_NEAR(C2Term(h, Vector3d(-1, 2, 0.5)).dot(h), 0.0, 1e-14);
    EXPECT_NEAR(UnequalStiffnessTerm(h, Vector3d(1, 2, 3), Vector3d::Zero()).dot(h), 0.0, 1e-14);
  }
}

TEST(DriftModel, NuTermAlongSpinAxisIsTheSumTermOnly) {
  // The printed nu part is perpendicular to h except for h1 h2 h3 (nu23 + nu31 + nu12), which
  // lies along h and does not move the axis (docs/decisions.md).
  const Vector3d nu(0.4, -0.1, 0.25);
  for (const Vector3d& h : RandomUnitVectors(300, 7)) {
    const double along = UnequalStiffnessTerm(h, Vector3d::Zero(), nu).dot(h);
    EXPECT_NEAR(along, h(0) * h(1) * h(2) * nu.sum(), 1e-15);
  }
  const Vector3d traceless(0.4, -0.1, -0.3);
  for (const Vector3d& h : RandomUnitVectors(300, 8)) {
    EXPECT_NEAR(UnequalStiffnessTerm(h, Vector3d::Zero(), traceless).dot(h), 0.0, 1e-15);
  }
}

TEST(DriftModel, RegressorTimesCoefficientsEqualsDrift) {
  std::mt19937_64 rng(9);
  std::normal_distribution<double> normal;
  for (const Vector3d& h : RandomUnitVectors(200, 10)) {
    DriftVector theta;
    for (int i = 0; i < kNumDriftCoefficients; ++i) theta(i) = normal(rng);
    const DriftCoefficients c = DriftCoefficients::FromVector(theta);
    EXPECT_LT((DriftRegressor(h) * theta - DriftRate_k(c, h)).norm(), 1e-13);
    EXPECT_EQ(c.AsVector(), theta);
  }
}

TEST(DriftModel, OffsetVoltageToDisplacementIsEq3) {
  // eq. (3): k = 200, U0 = 200 V, d0 = 30 um gives 0.03 um per mV (the paper's example).
  const double displacement = DisplacementFromOffsetVoltage(1e-3, 200.0, 200.0, 30e-6);
  EXPECT_NEAR(displacement, 0.03e-6, 1e-18);
  EXPECT_NEAR(OffsetVoltageFromDisplacement(1e-6, 200.0, 200.0, 30e-6), 1.0 / 30.0, 1e-15);
}

}  // namespace
}  // namespace esg::estimator
