// Deterministic ESG drift model, the paper's eq. (1), (8)-(10) (docs/physics.md, "Drift model").
//
// Every term gives the drift angular velocity dw_k of the spin axis in case axes [rad/s] as a
// function of the spin-axis direction cosines h_k. The k0, C1 and C2 terms share the projected
// force-function-gradient form (docs/physics.md)
//     dw_k = (h h^T - I) g(h),   g(h) = k0 h^3 + C1 + C2 h^2   (elementwise powers),
// which equals the printed component formulas of eq. (1), (8)-(10). The unequal-stiffness terms
// mu, nu of eq. (1) are implemented as printed. The mu part is perpendicular to h; the printed
// nu part has a component along h equal to h1 h2 h3 (nu23 + nu31 + nu12) h, which does not move
// the spin axis (dh/dt = dw x h), so only its perpendicular part matters (docs/decisions.md).
//
// The model is linear in its 13 coefficients theta = [k0, C1(3), C2(3), mu(3), nu(3)]:
//     dw_k = DriftRegressor(h_k) * theta.
#ifndef ESG_ESTIMATOR_DRIFT_MODEL_H_
#define ESG_ESTIMATOR_DRIFT_MODEL_H_

#include <array>
#include <vector>

#include "Eigen/Core"

namespace esg::estimator {

inline constexpr int kNumDriftCoefficients = 13;
// Offsets into theta.
inline constexpr int kThetaK0 = 0;
inline constexpr int kThetaC1 = 1;
inline constexpr int kThetaC2 = 4;
inline constexpr int kThetaMu = 7;
inline constexpr int kThetaNu = 10;

using DriftVector = Eigen::Matrix<double, kNumDriftCoefficients, 1>;
using DriftRegressorMatrix = Eigen::Matrix<double, 3, kNumDriftCoefficients>;

// Coefficients of eq. (1) and (10) [rad/s]. mu = (mu12, mu23, mu31), nu = (nu23, nu31, nu12).
struct DriftCoefficients {
  double k0 = 0.0;
  Eigen::Vector3d C1 = Eigen::Vector3d::Zero();
  Eigen::Vector3d C2 = Eigen::Vector3d::Zero();
  Eigen::Vector3d mu = Eigen::Vector3d::Zero();
  Eigen::Vector3d nu = Eigen::Vector3d::Zero();

  DriftVector AsVector() const;
  static DriftCoefficients FromVector(const DriftVector& theta);
  bool IsZero() const { return AsVector().isZero(0.0); }
};

// Individual terms, dw_k [rad/s] for unit h_k.
Eigen::Vector3d FourthHarmonicTerm(const Eigen::Vector3d& h_k, double k0);  // eq. (1), k0 part
Eigen::Vector3d C1Term(const Eigen::Vector3d& h_k, const Eigen::Vector3d& C1);  // eq. (8), (10)
Eigen::Vector3d C2Term(const Eigen::Vector3d& h_k, const Eigen::Vector3d& C2);  // eq. (9), (10)
Eigen::Vector3d UnequalStiffnessTerm(const Eigen::Vector3d& h_k, const Eigen::Vector3d& mu,
                                     const Eigen::Vector3d& nu);  // eq. (1), mu/nu part

// Full drift dw_k [rad/s], sum of all terms.
Eigen::Vector3d DriftRate_k(const DriftCoefficients& coefficients, const Eigen::Vector3d& h_k);

// d(dw_k)/d(theta), 3 x 13; DriftRate_k(c, h) == DriftRegressor(h) * c.AsVector().
DriftRegressorMatrix DriftRegressor(const Eigen::Vector3d& h_k);

// Coefficient theta[i]'s regressor as monomials h1^a h2^b h3^c along case axis `axis` (1..3) with
// a sign, up to its part along h, which moves nothing (the basis's spin_axis_harmonic terms,
// basis_term.h): k0, C1, C2 have dw = (h h^T - I) g(h) = -(g(h) across h), g = k0 h^3 + C1 +
// C2 h^2; mu, nu as printed in eq. (1) (x = h1 (mu12 h2^2 - mu31 h3^2) + h2 h3 nu23, cyclic).
// Empty for an index outside theta.
struct CoefficientMonomial {
  int axis = 1;
  std::array<int, 3> exponents = {0, 0, 0};
  double sign = 1.0;
};
std::vector<CoefficientMonomial> CoefficientMonomials(int i);

// Rotor displacement -> C1, C2 (eq. (8)-(10), docs/physics.md): with lambda the unit displacement
// direction in case axes, C1 = (C10 + C20) lambda and C2 = -5 C20 lambda, where C10 and C20
// scale with the displacement size: C10 = c10_per_m * |Delta|, C20 = c20_per_m * |Delta|.
struct DisplacementTerms {
  Eigen::Vector3d C1;
  Eigen::Vector3d C2;
};
DisplacementTerms DisplacementToC1C2(const Eigen::Vector3d& displacement_k, double c10_per_m,
                                     double c20_per_m);

// eq. (3): rotor displacement along one suspension axis from its offset voltage,
// Delta = k dU d0 / U0 [m] (dU [V], U0 [V], d0 [m]); and the inverse.
double DisplacementFromOffsetVoltage(double dU, double amplifier_gain, double reference_voltage,
                                     double gap);
double OffsetVoltageFromDisplacement(double displacement, double amplifier_gain,
                                     double reference_voltage, double gap);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_DRIFT_MODEL_H_
