#include "estimator/spacecraft_config.h"

#include <cmath>
#include <limits>
#include <set>
#include <tuple>
#include <string>
#include <vector>

#include "Eigen/LU"
#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/conventions.h"
#include "estimator/model_terms.h"
#include "estimator/status_macros.h"

namespace esg::estimator {

const GyroConfig* SpacecraftConfig::FindGyro(int id) const {
  for (const GyroConfig& g : gyros) {
    if (g.id == id) return &g;
  }
  return nullptr;
}

namespace {

absl::Status CheckPair(const SpacecraftConfig& config, const std::array<int, 2>& pair,
                       const char* field) {
  for (int id : pair) {
    if (config.FindGyro(id) == nullptr) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: gyro %d is not among the configured gyros", field, id));
    }
  }
  if (pair[0] == pair[1]) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: a pair needs two different gyros, got [%d, %d]", field, pair[0],
                        pair[1]));
  }
  return absl::OkStatus();
}

bool WithinLimit(double value_si, const ConfigLimit& limit) {
  constexpr double kSlack = 1e-12;  // relative: the SI round trip of a bound typed in the JSON
  const double v = limit.from_si(value_si);
  return v >= limit.min - kSlack * std::abs(limit.min) &&
         v <= limit.max + kSlack * std::abs(limit.max);  // false for NaN
}

absl::Status LimitError(double value_si, const ConfigLimit& limit, absl::string_view field) {
  return absl::InvalidArgumentError(absl::StrFormat("%s: %g is outside [%g, %g] %s (%s)", field,
                                                    limit.from_si(value_si), limit.min, limit.max,
                                                    limit.unit, limit.reason));
}

// A sigma that is a filter state's prior: 0 (the state is held, not estimated) or one whose
// variance sigma * sigma [SI], the prior P0 of its state, is a normal double. A smaller positive
// one made P0 zero or subnormal: the relative sigma sqrt(P)/sqrt(P0) could overflow and the
// session's checkpoint would not restore (session_checkpoint.cc). The bound, about sqrt(DBL_MIN)
// = 1.5e-154 in SI, is far below any physical sigma.
bool IsPriorSigma(double sigma_si) {
  return sigma_si == 0.0 || std::isnormal(sigma_si * sigma_si);
}

// `to_json` converts SI to the field's unit.
absl::Status PriorSigmaError(double sigma_si, double to_json, absl::string_view unit,
                             absl::string_view field) {
  const double smallest_si = std::sqrt(std::numeric_limits<double>::min());
  return absl::InvalidArgumentError(absl::StrFormat(
      "%s: %g %s is a prior sigma below about %g %s, whose variance is not a normal double: use "
      "0 to hold the state fixed, or a sigma of at least that",
      field, sigma_si * to_json, unit, smallest_si * to_json, unit));
}

absl::Status ValidateBasisTerms(const std::vector<BasisTerm>& terms, size_t gyro) {
  const ConfigLimits& L = kConfigLimits;
  if (terms.size() > static_cast<size_t>(kMaxBasisTermsPerGyro)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("gyros[%d].basisTerms: %d terms, at most %d per gyro", gyro, terms.size(),
                        kMaxBasisTermsPerGyro));
  }
  for (size_t k = 0; k < terms.size(); ++k) {
    const BasisTerm& t = terms[k];
    const std::string prefix = absl::StrFormat("gyros[%d].basisTerms[%d]", gyro, k);
    RETURN_IF_ERROR(ValidateBasisTerm(t, prefix));
    // The limits bound the drift at the kind's reference regressor size (ConfigLimits::
    // basis_value, BasisReferenceSize), in deg/h; the message gives the field's own value too.
    const double to_json = BasisValueToJson(t.kind);
    const double size = BasisReferenceSize(t.kind);
    const std::string unit = BasisScalarJsonUnit(t.kind) == "1"
                                 ? std::string("deg/h")
                                 : absl::StrCat("deg/h per ", std::string(BasisScalarJsonUnit(t.kind)));
    for (const auto& [value, limit, field] :
         {std::tuple<double, const ConfigLimit&, const char*>{t.value, L.basis_value, "valueDegH"},
          {t.sigma, L.basis_sigma, "sigmaDegH"}}) {
      if (WithinLimit(value * to_json * size, limit)) continue;
      const std::string at = BasisScalarJsonUnit(t.kind) == "1"
                                 ? std::string("a unit regressor")
                                 : absl::StrFormat("%g %s of its regressor", size,
                                                   std::string(BasisScalarJsonUnit(t.kind)));
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s.%s: %g %s is %g deg/h at %s, outside [%g, %g] (%s)", prefix, field,
          value * to_json, unit, value * to_json * size, at, limit.min, limit.max, limit.reason));
    }
    if (!IsPriorSigma(t.sigma)) {
      return PriorSigmaError(t.sigma, to_json, unit, prefix + ".sigmaDegH");
    }
  }
  return absl::OkStatus();
}

absl::Status ValidateReadoutDistortion(const Eigen::Matrix3d& D, size_t gyro) {
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      const std::string field = absl::StrFormat("gyros[%d].readoutDistortion[%d]", gyro, 3 * r + c);
      RETURN_IF_ERROR(CheckLimit(D(r, c), kConfigLimits.readout_distortion, field));
      if (!(std::abs(D(r, c) - D(c, r)) <= kReadoutDistortionSymmetryTolerance)) {
        return absl::InvalidArgumentError(absl::StrFormat(
            "%s: %g differs from its transpose entry [%d] = %g by more than %g (D must be "
            "symmetric)",
            field, D(r, c), 3 * c + r, D(c, r), kReadoutDistortionSymmetryTolerance));
      }
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status ValidateIdentifier(absl::string_view value, absl::string_view field) {
  // Quoted, escaped, at most kIdentifierQuoteLength characters of the value.
  const auto quoted = [&value]() {
    const bool cut = value.size() > static_cast<size_t>(kIdentifierQuoteLength);
    return absl::StrCat("\"", absl::CHexEscape(value.substr(0, kIdentifierQuoteLength)),
                        cut ? "\"..." : "\"");
  };
  static_assert(kMaxIdentifierLength == 64, "kRule states the length");
  constexpr absl::string_view kRule =
      "an identifier is 1..64 characters from [A-Za-z0-9._:-], starting with a letter or digit";
  if (value.empty()) return absl::InvalidArgumentError(absl::StrCat(field, ": must not be empty"));
  if (value.size() > static_cast<size_t>(kMaxIdentifierLength)) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: %d characters (%s) is too long: %s",
                                                      field, value.size(), quoted(), kRule));
  }
  for (size_t i = 0; i < value.size(); ++i) {
    const unsigned char c = static_cast<unsigned char>(value[i]);
    const bool alnum = absl::ascii_isalnum(c);
    if (alnum || (i > 0 && (c == '.' || c == '_' || c == ':' || c == '-'))) continue;
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: character '%s' at index %d of %s is not allowed: %s", field,
                        absl::CHexEscape(value.substr(i, 1)), i, quoted(), kRule));
  }
  return absl::OkStatus();
}

absl::Status CheckLimit(double value_si, const ConfigLimit& limit, absl::string_view field) {
  if (WithinLimit(value_si, limit)) return absl::OkStatus();
  return LimitError(value_si, limit, field);
}

absl::Status ValidateConfig(const SpacecraftConfig& config) {
  const ConfigLimits& L = kConfigLimits;
  RETURN_IF_ERROR(ValidateIdentifier(config.spacecraft_id, "spacecraftId"));
  if (config.gyros.size() < 2 || config.gyros.size() > static_cast<size_t>(kMaxGyros)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "gyros: between 2 and %d gyros are needed, got %d", kMaxGyros, config.gyros.size()));
  }
  std::set<int> ids;
  for (size_t i = 0; i < config.gyros.size(); ++i) {
    const GyroConfig& g = config.gyros[i];
    if (g.id < 1 || g.id > kMaxGyros) {
      return absl::InvalidArgumentError(
          absl::StrFormat("gyros[%d].id: %d is outside 1..%d", i, g.id, kMaxGyros));
    }
    if (!ids.insert(g.id).second) {
      return absl::InvalidArgumentError(
          absl::StrFormat("gyros[%d].id: gyro %d is configured twice", i, g.id));
    }
    const Eigen::Matrix3d should_be_identity = g.C_b_k.transpose() * g.C_b_k;
    if (!g.C_b_k.allFinite() || !should_be_identity.isIdentity(1e-6) ||
        !(g.C_b_k.determinant() > 0.0)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "gyros[%d].caseToBody: not a proper rotation matrix (orthonormal to 1e-6, det +1)", i));
    }
    const DriftVector model = g.model.AsVector(), sigma = g.model_sigma.AsVector();
    for (int k = 0; k < kNumDriftCoefficients; ++k) {  // field names built only on failure
      if (!WithinLimit(model[k], L.drift_coefficient)) {
        return LimitError(
            model[k], L.drift_coefficient,
            absl::StrFormat("gyros[%d].model.%s", i, FixedTermJsonName(kFixedTerms[k])));
      }
    }
    for (int k = 0; k < kNumDriftCoefficients; ++k) {
      if (!WithinLimit(sigma[k], L.drift_sigma)) {
        return LimitError(
            sigma[k], L.drift_sigma,
            absl::StrFormat("gyros[%d].modelSigma.%s", i, FixedTermJsonName(kFixedTerms[k])));
      }
      if (!IsPriorSigma(sigma[k])) {
        return PriorSigmaError(
            sigma[k], RadPerSecToDegPerHour(1.0), "deg/h",
            absl::StrFormat("gyros[%d].modelSigma.%s", i, FixedTermJsonName(kFixedTerms[k])));
      }
    }
    RETURN_IF_ERROR(CheckLimit(g.misalignment_sigma, L.misalignment_sigma,
                               absl::StrFormat("gyros[%d].misalignmentSigmaArcsec", i)));
    if (!IsPriorSigma(g.misalignment_sigma)) {
      return PriorSigmaError(g.misalignment_sigma, RadToArcsec(1.0), "arcsec",
                             absl::StrFormat("gyros[%d].misalignmentSigmaArcsec", i));
    }
    RETURN_IF_ERROR(ValidateBasisTerms(g.basis_terms, i));
    RETURN_IF_ERROR(ValidateReadoutDistortion(g.readout_distortion, i));
  }
  if (auto s = CheckPair(config, config.working_pair, "workingPair"); !s.ok()) return s;
  if (auto s = CheckPair(config, config.reserve_pair, "reservePair"); !s.ok()) return s;
  for (int k = 0; k < 3; ++k) {
    RETURN_IF_ERROR(CheckLimit(config.star_tracker.noise[k], L.star_tracker_noise,
                               absl::StrFormat("starTracker.noiseArcsec[%d]", k)));
  }
  RETURN_IF_ERROR(
      CheckLimit(config.star_tracker.latency, L.star_tracker_latency, "starTracker.latencyS"));
  RETURN_IF_ERROR(CheckLimit(config.star_tracker.latency_sigma, L.star_tracker_latency_sigma,
                             "starTracker.latencySigmaS"));
  if (!IsPriorSigma(config.star_tracker.latency_sigma)) {
    return PriorSigmaError(config.star_tracker.latency_sigma, 1.0, "s", "starTracker.latencySigmaS");
  }
  RETURN_IF_ERROR(CheckLimit(config.readout_noise, L.readout_noise, "readoutNoiseArcsec"));
  RETURN_IF_ERROR(CheckLimit(config.random_walk, L.random_walk, "randomWalkDegHSqrtH"));
  const SuspensionConfig& s = config.suspension;
  RETURN_IF_ERROR(CheckLimit(s.amplifier_gain, L.amplifier_gain, "suspension.amplifierGain"));
  RETURN_IF_ERROR(
      CheckLimit(s.reference_voltage, L.reference_voltage, "suspension.referenceVoltageV"));
  RETURN_IF_ERROR(CheckLimit(s.gap, L.gap, "suspension.gapUm"));
  const FilterConfig& f = config.filter;
  RETURN_IF_ERROR(
      CheckLimit(f.integration_rate_hz, L.integration_rate, "filter.integrationRateHz"));
  RETURN_IF_ERROR(CheckLimit(f.measurement_step, L.measurement_step, "filter.measurementStepS"));
  RETURN_IF_ERROR(CheckLimit(f.innovation_kd, L.innovation_kd, "filter.innovationKd"));
  RETURN_IF_ERROR(
      CheckLimit(f.fault_threshold, L.fault_threshold, "filter.faultThresholdArcsec"));
  RETURN_IF_ERROR(
      CheckLimit(f.drift_change_limit, L.drift_change_limit, "filter.driftChangeLimitDegH"));
  RETURN_IF_ERROR(ValidateChannelConfigs(config.channels));
  // A channel term reads a declared channel (basis_term.h kChannel).
  std::vector<std::string> declared;
  for (const ChannelConfig& c : config.channels) declared.push_back(c.name);
  for (size_t i = 0; i < config.gyros.size(); ++i) {
    const std::vector<BasisTerm>& terms = config.gyros[i].basis_terms;
    for (size_t k = 0; k < terms.size(); ++k) {
      RETURN_IF_ERROR(CheckBasisChannel(
          terms[k], declared, absl::StrFormat("gyros[%d].basisTerms[%d]", i, k)));
    }
  }
  return absl::OkStatus();
}

}  // namespace esg::estimator
