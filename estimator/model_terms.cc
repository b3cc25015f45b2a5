// The fixed terms of the drift model; contract in model_terms.h.
#include "estimator/model_terms.h"

#include "absl/strings/str_cat.h"
#include "absl/strings/str_replace.h"

namespace esg::estimator {

std::string FixedTermJsonName(const FixedTermDescriptor& term) {
  if (term.component < 0) return std::string(term.json_key);
  return absl::StrCat(term.json_key, "[", term.component, "]");
}

namespace {

// "deg/h" -> "deg_h", the unit as a column name writes it (docs/conventions.md, names carry units).
std::string ColumnUnit(const FixedTermDescriptor& term) {
  return absl::StrReplaceAll(term.unit, {{"/", "_"}});
}

}  // namespace

std::string FixedTermValueColumn(const FixedTermDescriptor& term) {
  return absl::StrCat(term.storage_key, "_", ColumnUnit(term));
}

std::string FixedTermSigmaColumn(const FixedTermDescriptor& term) {
  return absl::StrCat(term.storage_key, "_sigma_", ColumnUnit(term));
}

}  // namespace esg::estimator
