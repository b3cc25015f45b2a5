#include "estimator/simulator_truth.h"

namespace esg::estimator::simulator_truth {

using Eigen::Vector3d;

namespace {

// Powers of the direction cosines, computed once per evaluation.
struct Cosines {
  double h1, h2, h3;
  double h1_2, h2_2, h3_2;  // squares
  explicit Cosines(const Vector3d& h)
      : h1(h.x()), h2(h.y()), h3(h.z()), h1_2(h1 * h1), h2_2(h2 * h2), h3_2(h3 * h3) {}
};

// eq. (1), k0 part: x = h1 [-(1 - h1^2) h1^2 + h2^4 + h3^4] k0; y, z by cyclic permutation.
Vector3d Eq1K0(const Cosines& c, double k0) {
  const double h1_4 = c.h1_2 * c.h1_2, h2_4 = c.h2_2 * c.h2_2, h3_4 = c.h3_2 * c.h3_2;
  return k0 * Vector3d(c.h1 * (-(1.0 - c.h1_2) * c.h1_2 + h2_4 + h3_4),
                       c.h2 * (-(1.0 - c.h2_2) * c.h2_2 + h3_4 + h1_4),
                       c.h3 * (-(1.0 - c.h3_2) * c.h3_2 + h1_4 + h2_4));
}

// The unequal-stiffness coefficients of eq. (1) by their printed names, read through the
// DriftCoefficients layout mu = (mu12, mu23, mu31), nu = (nu23, nu31, nu12) (drift_model.h).
struct Stiffness {
  double mu12, mu23, mu31, nu23, nu31, nu12;
  explicit Stiffness(const DriftCoefficients& m)
      : mu12(m.mu(0)), mu23(m.mu(1)), mu31(m.mu(2)), nu23(m.nu(0)), nu31(m.nu(1)), nu12(m.nu(2)) {}
  bool IsZero() const {
    return mu12 == 0.0 && mu23 == 0.0 && mu31 == 0.0 && nu23 == 0.0 && nu31 == 0.0 && nu12 == 0.0;
  }
};

// eq. (1), unequal stiffness: x = h1 (mu12 h2^2 - mu31 h3^2) + h2 h3 nu23; cyclic
// (mu12 -> mu23 -> mu31, nu23 -> nu31 -> nu12).
Vector3d Eq1MuNu(const Cosines& c, const Stiffness& d) {
  return Vector3d(c.h1 * (d.mu12 * c.h2_2 - d.mu31 * c.h3_2) + c.h2 * c.h3 * d.nu23,
                  c.h2 * (d.mu23 * c.h3_2 - d.mu12 * c.h1_2) + c.h3 * c.h1 * d.nu31,
                  c.h3 * (d.mu31 * c.h1_2 - d.mu23 * c.h2_2) + c.h1 * c.h2 * d.nu12);
}

// eq. (10), C1 bracket: x = -(1 - h1^2) C11 + h1 h2 C12 + h1 h3 C13; cyclic.
Vector3d Eq10C1(const Cosines& c, const Vector3d& C1) {
  const double C11 = C1.x(), C12 = C1.y(), C13 = C1.z();
  return Vector3d(-(1.0 - c.h1_2) * C11 + c.h1 * c.h2 * C12 + c.h1 * c.h3 * C13,
                  -(1.0 - c.h2_2) * C12 + c.h2 * c.h3 * C13 + c.h2 * c.h1 * C11,
                  -(1.0 - c.h3_2) * C13 + c.h3 * c.h1 * C11 + c.h3 * c.h2 * C12);
}

// eq. (10), C2 bracket: x = -(1 - h1^2) h1^2 C21 + h1 h2^3 C22 + h1 h3^3 C23; cyclic.
Vector3d Eq10C2(const Cosines& c, const Vector3d& C2) {
  const double C21 = C2.x(), C22 = C2.y(), C23 = C2.z();
  const double h1_3 = c.h1_2 * c.h1, h2_3 = c.h2_2 * c.h2, h3_3 = c.h3_2 * c.h3;
  return Vector3d(-(1.0 - c.h1_2) * c.h1_2 * C21 + c.h1 * h2_3 * C22 + c.h1 * h3_3 * C23,
                  -(1.0 - c.h2_2) * c.h2_2 * C22 + c.h2 * h3_3 * C23 + c.h2 * h1_3 * C21,
                  -(1.0 - c.h3_2) * c.h3_2 * C23 + c.h3 * h1_3 * C21 + c.h3 * h2_3 * C22);
}

// eq. (8), harmonic n = 1, as printed for x, y and z.
Vector3d Eq8(const Cosines& c, const Vector3d& lambda, double C10) {
  const double l1 = lambda.x(), l2 = lambda.y(), l3 = lambda.z();
  return C10 * Vector3d(-(1.0 - c.h1_2) * l1 + c.h1 * c.h2 * l2 + c.h1 * c.h3 * l3,
                        -(1.0 - c.h2_2) * l2 + c.h2 * c.h3 * l3 + c.h2 * c.h1 * l1,
                        -(1.0 - c.h3_2) * l3 + c.h3 * c.h1 * l1 + c.h3 * c.h2 * l2);
}

// eq. (9), harmonic n = 3, as printed for x, y and z.
Vector3d Eq9(const Cosines& c, const Vector3d& lambda, double C20) {
  const double l1 = lambda.x(), l2 = lambda.y(), l3 = lambda.z();
  const double f1 = 1.0 - 5.0 * c.h1_2, f2 = 1.0 - 5.0 * c.h2_2, f3 = 1.0 - 5.0 * c.h3_2;
  return C20 * Vector3d(-(1.0 - c.h1_2) * f1 * l1 + f2 * c.h1 * c.h2 * l2 + f3 * c.h1 * c.h3 * l3,
                        -(1.0 - c.h2_2) * f2 * l2 + f3 * c.h2 * c.h3 * l3 + f1 * c.h2 * c.h1 * l1,
                        -(1.0 - c.h3_2) * f3 * l3 + f1 * c.h3 * c.h1 * l1 + f2 * c.h3 * c.h2 * l2);
}

}  // namespace

PrintedDrift FromGyroTruth(const DriftCoefficients& model, const Vector3d& rotor_displacement_k,
                           double c10_per_m, double c20_per_m) {
  PrintedDrift d;
  d.coefficients = model;
  const double size = rotor_displacement_k.norm();
  if (size > 0.0) {
    d.lambda = rotor_displacement_k / size;
    d.C10 = c10_per_m * size;
    d.C20 = c20_per_m * size;
  }
  return d;
}

Vector3d TrueDriftRate_k(const PrintedDrift& d, const Vector3d& h_k) {
  const Cosines c(h_k);
  const DriftCoefficients& m = d.coefficients;
  Vector3d dw_k = Eq1K0(c, m.k0) + Eq10C1(c, m.C1) + Eq10C2(c, m.C2);
  // Terms with all coefficients zero add exactly zero; skip them (this runs at the integration
  // rate for every gyro).
  const Stiffness stiffness(m);
  if (!stiffness.IsZero()) dw_k += Eq1MuNu(c, stiffness);
  if (d.C10 != 0.0 || d.C20 != 0.0) dw_k += Eq8(c, d.lambda, d.C10) + Eq9(c, d.lambda, d.C20);
  return dw_k;
}

DriftCoefficients EquivalentCoefficients(const PrintedDrift& d) {
  DriftCoefficients c = d.coefficients;
  c.C1 = d.coefficients.C1 + (d.C10 + d.C20) * d.lambda;
  c.C2 = d.coefficients.C2 - 5.0 * d.C20 * d.lambda;
  return c;
}

}  // namespace esg::estimator::simulator_truth
