// Jacobians of the eq. (13) measurements against central differences of the measurement built
// from a perturbed "true" world (GTSAM numericalDerivative style), with the error convention of
// conventions.h. Step 1e-6 rad: the measurement is smooth, truncation ~1e-12, rounding ~1e-10;
// the tolerance 1e-7 is far above both and far below any sign or factor error (~1).
#include "estimator/measurements.h"

#include <functional>
#include <random>

#include "estimator/rotation.h"
#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;
using Eigen::VectorXd;
using Matrix32 = Eigen::Matrix<double, 3, 2>;

constexpr double kStep = 1e-6;
constexpr double kTol = 1e-7;

Eigen::MatrixXd NumericalJacobian(const std::function<VectorXd(const VectorXd&)>& f, int n) {
  const VectorXd f0 = f(VectorXd::Zero(n));
  Eigen::MatrixXd J(f0.size(), n);
  for (int i = 0; i < n; ++i) {
    VectorXd e = VectorXd::Zero(n);
    e(i) = kStep;
    J.col(i) = (f(e) - f(-e)) / (2 * kStep);
  }
  return J;
}

struct World {
  Matrix3d C_in_b;   // true attitude
  Matrix3d C_b_k_a;  // estimated mountings
  Matrix3d C_b_k_b;
  Vector3d h_in_a;   // estimated (predicted) axes
  Vector3d h_in_b;
  Matrix32 T_a, T_b;
};

World RandomWorld(uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> n;
  auto vec = [&] { return Vector3d(n(rng), n(rng), n(rng)); };
  World w;
  w.C_in_b = ExpMatrix(vec());
  w.C_b_k_a = ExpMatrix(vec());
  w.C_b_k_b = ExpMatrix(vec());
  w.h_in_a = vec().normalized();
  w.h_in_b = vec().normalized();
  w.T_a = TangentBasis(w.h_in_a);
  w.T_b = TangentBasis(w.h_in_b);
  return w;
}

// The case-frame reading of a gyro whose true axis is h_true and true mounting C_b_k_true,
// with readout noise r in the tangent plane of the noise-free reading.
Vector3d Reading(const World& w, const Vector3d& h_true, const Matrix3d& C_b_k_true, const Eigen::Vector2d& r) {
  const Vector3d h_k = (C_b_k_true.transpose() * w.C_in_b.transpose() * h_true).normalized();
  return (h_k + TangentBasis(h_k) * r).normalized();
}

TEST(Measurements, StarTrackerDifferenceJacobiansMatchCentralDifferences) {
  for (uint64_t seed = 1; seed <= 20; ++seed) {
    const World w = RandomWorld(seed);
    // Parameters: dx_h (2), dphi (3), n_st (3), r (2).
    auto z = [&](const VectorXd& p) {
      const Vector3d h_true = (w.h_in_a + w.T_a * p.segment<2>(0)).normalized();
      const Matrix3d C_b_k_true = ExpMatrix(p.segment<3>(2)) * w.C_b_k_a;
      const Vector3d h_k = Reading(w, h_true, C_b_k_true, p.segment<2>(8));
      const Matrix3d C_in_b_st = w.C_in_b * ExpMatrix(p.segment<3>(5));
      return VectorXd(MakeStarTrackerDifference(w.h_in_a, w.T_a, C_in_b_st, w.C_b_k_a, h_k).z);
    };
    const Eigen::MatrixXd J = NumericalJacobian(z, 10);
    // The analytic Jacobians at the unperturbed point (reading noise-free, star tracker exact).
    const Vector3d h_k0 = Reading(w, w.h_in_a, w.C_b_k_a, Eigen::Vector2d::Zero());
    const StarTrackerDifference d = MakeStarTrackerDifference(w.h_in_a, w.T_a, w.C_in_b, w.C_b_k_a, h_k0);
    EXPECT_NEAR(d.z.norm(), 0.0, 1e-12);
    EXPECT_LT((J.block(0, 0, 2, 2) - d.H_h).norm(), kTol) << "seed " << seed;
    EXPECT_LT((J.block(0, 2, 2, 3) - d.H_phi).norm(), kTol) << "seed " << seed;
    EXPECT_LT((J.block(0, 5, 2, 3) - d.G_st).norm(), kTol) << "seed " << seed;
    EXPECT_LT((J.block(0, 8, 2, 2) - d.G_readout).norm(), kTol) << "seed " << seed;
  }
}

TEST(Measurements, AutonomousDifferenceJacobiansMatchCentralDifferences) {
  for (uint64_t seed = 1; seed <= 20; ++seed) {
    const World w = RandomWorld(100 + seed);
    // Parameters: dx_a (2), dx_b (2), dphi_a (3), dphi_b (3), r_a (2), r_b (2).
    auto z = [&](const VectorXd& p) {
      const Vector3d ha = (w.h_in_a + w.T_a * p.segment<2>(0)).normalized();
      const Vector3d hb = (w.h_in_b + w.T_b * p.segment<2>(2)).normalized();
      const Vector3d hka = Reading(w, ha, ExpMatrix(p.segment<3>(4)) * w.C_b_k_a, p.segment<2>(10));
      const Vector3d hkb = Reading(w, hb, ExpMatrix(p.segment<3>(7)) * w.C_b_k_b, p.segment<2>(12));
      VectorXd out(1);
      out(0) = MakeAutonomousDifference(w.h_in_a, w.T_a, w.C_b_k_a, hka, w.h_in_b, w.T_b, w.C_b_k_b, hkb).z;
      return out;
    };
    const Eigen::MatrixXd J = NumericalJacobian(z, 14);
    const Vector3d hka0 = Reading(w, w.h_in_a, w.C_b_k_a, Eigen::Vector2d::Zero());
    const Vector3d hkb0 = Reading(w, w.h_in_b, w.C_b_k_b, Eigen::Vector2d::Zero());
    const AutonomousDifference d =
        MakeAutonomousDifference(w.h_in_a, w.T_a, w.C_b_k_a, hka0, w.h_in_b, w.T_b, w.C_b_k_b, hkb0);
    EXPECT_NEAR(d.z, 0.0, 1e-12);
    EXPECT_LT((J.block(0, 0, 1, 2) - d.H_h_a).norm(), kTol) << "seed " << seed;
    EXPECT_LT((J.block(0, 2, 1, 2) - d.H_h_b).norm(), kTol) << "seed " << seed;
    EXPECT_LT((J.block(0, 4, 1, 3) - d.H_phi_a).norm(), kTol) << "seed " << seed;
    EXPECT_LT((J.block(0, 7, 1, 3) - d.H_phi_b).norm(), kTol) << "seed " << seed;
    EXPECT_LT((J.block(0, 10, 1, 2) - d.G_readout_a).norm(), kTol) << "seed " << seed;
    EXPECT_LT((J.block(0, 12, 1, 2) - d.G_readout_b).norm(), kTol) << "seed " << seed;
  }
}

}  // namespace
}  // namespace esg::estimator
