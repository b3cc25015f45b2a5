#include "estimator/drift_model.h"

namespace esg::estimator {

using Eigen::Vector3d;

DriftVector DriftCoefficients::AsVector() const {
  DriftVector theta;
  theta(kThetaK0) = k0;
  theta.segment<3>(kThetaC1) = C1;
  theta.segment<3>(kThetaC2) = C2;
  theta.segment<3>(kThetaMu) = mu;
  theta.segment<3>(kThetaNu) = nu;
  return theta;
}

DriftCoefficients DriftCoefficients::FromVector(const DriftVector& theta) {
  DriftCoefficients c;
  c.k0 = theta(kThetaK0);
  c.C1 = theta.segment<3>(kThetaC1);
  c.C2 = theta.segment<3>(kThetaC2);
  c.mu = theta.segment<3>(kThetaMu);
  c.nu = theta.segment<3>(kThetaNu);
  return c;
}

namespace {

// docs/physics.md, "One form for k0, C1, C2": dw = (h h^T - I) g.
Vector3d ProjectGradient(const Vector3d& h, const Vector3d& g) { return h * h.dot(g) - g; }

}  // namespace

Vector3d FourthHarmonicTerm(const Vector3d& h_k, double k0) {
  // eq. (1): g = k0 h^3.
  return ProjectGradient(h_k, k0 * h_k.array().cube().matrix());
}

Vector3d C1Term(const Vector3d& h_k, const Vector3d& C1) {
  // eq. (8), (10): g = C1.
  return ProjectGradient(h_k, C1);
}

Vector3d C2Term(const Vector3d& h_k, const Vector3d& C2) {
  // eq. (9), (10): g = C2 h^2.
  return ProjectGradient(h_k, C2.cwiseProduct(h_k.cwiseAbs2()));
}

Vector3d UnequalStiffnessTerm(const Vector3d& h_k, const Vector3d& mu, const Vector3d& nu) {
  // eq. (1): x = h1 (mu12 h2^2 - mu31 h3^2) + h2 h3 nu23, cyclic for y, z.
  // mu = (mu12, mu23, mu31), nu = (nu23, nu31, nu12).
  const double h1 = h_k.x(), h2 = h_k.y(), h3 = h_k.z();
  return Vector3d(h1 * (mu(0) * h2 * h2 - mu(2) * h3 * h3) + h2 * h3 * nu(0),
                  h2 * (mu(1) * h3 * h3 - mu(0) * h1 * h1) + h3 * h1 * nu(1),
                  h3 * (mu(2) * h1 * h1 - mu(1) * h2 * h2) + h1 * h2 * nu(2));
}

Vector3d DriftRate_k(const DriftCoefficients& c, const Vector3d& h_k) {
  return FourthHarmonicTerm(h_k, c.k0) + C1Term(h_k, c.C1) + C2Term(h_k, c.C2) +
         UnequalStiffnessTerm(h_k, c.mu, c.nu);
}

DriftRegressorMatrix DriftRegressor(const Vector3d& h_k) {
  DriftRegressorMatrix B;
  const Eigen::Matrix3d P = h_k * h_k.transpose() - Eigen::Matrix3d::Identity();
  B.col(kThetaK0) = P * h_k.array().cube().matrix();
  B.block<3, 3>(0, kThetaC1) = P;
  B.block<3, 3>(0, kThetaC2) = P * h_k.cwiseAbs2().asDiagonal();
  const double h1 = h_k.x(), h2 = h_k.y(), h3 = h_k.z();
  B.block<3, 3>(0, kThetaMu) << h1 * h2 * h2, 0.0, -h1 * h3 * h3,  //
      -h2 * h1 * h1, h2 * h3 * h3, 0.0,                              //
      0.0, -h3 * h2 * h2, h3 * h1 * h1;
  B.block<3, 3>(0, kThetaNu) << h2 * h3, 0.0, 0.0,  //
      0.0, h3 * h1, 0.0,                              //
      0.0, 0.0, h1 * h2;
  return B;
}

DisplacementTerms DisplacementToC1C2(const Vector3d& displacement_k, double c10_per_m,
                                     double c20_per_m) {
  const double size = displacement_k.norm();
  if (size == 0.0) return {Vector3d::Zero(), Vector3d::Zero()};
  const Vector3d lambda = displacement_k / size;
  const double C10 = c10_per_m * size;
  const double C20 = c20_per_m * size;
  // eq. (8)-(10) (sign of C2 as implied by eq. (9) against eq. (10), docs/decisions.md D3).
  return {(C10 + C20) * lambda, -5.0 * C20 * lambda};
}

double DisplacementFromOffsetVoltage(double dU, double amplifier_gain, double reference_voltage,
                                     double gap) {
  // eq. (3).
  return amplifier_gain * dU * gap / reference_voltage;
}

double OffsetVoltageFromDisplacement(double displacement, double amplifier_gain,
                                     double reference_voltage, double gap) {
  return displacement * reference_voltage / (amplifier_gain * gap);
}

std::vector<CoefficientMonomial> CoefficientMonomials(int i) {
  if (i == kThetaK0) return {{1, {3, 0, 0}, -1}, {2, {0, 3, 0}, -1}, {3, {0, 0, 3}, -1}};
  if (i >= kThetaC1 && i < kThetaC1 + 3) return {{i - kThetaC1 + 1, {0, 0, 0}, -1}};
  if (i >= kThetaC2 && i < kThetaC2 + 3) {
    std::array<int, 3> e = {0, 0, 0};
    e[i - kThetaC2] = 2;
    return {{i - kThetaC2 + 1, e, -1}};
  }
  switch (i) {
    case kThetaMu + 0:  // mu12: x h1 h2^2, y -h2 h1^2
      return {{1, {1, 2, 0}, 1}, {2, {2, 1, 0}, -1}};
    case kThetaMu + 1:  // mu23: y h2 h3^2, z -h3 h2^2
      return {{2, {0, 1, 2}, 1}, {3, {0, 2, 1}, -1}};
    case kThetaMu + 2:  // mu31: z h3 h1^2, x -h1 h3^2
      return {{3, {2, 0, 1}, 1}, {1, {1, 0, 2}, -1}};
    case kThetaNu + 0:  // nu23: x h2 h3
      return {{1, {0, 1, 1}, 1}};
    case kThetaNu + 1:  // nu31: y h3 h1
      return {{2, {1, 0, 1}, 1}};
    case kThetaNu + 2:  // nu12: z h1 h2
      return {{3, {1, 1, 0}, 1}};
    default:
      return {};
  }
}

}  // namespace esg::estimator
