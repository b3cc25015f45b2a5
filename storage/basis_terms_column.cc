// Basis terms of a coefficient estimate as a JSON column; contract in basis_terms_column.h.
#include "storage/basis_terms_column.h"

#include <cmath>
#include <cstdint>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "nlohmann/json.hpp"
#include "storage/schema.h"

namespace esg::storage {
namespace {

constexpr char kColumn[] = "coefficients.basis_terms_json";

absl::Status ColumnError(int term, absl::string_view what) {
  return absl::DataLossError(term < 0 ? absl::StrCat(kColumn, ": ", what)
                                      : absl::StrFormat("%s[%d]: %s", kColumn, term, what));
}

}  // namespace

std::string BasisTermsToColumn(const std::vector<estimator::BasisTerm>& terms) {
  nlohmann::json out = nlohmann::json::array();
  for (const estimator::BasisTerm& t : terms) {
    const double to_json = estimator::BasisValueToJson(t.kind);
    out.push_back({{"label", estimator::BasisTermLabel(t)},
                   {"kind", std::string(estimator::BasisKindName(t.kind))},
                   {"axis", t.axis},
                   {"exponents", t.exponents},
                   {"index", t.index},
                   {"harmonic", t.harmonic},
                   {"sine", t.sine},
                   {"period_s", t.period},
                   {"epoch_unix_ns", TimeToUnixNanos(t.epoch)},
                   {"value_deg_h", t.value * to_json},
                   {"sigma_deg_h", t.sigma * to_json}});
  }
  return out.dump();
}

absl::StatusOr<std::vector<estimator::BasisTerm>> BasisTermsFromColumn(absl::string_view text) {
  const nlohmann::json in = nlohmann::json::parse(text.begin(), text.end(), nullptr,
                                                  /*allow_exceptions=*/false);
  if (in.is_discarded() || !in.is_array()) return ColumnError(-1, "not a JSON array");
  std::vector<estimator::BasisTerm> terms;
  for (size_t k = 0; k < in.size(); ++k) {
    const int term = static_cast<int>(k);
    const nlohmann::json& j = in[k];
    if (!j.is_object()) return ColumnError(term, "not an object");
    estimator::BasisTerm t;
    try {
      absl::StatusOr<estimator::BasisKind> kind =
          estimator::ParseBasisKind(j.at("kind").get<std::string>());
      if (!kind.ok()) return ColumnError(term, kind.status().message());
      t.kind = *kind;
      t.axis = j.at("axis").get<int>();
      t.exponents = j.at("exponents").get<std::array<int, 3>>();
      t.index = j.at("index").get<std::array<int, 2>>();
      t.harmonic = j.at("harmonic").get<int>();
      t.sine = j.at("sine").get<bool>();
      t.period = j.at("period_s").get<double>();
      t.epoch = UnixNanosToTime(j.at("epoch_unix_ns").get<int64_t>());
      const double to_json = estimator::BasisValueToJson(t.kind);
      t.value = j.at("value_deg_h").get<double>() / to_json;
      t.sigma = j.at("sigma_deg_h").get<double>() / to_json;
    } catch (const nlohmann::json::exception& e) {
      return ColumnError(term, e.what());
    }
    if (absl::Status valid = estimator::ValidateBasisTerm(t, absl::StrFormat("%s[%d]", kColumn, term));
        !valid.ok()) {
      return absl::DataLossError(valid.message());
    }
    terms.push_back(t);
  }
  return terms;
}

}  // namespace esg::storage
