#include "estimator/basis_term.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "absl/strings/escaping.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/time/civil_time.h"
#include "absl/time/clock.h"
#include "estimator/channel_signal.h"
#include "estimator/channels.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"

namespace esg::estimator {

namespace {

constexpr std::array<std::pair<BasisKind, std::string_view>, 10> kKindNames = {{
    {BasisKind::kSpinAxisHarmonic, "spin_axis_harmonic"},
    {BasisKind::kBodyRate, "body_rate"},
    {BasisKind::kBodyRateProduct, "body_rate_product"},
    {BasisKind::kOrbitalHarmonic, "orbital_harmonic"},
    {BasisKind::kRamp, "ramp"},
    {BasisKind::kRampHarmonic, "ramp_harmonic"},
    {BasisKind::kSuspensionVoltage, "suspension_voltage"},
    {BasisKind::kExponentialDecay, "exponential_decay"},
    {BasisKind::kChannel, "channel"},
    {BasisKind::kCyclingHarmonic, "cycling_harmonic"},
}};

constexpr std::array<std::pair<ChannelForm, std::string_view>, 3> kFormNames = {{
    {ChannelForm::kValue, "value"},
    {ChannelForm::kLag, "lag"},
    {ChannelForm::kDerivative, "derivative"},
}};

bool InAxisRange(int i) { return i >= 1 && i <= 3; }

// Epochs lie where frame times may (docs/service.md "Limits": [1970-01-01, 2200-01-01)): a ramp
// from 0001-01-01 is a regressor of 1.8e7 h at the first frame.
absl::Status CheckEpoch(absl::Time epoch, std::string_view prefix) {
  const absl::Time earliest = absl::UnixEpoch();
  const absl::Time latest =
      absl::FromCivil(absl::CivilSecond(2200, 1, 1, 0, 0, 0), absl::UTCTimeZone());
  if (epoch >= earliest && epoch < latest) return absl::OkStatus();
  return absl::InvalidArgumentError(
      absl::StrCat(std::string(prefix),
                   ".epoch: ", FormatUtc(epoch),
                   " is outside [1970-01-01, 2200-01-01), the window frame times may have"));
}

// "x", "y", "z" for case axes 1..3.
char AxisLetter(int m) { return "xyz"[std::clamp(m, 1, 3) - 1]; }

std::string Monomial(const std::array<int, 3>& e) {
  std::string text;
  for (int i = 0; i < 3; ++i) {
    if (e[i] == 0) continue;
    absl::StrAppend(&text, text.empty() ? "" : "*", "h", i + 1);
    if (e[i] > 1) absl::StrAppend(&text, "^", e[i]);
  }
  return text.empty() ? "1" : text;
}

// h_1^a h_2^b h_3^c of a spin-axis term (eq. (1)'s products of direction cosines; degree up to
// kMaxHarmonicDegree). std::pow(double, int) is libm's pow of two doubles, 12% of a diagnosis's
// CPU (perf record of esg_bench BM_Diagnose30h/1): the exponents 0 and 1 are taken without it
// (the same bits: pow is within 0.52 ulp, so it returns a representable result, 1 or h,
// exactly), the others from the inputs' table when it is there (TabulateSpinAxisPowers: pow's
// own values, computed once per substep instead of once per term). h * h would differ from pow
// in rare ties, which changed the last digits of rejected candidates' deviances in the docs'
// worked example.
double SpinAxisProduct(const BasisInputs& in, const std::array<int, 3>& exponents) {
  double s = 1.0;
  for (int i = 0; i < 3; ++i) {
    const int e = exponents[i];
    if (e == 1) {
      s *= in.h_k(i);
    } else if (e >= 2 && e <= kMaxHarmonicDegree && in.h_powers.has_value()) {
      s *= (*in.h_powers)[i][e - 2];
    } else if (e != 0) {
      s *= std::pow(in.h_k(i), e);
    }
  }
  return s;
}

}  // namespace

std::string_view BasisKindName(BasisKind kind) {
  for (const auto& [k, name] : kKindNames) {
    if (k == kind) return name;
  }
  return "unknown";
}

absl::StatusOr<BasisKind> ParseBasisKind(std::string_view name) {
  for (const auto& [k, n] : kKindNames) {
    if (n == name) return k;
  }
  std::string known;
  for (const auto& [k, n] : kKindNames)
    absl::StrAppend(&known, known.empty() ? "" : ", ", std::string(n));
  return absl::InvalidArgumentError(
      absl::StrFormat("unknown basis kind \"%s\" (known: %s)", name, known));
}

std::string_view ChannelFormName(ChannelForm form) {
  for (const auto& [f, name] : kFormNames) {
    if (f == form) return name;
  }
  return "unknown";
}

absl::StatusOr<ChannelForm> ParseChannelForm(std::string_view name) {
  for (const auto& [f, n] : kFormNames) {
    if (n == name) return f;
  }
  return absl::InvalidArgumentError(absl::StrFormat(
      "unknown channel form \"%s\" (known: value, lag, derivative)",
      absl::CHexEscape(absl::string_view(name.data(), name.size()))));
}

absl::Status CheckBasisChannel(const BasisTerm& t, const std::vector<std::string>& declared,
                               std::string_view prefix) {
  if (t.kind != BasisKind::kChannel) return absl::OkStatus();
  if (std::find(declared.begin(), declared.end(), t.channel) != declared.end()) {
    return absl::OkStatus();
  }
  return absl::InvalidArgumentError(absl::StrCat(
      std::string(prefix), ".channel: \"",
      absl::CHexEscape(t.channel.substr(0, kMaxChannelNameLength)),
      "\" is not declared in channels (declared: ",
      declared.empty() ? std::string("none") : absl::StrJoin(declared, ", "), ")"));
}

absl::Status ValidateBasisTerm(const BasisTerm& t, std::string_view prefix) {
  auto bad = [&](std::string_view field, const std::string& why) {
    return absl::InvalidArgumentError(
        absl::StrCat(std::string(prefix), ".", std::string(field), ": ", why));
  };
  if (!InAxisRange(t.axis)) return bad("axis", absl::StrFormat("must be 1..3, got %d", t.axis));
  if (!std::isfinite(t.value)) return bad("value", "must be finite");
  if (!std::isfinite(t.sigma) || t.sigma < 0.0) return bad("sigma", "must be finite and >= 0");
  switch (t.kind) {
    case BasisKind::kCyclingHarmonic:
      if (!(t.period >= kMinOrbitalPeriodS && t.period <= kMaxOrbitalPeriodS)) {
        return bad("periodS", absl::StrFormat("%g s is outside [%g, %g] s (a minute to a year)",
                                              t.period, kMinOrbitalPeriodS, kMaxOrbitalPeriodS));
      }
      [[fallthrough]];
    case BasisKind::kSpinAxisHarmonic: {
      int degree = 0;
      for (int e : t.exponents) {
        // Each checked before the sum, which INT_MAX exponents would overflow.
        if (e < 0 || e > kMaxHarmonicDegree) {
          return bad("exponents",
                     absl::StrFormat("each must be 0..%d, got %d", kMaxHarmonicDegree, e));
        }
        degree += e;
      }
      if (degree > kMaxHarmonicDegree) {
        return bad("exponents", absl::StrFormat("degree %d above %d", degree, kMaxHarmonicDegree));
      }
      // The switch-on (D110); a cycling harmonic's phase zero.
      RETURN_IF_ERROR(CheckEpoch(t.epoch, prefix));
      break;
    }
    case BasisKind::kBodyRateProduct:
      if (!InAxisRange(t.index[1])) {
        return bad("index", absl::StrFormat("must be 1..3, got %d", t.index[1]));
      }
      [[fallthrough]];
    case BasisKind::kBodyRate:
    case BasisKind::kRampHarmonic:
    case BasisKind::kSuspensionVoltage:
      if (!InAxisRange(t.index[0])) {
        return bad("index", absl::StrFormat("must be 1..3, got %d", t.index[0]));
      }
      break;
    case BasisKind::kOrbitalHarmonic:
      if (t.harmonic < 1 || t.harmonic > kMaxOrbitalHarmonic) {
        return bad("harmonic",
                   absl::StrFormat("must be 1..%d, got %d", kMaxOrbitalHarmonic, t.harmonic));
      }
      if (!(t.period >= kMinOrbitalPeriodS && t.period <= kMaxOrbitalPeriodS)) {
        return bad("periodS", absl::StrFormat("%g s is outside [%g, %g] s (a minute to a year)",
                                              t.period, kMinOrbitalPeriodS, kMaxOrbitalPeriodS));
      }
      RETURN_IF_ERROR(CheckEpoch(t.epoch, prefix));
      break;
    case BasisKind::kRamp:
      RETURN_IF_ERROR(CheckEpoch(t.epoch, prefix));
      break;
    case BasisKind::kExponentialDecay:
      if (!(t.time_constant >= kMinDecayTimeConstantS &&
            t.time_constant <= kMaxDecayTimeConstantS)) {
        return bad("timeConstantS",
                   absl::StrFormat("%g s is outside [%g, %g] s (a minute to a year)",
                                   t.time_constant, kMinDecayTimeConstantS,
                                   kMaxDecayTimeConstantS));
      }
      RETURN_IF_ERROR(CheckEpoch(t.epoch, prefix));
      break;
    case BasisKind::kChannel:
      RETURN_IF_ERROR(ValidateChannelName(t.channel, absl::StrCat(std::string(prefix), ".channel")));
      if (!std::isfinite(t.reference)) return bad("referenceValue", "must be finite");
      if (t.form != ChannelForm::kValue &&
          !(t.time_constant >= kMinDecayTimeConstantS &&
            t.time_constant <= kMaxDecayTimeConstantS)) {
        return bad("timeConstantS",
                   absl::StrFormat("%g s is outside [%g, %g] s (a minute to a year) for the %s "
                                   "form",
                                   t.time_constant, kMinDecayTimeConstantS,
                                   kMaxDecayTimeConstantS, ChannelFormName(t.form)));
      }
      break;
  }
  if (t.kind == BasisKind::kRampHarmonic) RETURN_IF_ERROR(CheckEpoch(t.epoch, prefix));
  return absl::OkStatus();
}

void TabulateSpinAxisPowers(BasisInputs& in) {
  auto& table = in.h_powers.emplace();
  for (int i = 0; i < 3; ++i) {
    for (int e = 2; e <= kMaxHarmonicDegree; ++e) table[i][e - 2] = std::pow(in.h_k(i), e);
  }
}

double BasisScalar(const BasisTerm& t, const BasisInputs& in) {
  switch (t.kind) {
    case BasisKind::kSpinAxisHarmonic: {
      // Switched on at the epoch (D110: a step of a coefficient of eq. (1), (10)); the default
      // epoch, 1970, precedes every frame.
      if (in.time < t.epoch) return 0.0;
      return SpinAxisProduct(in, t.exponents);
    }
    case BasisKind::kBodyRate:
      return in.w_k(t.index[0] - 1);
    case BasisKind::kBodyRateProduct:
      return in.w_k(t.index[0] - 1) * in.w_k(t.index[1] - 1);
    case BasisKind::kOrbitalHarmonic: {
      const double phase = 2.0 * kPi * t.harmonic *
                           std::fmod(absl::ToDoubleSeconds(in.time - t.epoch), t.period) / t.period;
      return t.sine ? std::sin(phase) : std::cos(phase);
    }
    case BasisKind::kRamp:
      return absl::ToDoubleSeconds(in.time - t.epoch);
    case BasisKind::kRampHarmonic: {
      const double h = in.h_k(t.index[0] - 1);
      return absl::ToDoubleSeconds(in.time - t.epoch) * h * h;
    }
    case BasisKind::kSuspensionVoltage:
      return in.u_k_v.has_value() ? (*in.u_k_v)(t.index[0] - 1) : 0.0;
    case BasisKind::kExponentialDecay: {
      const double since_s = absl::ToDoubleSeconds(in.time - t.epoch);
      return since_s < 0.0 ? 0.0 : std::exp(-since_s / t.time_constant);
    }
    case BasisKind::kChannel:
      return in.channels != nullptr ? in.channels->Scalar(t, in.time) : 0.0;
    case BasisKind::kCyclingHarmonic: {
      const double s = SpinAxisProduct(in, t.exponents);
      const double phase =
          2.0 * kPi * std::fmod(absl::ToDoubleSeconds(in.time - t.epoch), t.period) / t.period;
      return s * (t.sine ? std::sin(phase) : std::cos(phase));
    }
  }
  return 0.0;
}

Eigen::Vector3d BasisRegressor_k(const BasisTerm& t, const BasisInputs& in) {
  return BasisScalar(t, in) * Eigen::Vector3d::Unit(std::clamp(t.axis, 1, 3) - 1);
}

Eigen::Vector3d BasisDrift_k(const BasisTerm& t, const BasisInputs& in) {
  return t.value * BasisRegressor_k(t, in);
}

Eigen::Vector3d BasisDriftSum_k(const std::vector<BasisTerm>& terms, const BasisInputs& in) {
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  for (const BasisTerm& t : terms) sum += BasisDrift_k(t, in);
  return sum;
}

std::string BasisTermLabel(const BasisTerm& t) {
  std::string s;
  switch (t.kind) {
    case BasisKind::kSpinAxisHarmonic:
      s = Monomial(t.exponents);
      break;
    case BasisKind::kBodyRate:
      s = absl::StrCat("rate[", t.index[0], "]");
      break;
    case BasisKind::kBodyRateProduct:
      s = absl::StrCat("rate[", t.index[0], "]*rate[", t.index[1], "]");
      break;
    case BasisKind::kOrbitalHarmonic:
      s = absl::StrCat("orbit ", t.sine ? "sin " : "cos ", t.harmonic);
      break;
    case BasisKind::kRamp:
      s = "ramp";
      break;
    case BasisKind::kRampHarmonic:
      s = absl::StrCat("ramp*h", t.index[0], "^2");
      break;
    case BasisKind::kSuspensionVoltage:
      s = absl::StrCat("voltage[", t.index[0], "]");
      break;
    case BasisKind::kExponentialDecay:
      s = absl::StrFormat("exp(-t/%.3gh)", t.time_constant / kSecondsPerHour);
      break;
    case BasisKind::kChannel:
      s = t.form == ChannelForm::kValue
              ? t.channel
              : absl::StrFormat("%slag(%s, %.3gh)", t.form == ChannelForm::kDerivative ? "d/dt " : "",
                                t.channel, t.time_constant / kSecondsPerHour);
      break;
    case BasisKind::kCyclingHarmonic: {
      const std::string monomial = Monomial(t.exponents);
      s = absl::StrFormat("%scycle %s %.3gh", monomial == "1" ? "" : monomial + "*",
                          t.sine ? "sin" : "cos", t.period / kSecondsPerHour);
      break;
    }
  }
  return absl::StrCat(s, " -> ", std::string(1, AxisLetter(t.axis)));
}

std::string_view BasisScalarJsonUnit(BasisKind kind) {
  switch (kind) {
    case BasisKind::kBodyRate:
      return "deg/s";
    case BasisKind::kBodyRateProduct:
      return "(deg/s)^2";
    case BasisKind::kRamp:
    case BasisKind::kRampHarmonic:
      return "h";
    case BasisKind::kSuspensionVoltage:
      return "V";
    case BasisKind::kChannel:
      return "channel unit";
    case BasisKind::kSpinAxisHarmonic:
    case BasisKind::kOrbitalHarmonic:
    case BasisKind::kExponentialDecay:
    case BasisKind::kCyclingHarmonic:
      return "1";
  }
  return "1";
}

double BasisValueToJson(BasisKind kind) {
  // value [rad/s per SI unit of s] -> [deg/h per JSON unit of s]: drift_deg_h = value_json *
  // s_json with s_json = s_si * (JSON unit per SI unit).
  const double drift = RadPerSecToDegPerHour(1.0);
  switch (kind) {
    case BasisKind::kBodyRate:
      return drift / RadToDeg(1.0);  // s in deg/s = s_si * (180/pi)
    case BasisKind::kBodyRateProduct:
      return drift / (RadToDeg(1.0) * RadToDeg(1.0));
    case BasisKind::kRamp:
    case BasisKind::kRampHarmonic:
      return drift * kSecondsPerHour;  // s in h = s_si / 3600
    case BasisKind::kSuspensionVoltage:
    case BasisKind::kSpinAxisHarmonic:
    case BasisKind::kOrbitalHarmonic:
    case BasisKind::kExponentialDecay:
    case BasisKind::kCyclingHarmonic:
    case BasisKind::kChannel:  // s in the channel's unit (per hour for the derivative) already
      return drift;
  }
  return drift;
}

double BasisReferenceSize(BasisKind kind) {
  switch (kind) {
    case BasisKind::kBodyRate:
      return 0.01;
    case BasisKind::kBodyRateProduct:
      return 1e-4;
    case BasisKind::kSuspensionVoltage:
      return 1e-3;
    case BasisKind::kRamp:
    case BasisKind::kRampHarmonic:
    case BasisKind::kSpinAxisHarmonic:
    case BasisKind::kOrbitalHarmonic:
    case BasisKind::kExponentialDecay:
    case BasisKind::kCyclingHarmonic:
    case BasisKind::kChannel:  // 1 unit of the channel (1 K)
      return 1.0;
  }
  return 1.0;
}

}  // namespace esg::estimator
