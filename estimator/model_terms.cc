// The fixed terms of the drift model; contract in model_terms.h.
#include "estimator/model_terms.h"

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_replace.h"

namespace esg::estimator {

std::string FixedTermJsonName(const FixedTermDescriptor& term) {
  if (term.component < 0) return std::string(term.json_key);
  return absl::StrCat(term.json_key, "[", term.component, "]");
}

std::string FixedTermFieldName(absl::string_view json_key) {
  std::string out;
  for (char c : json_key) {
    if (absl::ascii_isupper(static_cast<unsigned char>(c))) {
      out += '_';
      out += absl::ascii_tolower(static_cast<unsigned char>(c));
    } else {
      out += c;
    }
  }
  return out;
}

const std::vector<FixedTermKey>& FixedTermKeys() {
  static const auto* const keys = [] {
    auto* out = new std::vector<FixedTermKey>;
    for (const FixedTermDescriptor& term : kFixedTerms) {
      if (out->empty() || out->back().json_key != term.json_key) {
        out->push_back({term.json_key, term.symbol, term.unit, term.theta_index, 0});
      }
      if (term.component >= 0) ++out->back().components;
    }
    return out;
  }();
  return *keys;
}

std::optional<FixedTermKey> FindFixedTermKey(absl::string_view json_key) {
  for (const FixedTermKey& key : FixedTermKeys()) {
    if (key.json_key == json_key) return key;
  }
  return std::nullopt;
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
