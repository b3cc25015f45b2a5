#include "estimator/calibration_model.h"

#include <array>
#include <string>

#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"
#include "estimator/model_terms.h"

namespace esg::estimator {

std::string ModelSpec::Name() const {
  std::vector<std::string> parts_named;
  if (parts & kModelPart10) {
    parts_named.push_back("10");
  } else if (parts & kModelPart1) {
    parts_named.push_back("1");
  }
  if (random_walk) parts_named.push_back("11");
  return absl::StrJoin(parts_named, "+");
}

std::array<bool, kNumDriftCoefficients> ModelSpec::TermMask() const {
  std::array<bool, kNumDriftCoefficients> mask{};
  for (const FixedTermDescriptor& term : kFixedTerms) {
    mask[term.theta_index] = (term.model_parts & parts) != 0;
  }
  return mask;
}

absl::StatusOr<ModelSpec> ParseModel(absl::string_view name) {
  ModelSpec spec;
  if (name.empty()) return absl::InvalidArgumentError("model: empty (use 1, 10, 11 or e.g. 10+11)");
  for (absl::string_view part : absl::StrSplit(name, '+')) {
    part = absl::StripAsciiWhitespace(part);
    if (part == "1") {
      spec.parts |= kModelPart1;
    } else if (part == "10") {
      spec.parts |= kModelPart10;
    } else if (part == "11") {
      spec.random_walk = true;
    } else {
      // Quoted in part: a request may carry a name of any length.
      constexpr size_t kQuote = 32;
      const auto quoted = [](absl::string_view text) {
        return absl::StrCat(absl::CHexEscape(text.substr(0, kQuote)),
                            text.size() > kQuote ? "..." : "");
      };
      return absl::InvalidArgumentError(absl::StrFormat(
          "model: unknown term '%s' in '%s' (use 1, 10, 11 or a '+' set such as 10+11)",
          quoted(part), quoted(name)));
    }
  }
  return spec;
}

DriftVector ModelCoefficients(const ModelSpec& spec, const GyroConfig& gyro) {
  DriftVector theta = gyro.model.AsVector();
  // Model (11) alone: the configured (bench) model is applied as it is and the random walk takes
  // up what it leaves (the paper: model (11) stands alone when model (10) was not calibrated).
  if (!spec.HasFixedTerms()) return theta;
  const auto mask = spec.TermMask();
  for (int i = 0; i < kNumDriftCoefficients; ++i) {
    if (!mask[i]) theta(i) = 0.0;
  }
  return theta;
}

std::vector<int> FreeCoefficients(const ModelSpec& spec, const GyroConfig& gyro) {
  std::vector<int> free;
  // Model (11) alone estimates no coefficient (TermMask is all false then).
  const auto mask = spec.TermMask();
  const DriftVector sigma = gyro.model_sigma.AsVector();
  for (int i = 0; i < kNumDriftCoefficients; ++i) {
    if (mask[i] && sigma(i) > 0.0) free.push_back(i);
  }
  return free;
}

std::vector<int> FreeBasisTerms(const GyroConfig& gyro) {
  std::vector<int> free;
  for (size_t k = 0; k < gyro.basis_terms.size(); ++k) {
    if (gyro.basis_terms[k].sigma > 0.0) free.push_back(static_cast<int>(k));
  }
  return free;
}

const char* CoefficientName(int i) {
  static const auto* const kNames = [] {
    auto* names = new std::array<std::string, kNumDriftCoefficients>;
    for (int k = 0; k < kNumDriftCoefficients; ++k) (*names)[k] = FixedTermJsonName(kFixedTerms[k]);
    return names;
  }();
  return (i >= 0 && i < kNumDriftCoefficients) ? (*kNames)[i].c_str() : "?";
}

}  // namespace esg::estimator
