// The basis terms of a coefficient estimate (drift terms beyond eq. (1), (10), docs/physics.md
// "Basis of drift terms") in column coefficients.basis_terms_json: a JSON array, one object a
// term in the gyro's configured order,
//
//   {"label": "orbit cos 1 -> y", "kind": "orbital_harmonic", "axis": 2,
//    "exponents": [0, 0, 0], "index": [1, 1], "harmonic": 1, "sine": false,
//    "period_s": 5400, "epoch_unix_ns": 0, "value_deg_h": 0.0012, "sigma_deg_h": 4e-05}
//
// value_deg_h is the estimate and sigma_deg_h its 1-sigma (0: the term is held at its value), both
// in deg/h per JSON unit of the term's regressor (deg/s for body rates, h for ramps, V for
// voltages, 1 for harmonics: estimator/basis_term.h BasisScalarJsonUnit), the units of the
// configuration's basisTerms; the label is estimator::BasisTermLabel, for readers of plain SQL.
// Records are SI (records.h): the conversion happens here, at the column.
#ifndef ESG_STORAGE_BASIS_TERMS_COLUMN_H_
#define ESG_STORAGE_BASIS_TERMS_COLUMN_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "estimator/basis_term.h"

namespace esg::storage {

// The column text of `terms` (value and sigma SI, [rad/s per SI unit of s]).
std::string BasisTermsToColumn(const std::vector<estimator::BasisTerm>& terms);

// The terms of a column text, SI. DataLoss naming coefficients.basis_terms_json when the text is
// not such an array or a term is out of the ranges of estimator::ValidateBasisTerm.
absl::StatusOr<std::vector<estimator::BasisTerm>> BasisTermsFromColumn(absl::string_view text);

}  // namespace esg::storage

#endif  // ESG_STORAGE_BASIS_TERMS_COLUMN_H_
