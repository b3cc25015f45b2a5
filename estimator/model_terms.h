// The fixed terms of the drift model, eq. (1), (8)-(10) (docs/physics.md, "Drift model"): one
// descriptor per scalar coefficient of theta = [k0, C1(3), C2(3), mu(3), nu(3)] (drift_model.h),
// the one table every name of a coefficient is read from: the configuration's JSON keys
// (docs/formats.md), the filter's reports (calibration_model.h CoefficientName), the storage keys
// (storage/records.h), the CLI's history columns and the console's labels
// (console/plugin/series.js, checked against this table by tests/estimator/model_terms_test.cc).
//
// Every coefficient is a drift angular velocity of the spin axis in case axes k (docs/
// conventions.md, "Drift"), in rad/s inside the estimator and in deg/h in every exchange format.
// Component order: C1 = (C11, C12, C13) and C2 = (C21, C22, C23) along case axes x, y, z;
// mu = (mu12, mu23, mu31); nu = (nu23, nu31, nu12) (drift_model.h).
#ifndef ESG_ESTIMATOR_MODEL_TERMS_H_
#define ESG_ESTIMATOR_MODEL_TERMS_H_

#include <array>
#include <string>

#include "absl/strings/string_view.h"
#include "estimator/drift_model.h"

namespace esg::estimator {

struct FixedTermDescriptor {
  // Paper symbol of the term the coefficient belongs to: "k0", "C1", "C2", "mu", "nu".
  absl::string_view symbol;
  // Name for people, the component's symbol: "k0", "C11", ..., "mu12", ..., "nu12". The
  // console's telemetry key is its lower case ("c11").
  absl::string_view label;
  // Key of the term in the configuration's GyroDriftModel JSON ("k0DegH", "c1DegH"), and the
  // coefficient's index in that key's array (-1: the key holds a number).
  absl::string_view json_key;
  int component;
  // Unit of every exchange format (JSON, storage, CLI, console); SI inside is rad/s.
  absl::string_view unit;
  // Frame of the drift vector the coefficient scales (conventions.h frame tag).
  absl::string_view frame;
  // Offset in theta (drift_model.h): the regressor column, and the coefficient's filter state
  // when free (state_layout.h Theta(i) + position among the free ones).
  int theta_index;
  // Stem of its storage keys and CSV columns: "<key>_<unit>" for the value and
  // "<key>_sigma_<unit>" for its 1-sigma (storage/records.h; the unit with '/' written '_'),
  // "c1x", "mu12". Its part after the symbol ("x", "12") names the component in the CLI table.
  absl::string_view storage_key;
};

inline constexpr std::array<FixedTermDescriptor, kNumDriftCoefficients> kFixedTerms = {{
    {"k0", "k0", "k0DegH", -1, "deg/h", "k", kThetaK0, "k0"},
    {"C1", "C11", "c1DegH", 0, "deg/h", "k", kThetaC1 + 0, "c1x"},
    {"C1", "C12", "c1DegH", 1, "deg/h", "k", kThetaC1 + 1, "c1y"},
    {"C1", "C13", "c1DegH", 2, "deg/h", "k", kThetaC1 + 2, "c1z"},
    {"C2", "C21", "c2DegH", 0, "deg/h", "k", kThetaC2 + 0, "c2x"},
    {"C2", "C22", "c2DegH", 1, "deg/h", "k", kThetaC2 + 1, "c2y"},
    {"C2", "C23", "c2DegH", 2, "deg/h", "k", kThetaC2 + 2, "c2z"},
    {"mu", "mu12", "muDegH", 0, "deg/h", "k", kThetaMu + 0, "mu12"},
    {"mu", "mu23", "muDegH", 1, "deg/h", "k", kThetaMu + 1, "mu23"},
    {"mu", "mu31", "muDegH", 2, "deg/h", "k", kThetaMu + 2, "mu31"},
    {"nu", "nu23", "nuDegH", 0, "deg/h", "k", kThetaNu + 0, "nu23"},
    {"nu", "nu31", "nuDegH", 1, "deg/h", "k", kThetaNu + 1, "nu31"},
    {"nu", "nu12", "nuDegH", 2, "deg/h", "k", kThetaNu + 2, "nu12"},
}};

// The table is in theta order: kFixedTerms[i].theta_index == i.
constexpr bool FixedTermsInThetaOrder() {
  for (int i = 0; i < kNumDriftCoefficients; ++i) {
    if (kFixedTerms[i].theta_index != i) return false;
  }
  return true;
}
static_assert(FixedTermsInThetaOrder(), "kFixedTerms must list theta in order");

// The coefficient's JSON path below a GyroDriftModel: "k0DegH", "c1DegH[0]".
std::string FixedTermJsonName(const FixedTermDescriptor& term);

// Storage and CSV column names of the value and of its 1-sigma: "c1x_deg_h", "c1x_sigma_deg_h".
std::string FixedTermValueColumn(const FixedTermDescriptor& term);
std::string FixedTermSigmaColumn(const FixedTermDescriptor& term);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_MODEL_TERMS_H_
