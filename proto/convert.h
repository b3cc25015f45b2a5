// Conversions between the esg.v1 wire messages and the estimator's SI value types: the only place
// where proto and estimator types meet. Covers the spacecraft configuration and its
// JSON file, telemetry frames (same content as a recording CSV row; both in docs/formats.md), drift
// models (docs/physics.md) and timestamps. Unit conversions go through estimator/units.h.
//
// Error contract: every validation failure is absl::InvalidArgumentError whose message starts with
// the offending field, then ": ", then the reason, e.g.
//     "gyros[0].model.c1DegH: expected 3 values, got 2"      (configuration: JSON field names)
//     "gyros[1].h_k: norm 1.2 is not 1 (tolerance 0.001)"     (telemetry: proto field names)
// so a caller can split it at the first ": " (TelemetryAck.rejection {field, reason}).
#ifndef ESG_PROTO_CONVERT_H_
#define ESG_PROTO_CONVERT_H_

#include <cstdint>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "esg/v1/attitude.pb.h"
#include "esg/v1/spacecraft_config.pb.h"
#include "esg/v1/telemetry.pb.h"
#include "estimator/drift_model.h"
#include "estimator/model_terms.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"
#include "google/protobuf/timestamp.pb.h"

namespace esg::proto_convert {

// A spin-axis direction-cosine vector or a star-tracker quaternion is accepted when
// |norm - 1| <= kUnitNormTolerance. A real ESG readout or star-tracker output is unit to far
// better than this; the tolerance only catches wrong units, swapped or missing components.
inline constexpr double kUnitNormTolerance = 1e-3;
// Accepted vectors whose norm differs from 1 by more than this are renormalised; closer ones are
// kept as sent, so a value that was already unit round-trips bit for bit.
inline constexpr double kRenormaliseAbove = 1e-12;

// ---------------------------------------------------------------------------------------------
// Spacecraft configuration (docs/formats.md).

// Proto (deg/h, arcsec, V, um) -> SI (rad/s, rad, V, m). Applies the defaults documented in
// spacecraft_config.proto (suspension 200 / 200 V / 30 um, filter 8 Hz / 60 s / k_d 5 when 0;
// empty 3-vectors are zero), checks vector lengths (case_to_body 9, drift and noise vectors 0 or 3,
// pairs 2), then runs estimator::ValidateConfig (identifier rule for spacecraftId, the ranges of
// estimator::kConfigLimits, the channel declarations of estimator/channels.h; a maxAgeS that is
// not finite is refused here, "channels[0].maxAgeS: nan is not finite"). InvalidArgument names
// the JSON field, e.g.
// "gyros[0].caseToBody: expected 9 values, got 8", "workingPair: gyro 4 is not among the
// configured gyros" or "filter.integrationRateHz: 3e+07 is outside [0.1, 100] Hz (...)".
absl::StatusOr<estimator::SpacecraftConfig> ConfigFromProto(const esg::v1::SpacecraftConfig& proto);

// SI -> proto, complete: every vector written with all its values, suspension and filter with
// their effective values. Unit-converted values are rounded to 15 significant digits (a file
// reads 0.12, not 0.11999999999999998), so ConfigFromProto(ConfigToProto(c)) equals c to a
// relative 1e-15; the matrices, ids and dimensionless values are exact.
esg::v1::SpacecraftConfig ConfigToProto(const estimator::SpacecraftConfig& config);

// Parses the configuration JSON (proto3 JSON mapping of esg.v1.SpacecraftConfig, docs/formats.md),
// then ConfigFromProto. InvalidArgument for an unknown field ("gyros[0].k0: unknown field"), a
// value of the wrong JSON type ("gyros[2].model.k0DegH: invalid value "fast" for type TYPE_DOUBLE")
// and malformed JSON ("config JSON: <the parser's message>"); a key repeated in an object
// ("gyros[1].id: duplicate key ...") or an array inside an array ("gyros[0].caseToBody: an array
// inside an array ...") are refused before protobuf's parser, which would keep one of the values
// or flatten the array (proto/strict_json.h).
absl::StatusOr<estimator::SpacecraftConfig> ParseConfigJson(std::string_view json);

// Pretty-printed JSON ending in a newline (2-space indent, arrays of numbers and each keyed drift
// coefficient on one line, lowerCamelCase names, every field printed including zeros, except the
// deprecated fields of a drift model: its coefficients are keyed, DriftModelToProto) that
// ParseConfigJson reads back.
// Doubles are printed so that they parse back to the same double. Empty only if protobuf fails to
// print, which a message built by ConfigToProto cannot make it do.
std::string ConfigToJson(const estimator::SpacecraftConfig& config);

// One basis term (SI, estimator/basis_term.h) as the configuration holds it: an element of
// `gyros[].basisTerms`, in the units of its field names (deg/h per JSON unit of the regressor).
esg::v1::BasisTerm BasisTermToProto(const estimator::BasisTerm& term);
// The inverse; InvalidArgument "<prefix>.<field>: <reason>" for an unknown kind, a wrong count of
// exponents or indices or a bad epoch (the ranges are ValidateConfig's).
absl::StatusOr<estimator::BasisTerm> BasisTermFromProto(const esg::v1::BasisTerm& proto,
                                                        const std::string& prefix);
// The same, as compact JSON; the diagnosis reports the terms it found in this form.
std::string BasisTermToJson(const estimator::BasisTerm& term);

// File forms of the two above (the CLI's configuration files). ReadConfigFile: NotFound when the
// file cannot be opened, InvalidArgument "<path>: <field>: <reason>" when its content is bad.
// WriteConfigFile: InvalidArgument when ValidateConfig fails (nothing is written), Unavailable on
// an I/O failure. Writes "<path>.tmp" then renames it over <path>.

absl::StatusOr<estimator::SpacecraftConfig> ReadConfigFile(const std::string& path);
absl::Status WriteConfigFile(const std::string& path, const estimator::SpacecraftConfig& config);

// ---------------------------------------------------------------------------------------------
// Drift model (docs/physics.md): GyroDriftModel [deg/h] <-> DriftCoefficients [rad/s]. Used for the
// configuration and for CoefficientSnapshot.model / .sigma.

// `field` prefixes error messages, e.g. "gyros[0].model" -> "gyros[0].model.c2DegH: expected 3
// values, got 4". Empty vectors are zero. A coefficient may be given keyed instead
// (GyroDriftModel.coefficients: "gyros[0].model.coefficients[2].term: unknown term ..." for a key
// not in estimator/model_terms.h, one given twice, or one also given by its field). Values are
// not range-checked here.
absl::StatusOr<estimator::DriftCoefficients> DriftModelFromProto(const esg::v1::GyroDriftModel& proto,
                                                                 std::string_view field);
// Every coefficient keyed (GyroDriftModel.coefficients), in the table's order, none in the
// deprecated fields; rounded to 15 significant digits like ConfigToProto.
esg::v1::GyroDriftModel DriftModelToProto(const estimator::DriftCoefficients& coefficients);

// One coefficient of a GyroDriftModel as on the wire [deg/h], found by its descriptor
// (estimator/model_terms.h): its keyed entry (coefficients[].term == term.storage_key) if the
// message has one, otherwise the field whose JSON name is term.json_key, entry term.component;
// an entry the message does not hold reads 0 (an empty vector is zero).
double DriftModelTermDegH(const esg::v1::GyroDriftModel& model,
                          const estimator::FixedTermDescriptor& term);
// Sets it in its keyed entry (added after the others when the message has none). Coefficients
// the message gives by their deprecated fields are first moved to keyed entries, so that no term
// is given both ways.
void SetDriftModelTermDegH(const estimator::FixedTermDescriptor& term, double deg_h,
                           esg::v1::GyroDriftModel* model);

// ---------------------------------------------------------------------------------------------
// Telemetry frames (docs/formats.md).

// Validates and converts one frame. Checks, in this order: spacecraft_id satisfies
// estimator::ValidateIdentifier (1..64 characters from [A-Za-z0-9._:-]; whether it is configured
// is the caller's, as is `sequence`); `time` present and valid; each gyro_id in 1..4 and not
// repeated; h_k exactly 3 finite values with unit norm (kUnitNormTolerance); u_k_mv empty or 3
// finite values; star_tracker absent = outage; star_tracker.valid: q_in_b exactly 4 finite values,
// unit norm; not valid: q_in_b empty or 4 finite values, not carried (the reading is kept with
// valid = false and an identity quaternion); channels: at most estimator::kMaxChannels ("channels:
// 65 channels, at most 64 in a frame"), each name a channel name and each value finite
// (estimator::ValidateFrameChannels: `channels["T_gyro2"]: nan is not finite`), whether each is
// declared and in range being the caller's (estimator::CheckDeclaredChannels). Accepted vectors
// are renormalised as described at
// kRenormaliseAbove. Errors: InvalidArgument "<field>: <reason>", field in proto names, e.g.
// "spacecraft_id: character '\n' at index 5 of ...", "gyros[1].h_k: norm 1.2 is not 1
// (tolerance 0.001)", "star_tracker.q_in_b[2]: nan is not finite", "gyros[2].gyro_id: gyro 3
// appears twice".
absl::StatusOr<estimator::TelemetryFrame> FrameFromProto(const esg::v1::TelemetryFrame& proto);

// The reverse: gyros in id order, u_k_mv only when present, star_tracker only when present
// (q_in_b empty when not valid), the channels the frame carries. Quaternions are written as
// stored (no sign canonicalisation).
esg::v1::TelemetryFrame FrameToProto(const estimator::TelemetryFrame& frame,
                                     std::string spacecraft_id, int64_t sequence);

// ---------------------------------------------------------------------------------------------
// Time (UTC instants, conventions.h §9).

// InvalidArgument when seconds lie outside 0001-01-01..9999-12-31 or nanos outside
// 0..999999999 (the google.protobuf.Timestamp rules).
absl::StatusOr<absl::Time> TimeFromProto(const google::protobuf::Timestamp& timestamp);
// Truncates below 1 ns (absl::Time resolves 1/4 ns); instants outside the Timestamp range,
// including absl::InfinitePast/InfiniteFuture, are clamped to its ends.
google::protobuf::Timestamp TimeToProto(absl::Time time);

}  // namespace esg::proto_convert

#endif  // ESG_PROTO_CONVERT_H_
