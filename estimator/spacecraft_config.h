// Spacecraft configuration value types (JSON of docs/formats.md, proto esg.v1.SpacecraftConfig).
// Everything here is SI: drift coefficients in rad/s, noise in rad. proto/convert.cc converts
// from and to the deg/h and arcsec of the JSON form.
#ifndef ESG_ESTIMATOR_SPACECRAFT_CONFIG_H_
#define ESG_ESTIMATOR_SPACECRAFT_CONFIG_H_

#include <array>
#include <string>
#include <tuple>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/strings/string_view.h"
#include "estimator/basis_term.h"
#include "estimator/channels.h"
#include "estimator/drift_model.h"
#include "estimator/units.h"

namespace esg::estimator {

struct GyroConfig {
  int id = 0;  // 1..kMaxGyros.
  // C_b_k: case frame k to body b.
  Eigen::Matrix3d C_b_k = Eigen::Matrix3d::Identity();
  // A-priori (bench) drift model the user believes [rad/s].
  DriftCoefficients model;
  // 1-sigma prior uncertainty of each coefficient [rad/s]; > 0 means estimated (free),
  // 0 means held at its model value.
  DriftCoefficients model_sigma;
  // Prior 1-sigma of the gyro-to-star-tracker misalignment per body axis [rad]; 0 = not estimated.
  double misalignment_sigma = 0.0;
  // Drift terms beyond eq. (1), (10) (basis_term.h), e.g. found by the diagnosis's open-ended
  // stage; a term with sigma > 0 is calibrated.
  std::vector<BasisTerm> basis_terms;
  // Symmetric distortion D of the spin-axis readout [1]: the reading is h_meas = (I + D) h_k
  // normalised; the filter uses normalise((I + D)^-1 h_meas). Zero: none.
  Eigen::Matrix3d readout_distortion = Eigen::Matrix3d::Zero();
};

struct StarTrackerConfig {
  // 1-sigma noise about the body x, y, z axes [rad].
  Eigen::Vector3d noise = Eigen::Vector3d::Zero();
  // Time-tag error [s]: positive when the quaternion stamped t is the attitude at t - latency.
  // The filter corrects each sample to q_in_b(t) = q_st(t) (x) Exp(w_b latency) with the body
  // rate w_b its gyro pairs measure (as the diagnosis's star-tracker latency effect does).
  double latency = 0.0;
  // Prior 1-sigma of the latency [s]; > 0: the latency is a filter state, estimated online from
  // the star-tracker differences with `latency` as its prior mean; 0: held at `latency`.
  double latency_sigma = 0.0;
};

// Rotor-displacement readout of eq. (3): Delta = k * dU * d0 / U0.
struct SuspensionConfig {
  double amplifier_gain = 200.0;     // k [1]
  double reference_voltage = 200.0;  // U0 [V]
  double gap = 30e-6;                // d0 [m]
};

struct FilterConfig {
  double integration_rate_hz = 8.0;  // propagation rate [Hz]
  double measurement_step = 60.0;    // measurement update step [s]
  double innovation_kd = 5.0;        // k_d of eq. (14)
  double fault_threshold = 0.0;      // allowed mismatch angle of eq. (12) [rad]; 0 = derived
  // A change of a gyro's drift larger than this excludes the gyro; a smaller one is a drift
  // change, alerted and recalibrated (reading_fault_monitor.h, D94) [rad/s].
  double drift_change_limit = DegPerHourToRadPerSec(1.0);
};

struct SpacecraftConfig {
  std::string spacecraft_id;
  std::vector<GyroConfig> gyros;
  std::array<int, 2> working_pair = {1, 2};  // gyro ids, reference first
  std::array<int, 2> reserve_pair = {1, 3};
  StarTrackerConfig star_tracker;
  double readout_noise = 0.0;  // 1-sigma readout noise of h_k, per axis [rad]
  // Intensity of each gyro's residual random-walk drift, model (11) [rad/s/sqrt(s)].
  double random_walk = 0.0;
  SuspensionConfig suspension;
  FilterConfig filter;
  // Auxiliary housekeeping channels a frame may carry (channels.h); none: a frame carrying any
  // channel is refused.
  std::vector<ChannelConfig> channels;

  // Gyro by id, or nullptr.
  const GyroConfig* FindGyro(int id) const;
};

// ---------------------------------------------------------------------------------------------
// Input limits (docs/service.md "Limits"). Every bound below is inclusive and stated in the units
// of the JSON field it guards (spacecraft_config.proto), with the physical reason that sets it.
// The bounds are a factor of about 30-100 beyond the paper's values (k0 a few tenths of deg/h,
// C1/C2 up to 0.2 deg/h, priors 0.3 and 0.1 deg/h, star tracker 5/5/30 arcsec, readout 3 arcsec,
// 8 Hz, 60 s, k_d 4..6), so any real ESG system fits, while a value in the wrong unit, a typo or a
// hostile value that would make the filter run away is refused.

// A spacecraft or station identifier: 1..64 characters from [A-Za-z0-9._:-], starting with a
// letter or digit.
inline constexpr int kMaxIdentifierLength = 64;
// Characters of a refused value quoted in its error message (escaped with absl::CHexEscape).
inline constexpr int kIdentifierQuoteLength = 32;

// One numeric configuration limit: value in [min, max] of `unit`. A value equal to a bound in the
// JSON's unit passes even after the SI round trip (relative slack 1e-12); NaN and infinities fail.
struct ConfigLimit {
  const char* field;  // JSON field, "[]" where an index goes: "gyros[].model.k0DegH"
  double min;
  double max;
  const char* unit;           // unit of min, max and the JSON field, e.g. "deg/h"
  double (*from_si)(double);  // SI value of spacecraft_config.h -> `unit`
  const char* typical;        // default or the paper's value, for the documentation
  const char* reason;         // why these bounds; ends the error message
};

// The one table of numeric limits, read by ValidateConfig and by the documentation (All()).
struct ConfigLimits {
  ConfigLimit drift_coefficient;
  ConfigLimit drift_sigma;
  ConfigLimit misalignment_sigma;
  ConfigLimit star_tracker_noise;
  ConfigLimit star_tracker_latency;
  ConfigLimit star_tracker_latency_sigma;
  ConfigLimit readout_noise;
  ConfigLimit random_walk;
  ConfigLimit amplifier_gain;
  ConfigLimit reference_voltage;
  ConfigLimit gap;
  ConfigLimit integration_rate;
  ConfigLimit measurement_step;
  ConfigLimit innovation_kd;
  ConfigLimit fault_threshold;
  ConfigLimit drift_change_limit;
  // The basis terms' value and sigma are checked in the JSON unit (deg/h per JSON unit of s,
  // basis_term.h BasisValueToJson), which depends on the term's kind: their from_si is the
  // identity and ValidateConfig converts before the check.
  ConfigLimit basis_value;
  ConfigLimit basis_sigma;
  ConfigLimit readout_distortion;

  // Every limit above, in declaration order.
  constexpr std::array<ConfigLimit, 19> All() const {
    return {drift_coefficient,    drift_sigma,    misalignment_sigma,
            star_tracker_noise,   star_tracker_latency,
            star_tracker_latency_sigma,
            readout_noise,        random_walk,    amplifier_gain,
            reference_voltage,    gap,            integration_rate,
            measurement_step,     innovation_kd,  fault_threshold,
            drift_change_limit,
            basis_value,          basis_sigma,    readout_distortion};
  }
};

// At most this many basis terms per gyro: each free one is a filter state of its gyro's block
// (the largest diagnosis adds a handful), and 16 keep a three-gyro state below about 100.
inline constexpr int kMaxBasisTermsPerGyro = 16;
// readoutDistortion must be symmetric to this absolute tolerance [1].
inline constexpr double kReadoutDistortionSymmetryTolerance = 1e-12;

namespace config_limits_internal {
constexpr double Identity(double x) { return x; }
constexpr double MetresToUm(double x) { return x / kMetresPerUm; }
}  // namespace config_limits_internal

inline constexpr ConfigLimits kConfigLimits = {
    .drift_coefficient = {"gyros[].model.{k0,c1,c2,mu,nu}DegH", -10.0, 10.0, "deg/h",
                          &RadPerSecToDegPerHour,
                          "k0 0.2..0.3, C1/C2 up to 0.2, mu/nu about 0.01",
                          "the paper's k0 is a few tenths of deg/h and C1, C2 reach 0.2 deg/h; "
                          "10 deg/h is 30-50 times that"},
    .drift_sigma = {"gyros[].modelSigma.{k0,c1,c2,mu,nu}DegH", 0.0, 10.0, "deg/h",
                    &RadPerSecToDegPerHour, "0.3 (k0), 0.1 (C1, C2, mu, nu)",
                    "the paper's priors are 0.3 deg/h (k0) and 0.1 deg/h (C); 10 deg/h is "
                    "30-100 times that and wider than any real coefficient"},
    .misalignment_sigma = {"gyros[].misalignmentSigmaArcsec", 0.0, 3600.0, "arcsec",
                           &RadToArcsec, "30 (example), 60 (diagnosis prior)",
                           "the misalignment is a small-angle error state; 1 deg is 60-120 times "
                           "the usual prior"},
    .star_tracker_noise = {"starTracker.noiseArcsec[]", 0.0, 3600.0, "arcsec", &RadToArcsec,
                           "5, 5, 30",
                           "a star tracker is good to arcseconds; at 1 deg (120 times the "
                           "paper's worst axis) it carries no information on arcsec-level drift"},
    .star_tracker_latency = {"starTracker.latencyS", -10.0, 10.0, "s",
                             &config_limits_internal::Identity, "0 (the diagnosis reports it)",
                             "star-tracker time tags err by milliseconds to a fraction of a "
                             "second; 10 s is a clock fault, not a latency to correct"},
    .star_tracker_latency_sigma = {"starTracker.latencySigmaS", 0.0, 10.0, "s",
                                   &config_limits_internal::Identity,
                                   "0 (held), 0.5 to estimate an unknown latency",
                                   "the latency state is linear only while the attitude turns "
                                   "by small angles over it; 10 s is a clock fault"},
    .readout_noise = {"readoutNoiseArcsec", 0.0, 300.0, "arcsec", &RadToArcsec, "3",
                      "an ESG spin-axis readout is good to a few arcsec (3 in the paper); "
                      "300 arcsec is 100 times that"},
    .random_walk = {"randomWalkDegHSqrtH", 0.0, 1.0, "deg/h/sqrt(h)", &SiToDegPerHourSqrtHour,
                    "0.0015 (0.0005..0.003)",
                    "a residual drift wandering by 1 deg/h within an hour exceeds the whole "
                    "modelled drift of an ESG (a few tenths of deg/h)"},
    .amplifier_gain = {"suspension.amplifierGain", 1.0, 10000.0, "1",
                       &config_limits_internal::Identity, "200",
                       "eq. (3) readout gain; 50 times the default, below 1 it is no amplifier"},
    .reference_voltage = {"suspension.referenceVoltageV", 1.0, 10000.0, "V",
                          &config_limits_internal::Identity, "200",
                          "ESG suspension voltages are hundreds of volts; 10 kV is 50 times "
                          "the default"},
    .gap = {"suspension.gapUm", 1.0, 1000.0, "um", &config_limits_internal::MetresToUm, "30",
            "ESG electrode gaps are tens of um; 1 mm is 33 times the default"},
    .integration_rate = {"filter.integrationRateHz", 0.1, 100.0, "Hz",
                         &config_limits_internal::Identity, "8 (the paper), 0.2 in diagnosis",
                         "the propagation step must resolve the drift as the spin axes move (at "
                         "least one step per 10 s) and stay affordable (at most 100 per second, "
                         "12 times the paper's 8 Hz: 6.05e7 steps for a 7-day gap)"},
    .measurement_step = {"filter.measurementStepS", 1.0, 3600.0, "s",
                         &config_limits_internal::Identity, "60",
                         "star-tracker errors are correlated over about a second, so faster "
                         "updates count one error twice; slower than hourly (60 times the "
                         "paper's 60 s) leaves the tests of eq. (12) and (14) hours apart"},
    .innovation_kd = {"filter.innovationKd", 2.0, 20.0, "1", &config_limits_internal::Identity,
                      "5 (the paper: 4..6)",
                      "below 2 eq. (14) rejects about 5% of good samples per axis, above 20 it "
                      "lets through outliers of many arcmin"},
    .fault_threshold = {"filter.faultThresholdArcsec", 0.0, 648000.0, "arcsec", &RadToArcsec,
                        "0 (derived from the noise), 180 deg in diagnosis",
                        "a mismatch angle between two attitudes is at most 180 deg; 0 derives "
                        "the threshold from the noise"},
    .drift_change_limit = {"filter.driftChangeLimitDegH", 0.01, 100.0, "deg/h",
                           &RadPerSecToDegPerHour, "1",
                           "a drift change below the limit is recalibrated, above it the gyro is "
                           "excluded: below 0.01 deg/h the random walk of eq. (11) alone crosses it "
                           "within hours; above 100 deg/h a reading frozen while the spacecraft "
                           "turns slowly would pass as a drift"},
    .basis_value = {"gyros[].basisTerms[].valueDegH", -10.0, 10.0,
                    "deg/h at the kind's reference size of s", &config_limits_internal::Identity,
                    "a few hundredths to tenths of deg/h (the diagnosis's findings)",
                    "the value times the smallest regressor at which a term still matters (a "
                    "unit spin-axis or orbital harmonic, 0.01 deg/s of body rate, (0.01 deg/s)^2 "
                    "of its square, 1 h of ramp, 1 mV of offset voltage) is a drift no larger "
                    "than the eq. (1) coefficients may be: 10 deg/h is 30-50 times the paper's "
                    "largest"},
    .basis_sigma = {"gyros[].basisTerms[].sigmaDegH", 0.0, 10.0,
                    "deg/h at the kind's reference size of s", &config_limits_internal::Identity,
                    "0 (held), 0.1 deg/h at the regressor's RMS to calibrate",
                    "the prior of a term is that of an eq. (1) coefficient (0.1 deg/h in the "
                    "paper); 10 deg/h at the reference size of its regressor is 100 times that"},
    .readout_distortion = {"gyros[].readoutDistortion[]", -0.01, 0.01, "1",
                           &config_limits_internal::Identity, "0 (none)",
                           "a 1% distortion of the readout bends a spin-axis reading by up to "
                           "0.6 deg, 700 times the paper's 3 arcsec noise; beyond that the "
                           "readout is broken, not distorted"},
};
static_assert(sizeof(ConfigLimits) == std::tuple_size_v<decltype(kConfigLimits.All())> *
                                          sizeof(ConfigLimit),
              "ConfigLimits::All() must list every limit");

// InvalidArgument "<field>: ..." unless `value` satisfies the identifier rule above. The message
// quotes at most kIdentifierQuoteLength characters of the value with non-printable bytes escaped
// (absl::CHexEscape), so no raw control character or huge value ever reaches a message.
absl::Status ValidateIdentifier(absl::string_view value, absl::string_view field);

// InvalidArgument "<field>: <value> is outside [min, max] <unit> (<reason>)" unless the SI value
// `value_si`, converted with limit.from_si, lies within `limit`.
absl::Status CheckLimit(double value_si, const ConfigLimit& limit, absl::string_view field);

// Checks the spacecraft id (ValidateIdentifier), gyro ids and pairs, caseToBody (a proper
// rotation: orthonormal to 1e-6, det +1), every numeric field against kConfigLimits, each gyro's
// basis terms (at most kMaxBasisTermsPerGyro, ValidateBasisTerm, then value and sigma in their JSON
// unit: "gyros[0].basisTerms[1].axis: must be 1..3, got 4") and its readoutDistortion (symmetric
// to kReadoutDistortionSymmetryTolerance, each entry within its limit) and the channel
// declarations (channels.h ValidateChannelConfigs: "channels[2].validMin: ..."). The
// message of an InvalidArgument names the JSON field, e.g. "gyros[1].caseToBody: not a proper
// rotation matrix ..." or "filter.integrationRateHz: 3e+07 is outside [0.1, 100] Hz (...)".
absl::Status ValidateConfig(const SpacecraftConfig& config);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_SPACECRAFT_CONFIG_H_
