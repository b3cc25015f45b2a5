// Plain value types stored by the SQLite stores (docs/formats.md "Time" and "Alerts").
// They carry no gRPC or proto types: the server converts. Times are UTC instants (absl::Time);
// every record kept by the service carries the measurement epoch (the telemetry's own time) and,
// where it is a computed product, the instant the service computed it.
#ifndef ESG_STORAGE_RECORDS_H_
#define ESG_STORAGE_RECORDS_H_

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "estimator/basis_term.h"
#include "estimator/drift_model.h"

namespace esg::storage {

// One version of a spacecraft's configuration (JSON of docs/formats.md, stored verbatim).
struct ConfigRecord {
  std::string spacecraft_id;
  std::string config_json;
  absl::Time updated_time = absl::UnixEpoch();
  int64_t version = 0;  // 1, 2, ... per spacecraft; assigned by ConfigStore::Put, ignored on input
};

// One accepted telemetry frame, kept so a session can be recalibrated or replayed.
// The station of a frame that names none (docs/service.md "Ingest contract").
inline constexpr char kDefaultStation[] = "default";

// One archived frame. Identity: (spacecraft_id, station_id, sequence). The measurement time is
// unique per spacecraft too, and orders the frames for the filter.
struct ArchivedFrame {
  std::string spacecraft_id;
  std::string station_id = kDefaultStation;
  int64_t sequence = 0;  // the frame's sequence number in its station's stream
  absl::Time measurement_time = absl::UnixEpoch();
  std::string payload;  // serialized frame bytes, format chosen by the server
};

// Layout of CoefficientRecord::values and ::sigmas: kNumCoefficientValues numbers in this fixed
// order, in SI like every record: the drift terms of estimator/model_terms.h in theta order
// (eq. (1), (8)-(10), docs/physics.md), indexed by theta's offsets (estimator/drift_model.h
// kTheta*), all [rad/s]; then the misalignment, a small rotation vector about body axes b [rad].
// Each is stored as a row of table `coefficient_values` keyed by its name with its unit
// (CoefficientColumns() below), value and 1-sigma in that unit (deg/h for the drift terms, arcsec
// for the misalignment): CoefficientStore converts at the rows, so a user of plain SQL reads the
// units operators use.
inline constexpr int kCoefficientMisalignment = estimator::kNumDriftCoefficients;
inline constexpr int kNumCoefficientValues = kCoefficientMisalignment + 3;

// Names of the values (their storage keys, coefficient_values.term_key) and of the sigmas, in
// layout order: the drift terms' from their descriptors (estimator/model_terms.h: "k0_deg_h",
// "k0_sigma_deg_h", ...), then "misalignment_x_arcsec", ..., "misalignment_z_sigma_arcsec".
// Defined in coefficient_store.cc.
const std::array<std::string, kNumCoefficientValues>& CoefficientColumns();
const std::array<std::string, kNumCoefficientValues>& CoefficientSigmaColumns();

// One estimate of one gyro's model coefficients.
struct CoefficientRecord {
  std::string spacecraft_id;
  int gyro_id = 0;                                  // 1..4 as in the configuration
  absl::Time measurement_time = absl::UnixEpoch();  // epoch of the telemetry the estimate uses
  absl::Time compute_time = absl::UnixEpoch();
  std::vector<double> values;  // kNumCoefficientValues, layout above [rad/s, rad]; NaN = not estimated
  std::vector<double> sigmas;  // 1-sigma, same layout and units, or empty when unknown; NaN = unknown
  std::string model_name;      // e.g. "model10"
  // The gyro's configured basis terms (drift terms beyond eq. (1), (10), estimator/basis_term.h),
  // in configuration order, each with `value` the estimate and `sigma` its 1-sigma (0: held at its
  // value), SI [rad/s per SI unit of the term's regressor]; empty when the gyro has none.
  std::vector<estimator::BasisTerm> basis_terms;
  // Wall-clock time a re-run over a late frame superseded this estimate (docs/service.md
  // "Several ground stations"); InfinitePast: current. Ignored on input (stored current).
  absl::Time revised_time = absl::InfinitePast();
};

// One alert (docs/formats.md "Alerts": Yamcs/COSMOS/Open MCT conventions).
struct AlertRecord {
  std::string spacecraft_id;
  int64_t sequence = 0;      // 1, 2, ... per spacecraft; assigned by the store, ignored on input
  std::string severity;      // e.g. "WATCH", "WARNING", "CRITICAL" (the server's vocabulary)
  std::string reason;        // machine-readable reason code, e.g. "INNOVATION_TEST"
  std::string subsystem;     // e.g. "gyro2", "star_tracker", "pair(1,2)"
  double value = 0.0;        // the triggering value, in `unit`; NaN allowed
  double threshold = 0.0;    // the threshold it was tested against, in `unit`; NaN allowed
  std::string unit;          // e.g. "arcsec"
  int64_t repeat_count = 1;  // occurrences collapsed into this alert, >= 1
  absl::Time first_time = absl::UnixEpoch();        // measurement epoch of the first occurrence
  absl::Time measurement_time = absl::UnixEpoch();  // measurement epoch of the latest occurrence
  absl::Time compute_time = absl::UnixEpoch();
  std::string message;
  bool acknowledged = false;
  std::string acknowledged_by;
  absl::Time acknowledged_time = absl::InfinitePast();  // InfinitePast while not acknowledged
  bool cleared = false;
  // Measurement epoch at which the service found the condition over (server/alert_catalog.h
  // ClearRule); InfinitePast while not cleared, or when cleared before it was stored.
  absl::Time cleared_time = absl::InfinitePast();
  // Wall-clock time a re-run over a late frame superseded this alert (docs/service.md "Several
  // ground stations"); InfinitePast: current. Ignored on input (stored current).
  absl::Time revised_time = absl::InfinitePast();
};

// A repeat of an existing alert, collapsed into it (AlertStore::UpdateRepeat).
struct AlertRepeat {
  std::string spacecraft_id;
  int64_t sequence = 0;
  int64_t repeat_count = 1;                  // the new total, >= 1
  absl::Time last_time = absl::UnixEpoch();  // measurement epoch of the latest occurrence
};

// The star-tracker innovation of one gyro at one measurement step: the spin axis the star
// tracker implies minus the filter's predicted one, in the gyro's tangent basis (z2..z5 of eq.
// (13), before the eq. (14) decision), and its 1-sigma (square root of the innovation
// covariance's diagonal). SI like every record [rad].
struct GyroInnovationRecord {
  int gyro_id = 0;  // 1..4
  std::array<double, 2> innovation = {0.0, 0.0};
  std::array<double, 2> sigma = {0.0, 0.0};
};

// The filter's output at one measurement step (the per-step estimate archive, docs/service.md
// "Per-step estimates"). Identity: (spacecraft_id, measurement_time); storing a record again at
// the same identity replaces it.
struct EstimateRecord {
  std::string spacecraft_id;
  absl::Time measurement_time = absl::UnixEpoch();  // epoch of the step's telemetry frame
  absl::Time compute_time = absl::UnixEpoch();      // when the service computed it
  std::string state;  // session state after the step (estimator::SessionStateName)
  // Attitude output of the step; q_in_b, sigma_b and output_pair are meaningful only when valid
  // (not stored otherwise).
  bool attitude_valid = false;
  std::array<double, 4> q_in_b = {1.0, 0.0, 0.0, 0.0};  // scalar first (q0, q1, q2, q3) [1]
  std::array<double, 3> sigma_b = {0.0, 0.0, 0.0};      // 1-sigma about body x, y, z [rad]
  std::array<int, 2> output_pair = {0, 0};              // gyro ids, reference gyro first
  std::string attitude_invalid_reason;                  // empty when valid
  bool star_tracker_used = false;
  // One per healthy gyro, in the session's gyro order; empty when none were formed.
  std::vector<GyroInnovationRecord> star_tracker_innovations;
  double star_tracker_test_ratio = 0.0;  // largest normalised innovation of eq. (14) [1]
  // Latest step at or before this one that applied the star tracker; InfinitePast: none yet.
  absl::Time last_star_tracker_time = absl::InfinitePast();
  // The attitude error estimate of the step's star-tracker update (estimator::StepReport::
  // attitude_error_b_arcsec): the correction about body x, y, z and its 1-sigma [rad];
  // meaningful only when has_attitude_error (not stored otherwise).
  bool has_attitude_error = false;
  std::array<double, 3> attitude_error_b = {0.0, 0.0, 0.0};
  std::array<double, 3> attitude_error_sigma_b = {0.0, 0.0, 0.0};
};

// The latest checkpoint of a spacecraft's estimation session (one per spacecraft).
struct CheckpointRecord {
  std::string spacecraft_id;
  int64_t last_sequence = 0;  // sequence of the last frame the state includes
  absl::Time measurement_time = absl::UnixEpoch();
  absl::Time compute_time = absl::UnixEpoch();
  std::string state_blob;  // serialized session state, format chosen by the server
};

// The result of one model-discrepancy diagnosis over [from_time, to_time) (docs/discovery.md).
struct DiagnosisRecord {
  std::string spacecraft_id;
  int64_t id = 0;  // assigned by DiagnosisStore::Put, ignored on input
  absl::Time from_time = absl::UnixEpoch();
  absl::Time to_time = absl::UnixEpoch();
  absl::Time compute_time = absl::UnixEpoch();
  std::string verdict;      // e.g. "gyro_misalignment", "unexplained"
  std::string report_json;  // full report, stored verbatim
  int64_t frames = 0;       // frames diagnosed (>= 0)
  // The configuration version (ConfigRecord::version) and the model name ("10+11") the diagnosis
  // ran on; 0 and empty for a diagnosis stored before schema version 11 (not recorded).
  int64_t config_version = 0;
  std::string model_name;
  // Who asked for it: kRequestedByService for the service's automatic diagnosis of a
  // MODEL_INCONSISTENT alert (docs/service.md "Automatic diagnosis"), empty for a Diagnose call
  // (and for every diagnosis stored before schema version 12); answers_alert: the sequence of
  // the alert an automatic diagnosis answers, 0 otherwise.
  std::string requested_by;
  int64_t answers_alert = 0;
};

inline constexpr const char* kRequestedByService = "service";

// An operator's cancel of the service's automatic diagnosis of a spacecraft (docs/service.md
// "Automatic diagnosis"): none runs again for it under `config_version` (ConfigRecord::version),
// across restarts; a new configuration version starts afresh.
struct AutoCancelRecord {
  std::string spacecraft_id;
  int64_t config_version = 0;  // >= 1
  int64_t answers_alert = 0;   // the sequence of the alert the cancelled diagnosis answered
  absl::Time cancel_time = absl::UnixEpoch();  // wall clock
};

// An operator's readmission of a gyro the filter excluded (docs/service.md "Readmitting a gyro"):
// the gyro rejoins the filter at the first measurement step after `after_time`, the measurement
// time of the last frame applied when it was stored; a re-run from the archive applies it there
// again.
struct ReadmissionRecord {
  std::string spacecraft_id;
  int gyro_id = 0;
  absl::Time after_time = absl::UnixEpoch();
  absl::Time compute_time = absl::UnixEpoch();  // wall clock when stored
  std::string operator_name;
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_RECORDS_H_
