// The simulator's true ESG drift, typed from the paper's printed component formulas: eq. (1)
// (k0 and the unequal-stiffness terms mu, nu), eq. (10) (the coefficients C1, C2) and eq. (8),
// (9) (a rotor displaced by Delta along the unit direction lambda).
//
// This file deliberately does not call the filter's drift model (estimator/drift_model.h:
// DriftRate_k, the term functions, DriftRegressor, DisplacementToC1C2). The filter computes the
// same drift in another form (a gradient projected perpendicular to h, and a regressor linear in
// the 13 coefficients); the truth here writes every component out as printed. A sign or index
// slip on either side therefore shows as a disagreement between the two, which the tests check
// (tests/estimator/simulator_test.cc, tests/estimator/drift_model_test.cc). Only the plain data
// type DriftCoefficients is shared; the printed formulas (simulator_truth.cc) read its components
// by the paper's names through its documented layout (drift_model.h), the one place here that
// names the coefficients one by one (estimator/model_terms.h lists the others).
//
// All rates [rad/s], components in the gyro case axes k; h_k is the unit spin axis in case axes.
#ifndef ESG_ESTIMATOR_SIMULATOR_TRUTH_H_
#define ESG_ESTIMATOR_SIMULATOR_TRUTH_H_

#include "Eigen/Core"
#include "estimator/drift_model.h"

namespace esg::estimator::simulator_truth {

// One gyro's true drift as the paper writes it.
struct PrintedDrift {
  // The coefficients of eq. (1) and (10) [rad/s].
  DriftCoefficients coefficients;
  // Rotor displacement, eq. (8), (9): unit direction lambda (zero when there is none) and the
  // sizes C10, C20 [rad/s], which scale with the displacement length.
  Eigen::Vector3d lambda = Eigen::Vector3d::Zero();
  double C10 = 0.0;
  double C20 = 0.0;
};

// model: the eq. (1)/(10) coefficients; rotor_displacement_k [m] in case axes; C10 and C20 are
// c10_per_m |Delta| and c20_per_m |Delta| [rad/s] with lambda = Delta / |Delta|.
PrintedDrift FromGyroTruth(const DriftCoefficients& model,
                           const Eigen::Vector3d& rotor_displacement_k, double c10_per_m,
                           double c20_per_m);

// The true drift dw_k [rad/s] at the unit spin axis h_k: the sum of the printed components of
// eq. (1) (k0, mu, nu), eq. (10) (C1, C2) and eq. (8) + eq. (9) (lambda, C10, C20).
Eigen::Vector3d TrueDriftRate_k(const PrintedDrift& drift, const Eigen::Vector3d& h_k);

// The eq. (10) coefficients that give the same drift as `drift` (what a calibration should
// recover): eq. (8) is eq. (10)'s C1 part with C1 = C10 lambda; eq. (9) expands to
// C20 [eq. (8) bracket] - 5 C20 [eq. (10) C2 bracket], so the displacement adds
// C1 += (C10 + C20) lambda and C2 += -5 C20 lambda (the minus sign follows from expanding eq. (9);
// the paper's text after eq. (9) prints C2i = 5 C20 lambda_i without it).
DriftCoefficients EquivalentCoefficients(const PrintedDrift& drift);

}  // namespace esg::estimator::simulator_truth

#endif  // ESG_ESTIMATOR_SIMULATOR_TRUTH_H_
