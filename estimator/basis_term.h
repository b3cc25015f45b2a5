// Drift terms beyond eq. (1), (10): the documented basis of the open-ended stage of the diagnosis
// (docs/physics.md, "Basis of drift terms"). Each term is one scalar regressor s times a case
// axis e_m, with one coefficient:
//
//     dw_k = value * s(t, h_k, w_k, u_k) * e_m        [rad/s, case axes k]
//
// Only the part of dw_k perpendicular to h_k moves the spin axis (dh/dt = dw x h), as for the
// terms of eq. (1). The regressors, in SI (the configuration JSON states its units in the field
// names and converts at the boundary, proto/convert.cc):
//
//   kind                    s                                             unit of s
//   spin_axis_harmonic      h1^a h2^b h3^c, a + b + c <= 4                1
//                           (degree 0 is a case-fixed drift; eq. (1), (10) are combinations of
//                           degrees 0-4), from the epoch on, 0 before it (the default
//                           epoch, 1970, precedes every frame; a later one is a step of
//                           a coefficient of eq. (1), (10) at the epoch, D110)
//   body_rate               w_k[i], the body rate in case axes            rad/s
//   body_rate_product       w_k[i] w_k[j]                                 (rad/s)^2
//   orbital_harmonic        cos or sin of n 2 pi (t - epoch) / period      1
//   ramp                    t - epoch                                     s
//   ramp_harmonic           (t - epoch) h_k[i]^2 (a C2-like term growing)   s
//   suspension_voltage      dU_k[i], the suspension offset voltage        V
//   exponential_decay       exp(-(t - epoch) / tau) from the epoch on,    1
//                           0 before it (a transient switched on at the epoch
//                           that decays with time constant tau: a warm-up, epoch
//                           at the recording's start; docs/formats.md "BasisTerm")
//   cycling_harmonic        h1^a h2^b h3^c times cos or sin of              1
//                           2 pi (t - epoch) / period, a + b + c <= 4 (a
//                           coefficient of eq. (1), (10) cycling: C1, C2 of
//                           a rotor displacement turning, degrees 0 and 2)
//   channel                 a declared housekeeping channel x (channels.h):  u, the channel's
//                           value x - reference, its first-order lag            unit (u/h for
//                           y - reference (time constant tau) or the lag's      the derivative)
//                           derivative dy/dt (channel_signal.h)
//
// A configuration holds terms per gyro (GyroConfig::basis_terms); a term with sigma > 0 is a
// filter state (calibrated), otherwise held at its value.
#ifndef ESG_ESTIMATOR_BASIS_TERM_H_
#define ESG_ESTIMATOR_BASIS_TERM_H_

#include <array>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "absl/time/time.h"

namespace esg::estimator {

enum class BasisKind {
  kSpinAxisHarmonic,
  kBodyRate,
  kBodyRateProduct,
  kOrbitalHarmonic,
  kRamp,
  kRampHarmonic,
  kSuspensionVoltage,
  kExponentialDecay,
  kChannel,
  kCyclingHarmonic,
};

// How a term of kind kChannel reads its channel (channel_signal.h): its held value, its
// first-order lag of time constant tau, or that lag's time derivative.
enum class ChannelForm { kValue, kLag, kDerivative };
// "value", "lag", "derivative" (the JSON's `channelForm`).
std::string_view ChannelFormName(ChannelForm form);
absl::StatusOr<ChannelForm> ParseChannelForm(std::string_view name);

class ChannelSignals;  // channel_signal.h

// "spin_axis_harmonic", ... (the names of the table above; the JSON's `kind`).
std::string_view BasisKindName(BasisKind kind);
absl::StatusOr<BasisKind> ParseBasisKind(std::string_view name);

inline constexpr int kMaxHarmonicDegree = 4;
inline constexpr int kMaxOrbitalHarmonic = 4;
// An orbital harmonic's period [s]: a minute (harmonic 4 of it is still 8 propagation steps at
// the paper's 8 Hz) to a year (the sun's apparent motion, the slowest periodic cause of a drift).
inline constexpr double kMinOrbitalPeriodS = 60.0;
inline constexpr double kMaxOrbitalPeriodS = 366.0 * 86400.0;
// An exponential decay's time constant [s]: a minute (a few star-tracker samples see it) to a
// year (beyond it the transient is a constant drift over any recording).
inline constexpr double kMinDecayTimeConstantS = 60.0;
inline constexpr double kMaxDecayTimeConstantS = 366.0 * 86400.0;

struct BasisTerm {
  BasisKind kind = BasisKind::kSpinAxisHarmonic;
  int axis = 1;  // m, the case axis of the drift direction e_m, 1..3
  // kSpinAxisHarmonic, kCyclingHarmonic: (a, b, c), each >= 0, sum <= kMaxHarmonicDegree.
  std::array<int, 3> exponents = {0, 0, 0};
  // kBodyRate, kRampHarmonic, kSuspensionVoltage: i = index[0]; kBodyRateProduct: i, j (1..3).
  std::array<int, 2> index = {1, 1};
  int harmonic = 1;    // kOrbitalHarmonic: n, 1..kMaxOrbitalHarmonic
  bool sine = false;   // kOrbitalHarmonic, kCyclingHarmonic: sin (true) or cos (false)
  double period = 0;   // kOrbitalHarmonic, kCyclingHarmonic: [s], > 0
  double time_constant = 0;  // kExponentialDecay; kChannel lag and derivative: tau [s], > 0
  // kChannel: the declared channel's name, how the term reads it, and the channel's value at
  // which the value and lag forms give s = 0 [the channel's unit].
  std::string channel;
  ChannelForm form = ChannelForm::kValue;
  double reference = 0.0;
  // kOrbitalHarmonic, kCyclingHarmonic: phase zero; kRamp*: s = 0; kExponentialDecay: s = 1, 0 before it;
  // kSpinAxisHarmonic: switched on (0 before it).
  absl::Time epoch = absl::UnixEpoch();
  double value = 0.0;  // coefficient [rad/s per unit of s]
  double sigma = 0.0;  // prior 1-sigma [rad/s per unit of s]; > 0: estimated
};

// What a regressor may depend on at one instant.
struct BasisInputs {
  absl::Time time;
  Eigen::Vector3d h_k = Eigen::Vector3d::UnitZ();  // spin axis, case axes [1]
  Eigen::Vector3d w_k = Eigen::Vector3d::Zero();   // body rate in case axes [rad/s]
  std::optional<Eigen::Vector3d> u_k_v;            // suspension offset voltages [V]
  // The held channels and their lags (kChannel); null: a channel term gives 0.
  const ChannelSignals* channels = nullptr;
  // h_k's components to the powers 2 to kMaxHarmonicDegree, h_powers[i][e - 2] =
  // std::pow(h_k(i), e), for inputs a spin-axis term is evaluated at many times (a deviation
  // series' substeps, under every candidate): TabulateSpinAxisPowers. Empty: taken per term.
  std::optional<std::array<std::array<double, kMaxHarmonicDegree - 1>, 3>> h_powers;
};

// Fills in.h_powers from in.h_k (the same bits as the per-term powers).
void TabulateSpinAxisPowers(BasisInputs& in);

// InvalidArgument naming the field (prefix, e.g. "gyros[1].basisTerms[0]") when the term's
// indices, degree, harmonic, period or numbers are out of range or not finite.
absl::Status ValidateBasisTerm(const BasisTerm& term, std::string_view prefix);

// kChannel: `term.channel` must be one of `declared` (the configuration's channels), with the
// field named: "<prefix>.channel: \"T_x\" is not declared in channels (declared: ...)".
absl::Status CheckBasisChannel(const BasisTerm& term, const std::vector<std::string>& declared,
                               std::string_view prefix);

// s of the table above. A voltage term without voltages, a channel term without channels, gives 0.
double BasisScalar(const BasisTerm& term, const BasisInputs& in);

// d(dw_k)/d(value) = s e_m, 3 x 1 [rad/s per unit of value]; and the term's drift value * s e_m.
Eigen::Vector3d BasisRegressor_k(const BasisTerm& term, const BasisInputs& in);
Eigen::Vector3d BasisDrift_k(const BasisTerm& term, const BasisInputs& in);

// Sum of the terms' drifts [rad/s].
Eigen::Vector3d BasisDriftSum_k(const std::vector<BasisTerm>& terms, const BasisInputs& in);

// Short identifier, stable across runs: "h1^2*h3 -> x", "rate[2] -> z", "orbit cos 1 -> y",
// "ramp -> x", "ramp*h2^2 -> x", "voltage[1] -> z", "rate[1]*rate[3] -> y",
// "exp(-t/4.1h) -> y", "h2^2*cycle cos 24.3h -> y" (a harmonic's switch-on epoch is not in its
// label).
std::string BasisTermLabel(const BasisTerm& term);

// Unit of s in the JSON (deg/s for rates, h for ramps) and the factor from SI to it: the
// JSON value [deg/h per JSON unit of s] = SI value * ValueToJson(kind).
std::string_view BasisScalarJsonUnit(BasisKind kind);
double BasisValueToJson(BasisKind kind);

// The smallest size of s at which a term still matters, in the JSON unit of s (1 for the
// harmonics, 0.01 deg/s of body rate, 1e-4 (deg/s)^2, 1 h of ramp, 0.001 V): the configuration's
// limits bound value * this size (spacecraft_config.h kConfigLimits.basis_value).
double BasisReferenceSize(BasisKind kind);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_BASIS_TERM_H_
