// The fixed terms of the drift model, eq. (1), (8)-(10) (docs/physics.md, "Drift model"): one
// descriptor per scalar coefficient of theta = [k0, C1(3), C2(3), mu(3), nu(3)] (drift_model.h),
// the one table every name of a coefficient is read from: the configuration's JSON keys
// (docs/formats.md), the filter's reports (calibration_model.h CoefficientName), the storage keys
// (storage/records.h), the CLI's history columns, calibration output and truth files, the
// scenario's keys, the model strings that take each term (calibration_model.h), the discovery
// effect that frees it (estimator/discovery/candidates.h) and the console's labels
// (console/plugin/series.js, checked against this table by tests/estimator/model_terms_test.cc).
//
// Every coefficient is a drift angular velocity of the spin axis in case axes k (docs/
// conventions.md, "Drift"), in rad/s inside the estimator and in deg/h in every exchange format.
// Component order: C1 = (C11, C12, C13) and C2 = (C21, C22, C23) along case axes x, y, z;
// mu = (mu12, mu23, mu31); nu = (nu23, nu31, nu12) (drift_model.h).
#ifndef ESG_ESTIMATOR_MODEL_TERMS_H_
#define ESG_ESTIMATOR_MODEL_TERMS_H_

#include <array>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/string_view.h"
#include "estimator/drift_model.h"

namespace esg::estimator {

// The parts of a model string (calibration_model.h ParseModel) that take fixed terms, as bits:
// "1" takes the terms of eq. (1), "10" those of eq. (10) and the mu, nu of the full model.
inline constexpr unsigned kModelPart1 = 1u << 0;
inline constexpr unsigned kModelPart10 = 1u << 1;
inline constexpr unsigned kAllModelParts = kModelPart1 | kModelPart10;

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
  // What the term is, in words for people (the console's diagnosis labels: "<label>, <meaning>").
  absl::string_view meaning;
  // The model-string parts that take the term (kModelPart* bits).
  unsigned model_parts;
  // The discovery library's effect that frees the term when the model holds it (docs/
  // discovery.md, "How each effect enters the model"), by its report id; an effect's terms are
  // contiguous in theta (checked by tests/estimator/model_terms_test.cc). Empty: none.
  absl::string_view effect;
};

// clang-format off
inline constexpr std::array<FixedTermDescriptor, kNumDriftCoefficients> kFixedTerms = {{
    {"k0", "k0", "k0DegH", -1, "deg/h", "k", kThetaK0, "k0",
     "4th shape harmonic", kModelPart1 | kModelPart10, "fourth_harmonic"},
    {"C1", "C11", "c1DegH", 0, "deg/h", "k", kThetaC1 + 0, "c1x",
     "rotor displacement (1st harmonic)", kModelPart10, "rotor_displacement"},
    {"C1", "C12", "c1DegH", 1, "deg/h", "k", kThetaC1 + 1, "c1y",
     "rotor displacement (1st harmonic)", kModelPart10, "rotor_displacement"},
    {"C1", "C13", "c1DegH", 2, "deg/h", "k", kThetaC1 + 2, "c1z",
     "rotor displacement (1st harmonic)", kModelPart10, "rotor_displacement"},
    {"C2", "C21", "c2DegH", 0, "deg/h", "k", kThetaC2 + 0, "c2x",
     "rotor displacement (3rd harmonic)", kModelPart10, "rotor_displacement"},
    {"C2", "C22", "c2DegH", 1, "deg/h", "k", kThetaC2 + 1, "c2y",
     "rotor displacement (3rd harmonic)", kModelPart10, "rotor_displacement"},
    {"C2", "C23", "c2DegH", 2, "deg/h", "k", kThetaC2 + 2, "c2z",
     "rotor displacement (3rd harmonic)", kModelPart10, "rotor_displacement"},
    {"mu", "mu12", "muDegH", 0, "deg/h", "k", kThetaMu + 0, "mu12",
     "unequal stiffness", kModelPart1 | kModelPart10, "unequal_stiffness"},
    {"mu", "mu23", "muDegH", 1, "deg/h", "k", kThetaMu + 1, "mu23",
     "unequal stiffness", kModelPart1 | kModelPart10, "unequal_stiffness"},
    {"mu", "mu31", "muDegH", 2, "deg/h", "k", kThetaMu + 2, "mu31",
     "unequal stiffness", kModelPart1 | kModelPart10, "unequal_stiffness"},
    {"nu", "nu23", "nuDegH", 0, "deg/h", "k", kThetaNu + 0, "nu23",
     "unequal stiffness", kModelPart1 | kModelPart10, "unequal_stiffness"},
    {"nu", "nu31", "nuDegH", 1, "deg/h", "k", kThetaNu + 1, "nu31",
     "unequal stiffness", kModelPart1 | kModelPart10, "unequal_stiffness"},
    {"nu", "nu12", "nuDegH", 2, "deg/h", "k", kThetaNu + 2, "nu12",
     "unequal stiffness", kModelPart1 | kModelPart10, "unequal_stiffness"},
}};
// clang-format on

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

// "c1DegH" -> "c1_deg_h": the proto field of a JSON key (the proto3 JSON mapping), also the stem
// of the simulator truth file's coefficient lines (client/commands/simulate.cc).
std::string FixedTermFieldName(absl::string_view json_key);

// One JSON key of the table (a term's symbol, e.g. "c1DegH" for C1), in theta order: the theta
// index of its first coefficient and its number of components (0: the key holds one number).
struct FixedTermKey {
  absl::string_view json_key;
  absl::string_view symbol;
  absl::string_view unit;
  int first_theta_index;
  int components;
};
// Every key once, in theta order (a key's coefficients are contiguous in theta).
const std::vector<FixedTermKey>& FixedTermKeys();
// The key named `json_key`, or nullopt.
std::optional<FixedTermKey> FindFixedTermKey(absl::string_view json_key);

// Storage and CSV column names of the value and of its 1-sigma: "c1x_deg_h", "c1x_sigma_deg_h".
std::string FixedTermValueColumn(const FixedTermDescriptor& term);
std::string FixedTermSigmaColumn(const FixedTermDescriptor& term);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_MODEL_TERMS_H_
