// The SQLite schema of the service database and its migrations, keyed on PRAGMA user_version
// (docs/service.md "Durability and recovery"); a PostgreSQL database is created at the current
// version with the same tables (postgres_schema.h), and these functions dispatch to it. Column encodings shared by every store are defined
// here too.
//
// Versions (user_version):
//   0  empty file.
//   1  spacecraft_configs, telemetry_frames, coefficients, alerts (without `unit`), checkpoints.
//   2  alerts.unit; index alerts_by_time; diagnoses.
//   3  telemetry_frames keyed by (spacecraft, station, sequence), unique measurement time per
//      spacecraft; frames stored before belong to station "default".
//   4  alerts.cleared_time_unix_ns (NULL: not cleared, or cleared before version 4).
//   5  diagnoses.frames (frames diagnosed; diagnoses stored before get the count of the archived
//      frames in their span).
//   6  the reorder window (docs/service.md "Several ground stations"): coefficients and alerts
//      carry revised_time_unix_ns (NULL: current; else the wall-clock time a re-run over a
//      late frame superseded the row); late_frames (late frames archived but not yet applied by
//      a re-run); window_checkpoints (periodic session checkpoints the re-runs start from).
//   7  estimates (the per-step estimate archive, estimate_store.h).
//   8  coefficients.basis_terms_json (basis_terms_column.h; NULL: none, or stored before 8).
//   9  estimates.attitude_error_{x,y,z}_arcsec and attitude_error_sigma_{x,y,z}_arcsec (the
//      attitude error estimate of a step's star-tracker update; NULL: none, or stored before 9).
//  10  coefficient values keyed by term: coefficient_values (coefficient_id, term_key, value,
//      sigma), one row per value of records.h's layout, term_key its column name of versions
//      1-9 ("k0_deg_h", "misalignment_x_arcsec"); the 32 value and sigma columns of
//      coefficients move there and are dropped.
//  11  diagnoses.config_version and diagnoses.model_name (the configuration version and model a
//      diagnosis ran on; NULL for those stored before); gyro_readmissions (operators'
//      readmissions of excluded gyros, session_store.h).
//  12  diagnoses.requested_by ('service' for the service's automatic diagnosis, '' for a
//      Diagnose call; '' for those stored before) and diagnoses.answers_alert (the sequence of
//      the MODEL_INCONSISTENT alert an automatic diagnosis answers; 0 otherwise).
//  13  auto_diagnosis_cancels (an operator's cancel of the automatic diagnosis of a spacecraft,
//      per configuration version: none runs again under that version; diagnosis_store.h).
//  14  orbits (uploaded orbit deliveries, CCSDS OEM text as received, with the span they cover;
//      orbit_store.h).
//                                                                    <- kCurrentSchemaVersion
// Migration N -> N+1 is one function, applied in order, each in its own IMMEDIATE transaction
// together with the new user_version, so a crash mid-migration leaves the previous version
// intact. A migration's DDL is frozen once released: change the schema only by appending a
// migration.
//
// Encodings:
//   * instants: INTEGER columns named *_time_unix_ns, nanoseconds since 1970-01-01T00:00:00Z
//     (absl::Time, UTC without leap seconds; sub-nanosecond parts are truncated toward the
//     past). SQL users: datetime(measurement_time_unix_ns / 1e9, 'unixepoch').
//   * a NaN double is stored as NULL (SQLite has no NaN) and read back as NaN.
//   * booleans: INTEGER 0/1.
//   * coefficient values: a row per value in coefficient_values, keyed by the value's name with
//     its unit (records.h CoefficientColumns()), value and 1-sigma in that unit.
#ifndef ESG_STORAGE_SCHEMA_H_
#define ESG_STORAGE_SCHEMA_H_

#include <cstdint>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "storage/database.h"

namespace esg::storage {

inline constexpr int kCurrentSchemaVersion = 14;

// The DDL of version 11 in the dialect's types (SQLite INTEGER, PostgreSQL BIGINT).
std::string ReadmissionsMigration(Dialect dialect);

// The DDL of version 12 in the dialect's types: who asked for each diagnosis.
std::string DiagnosisOriginMigration(Dialect dialect);

// The DDL of version 13 in the dialect's types: operators' cancels of the automatic diagnosis.
std::string AutoDiagnosisCancelsMigration(Dialect dialect);

// The DDL of version 14 in the dialect's types: uploaded orbit deliveries.
std::string OrbitsMigration(Dialect dialect);

// The DDL of version 8, the same in both dialects.
inline constexpr absl::string_view kCoefficientBasisTermsColumn =
    "ALTER TABLE coefficients ADD COLUMN basis_terms_json TEXT;";

// The migration to version 10 in the dialect's types: the 16 values and sigmas of each coefficient
// row move to coefficient_values and their columns are dropped (SQLite rebuilds the table; the
// names are those of versions 1-9, frozen).
std::string KeyedCoefficientValuesMigration(Dialect dialect);

// PRAGMA user_version of the open database.
absl::StatusOr<int> SchemaVersion(Database& db);

// Brings the database to kCurrentSchemaVersion by running the missing migrations in order.
// Idempotent; safe against another process migrating the same file at the same time (the
// version is re-read inside each migration's write transaction). FailedPrecondition if the file
// is newer than this code (user_version > kCurrentSchemaVersion) or its user_version is negative;
// otherwise the errors of Database::Begin / Transaction::Execute.
absl::Status MigrateToCurrent(Database& db);

// Brings the database to exactly `target_version` (<= kCurrentSchemaVersion). For tests of the
// migration path; production code calls MigrateToCurrent(). InvalidArgument for a target
// outside [0, kCurrentSchemaVersion]; FailedPrecondition if the file is already newer.
absl::Status MigrateTo(Database& db, int target_version);

// Instant <-> INTEGER column. InfinitePast/InfiniteFuture map to INT64_MIN/INT64_MAX (useful as
// open query bounds) and back.
int64_t TimeToUnixNanos(absl::Time t);
absl::Time UnixNanosToTime(int64_t unix_ns);

// OK if `id` is a non-empty spacecraft id; otherwise InvalidArgument naming `field`.
absl::Status ValidateSpacecraftId(absl::string_view id, absl::string_view field);

// OK if `t` is finite and representable as int64 Unix nanoseconds (years 1678..2262);
// otherwise InvalidArgument naming `field`.
absl::Status ValidateStorableTime(absl::Time t, absl::string_view field);

}  // namespace esg::storage

#endif  // ESG_STORAGE_SCHEMA_H_
