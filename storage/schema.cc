// Schema DDL and migrations; contract and version history in schema.h.
#include "storage/schema.h"

#include <cstdint>
#include <iterator>
#include <limits>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/status_macros.h"
#include "estimator/utc_time.h"
#include "storage/postgres_schema.h"

namespace esg::storage {
namespace {

// Frozen schema history, begin. The DDL of versions 1-9 and their coefficient columns describe
// what databases of those versions hold, not the current terms (estimator/model_terms.h); the
// text up to the end mark is pinned by tests/estimator/model_terms_test.cc.
// Version 1: the first layout. Frozen: never edit, append a migration instead.
constexpr absl::string_view kSchemaV1 = R"sql(
CREATE TABLE spacecraft_configs (
  spacecraft_id        TEXT    NOT NULL,
  version              INTEGER NOT NULL CHECK (version >= 1),
  updated_time_unix_ns INTEGER NOT NULL,
  config_json          TEXT    NOT NULL,
  PRIMARY KEY (spacecraft_id, version)
);

CREATE TABLE telemetry_frames (
  spacecraft_id            TEXT    NOT NULL,
  sequence                 INTEGER NOT NULL,
  measurement_time_unix_ns INTEGER NOT NULL,
  payload                  BLOB    NOT NULL,
  PRIMARY KEY (spacecraft_id, sequence)
);
CREATE INDEX telemetry_frames_by_time
  ON telemetry_frames (spacecraft_id, measurement_time_unix_ns);

CREATE TABLE coefficients (
  id                          INTEGER PRIMARY KEY,
  spacecraft_id               TEXT    NOT NULL,
  gyro_id                     INTEGER NOT NULL CHECK (gyro_id >= 1),
  measurement_time_unix_ns    INTEGER NOT NULL,
  compute_time_unix_ns        INTEGER NOT NULL,
  model_name                  TEXT    NOT NULL,
  k0_deg_h                    REAL,
  c1x_deg_h                   REAL,
  c1y_deg_h                   REAL,
  c1z_deg_h                   REAL,
  c2x_deg_h                   REAL,
  c2y_deg_h                   REAL,
  c2z_deg_h                   REAL,
  mu12_deg_h                  REAL,
  mu23_deg_h                  REAL,
  mu31_deg_h                  REAL,
  nu23_deg_h                  REAL,
  nu31_deg_h                  REAL,
  nu12_deg_h                  REAL,
  misalignment_x_arcsec       REAL,
  misalignment_y_arcsec       REAL,
  misalignment_z_arcsec       REAL,
  k0_sigma_deg_h              REAL,
  c1x_sigma_deg_h             REAL,
  c1y_sigma_deg_h             REAL,
  c1z_sigma_deg_h             REAL,
  c2x_sigma_deg_h             REAL,
  c2y_sigma_deg_h             REAL,
  c2z_sigma_deg_h             REAL,
  mu12_sigma_deg_h            REAL,
  mu23_sigma_deg_h            REAL,
  mu31_sigma_deg_h            REAL,
  nu23_sigma_deg_h            REAL,
  nu31_sigma_deg_h            REAL,
  nu12_sigma_deg_h            REAL,
  misalignment_x_sigma_arcsec REAL,
  misalignment_y_sigma_arcsec REAL,
  misalignment_z_sigma_arcsec REAL
);
CREATE INDEX coefficients_by_time
  ON coefficients (spacecraft_id, measurement_time_unix_ns, gyro_id);

CREATE TABLE alerts (
  spacecraft_id            TEXT    NOT NULL,
  sequence                 INTEGER NOT NULL CHECK (sequence >= 1),
  severity                 TEXT    NOT NULL,
  reason                   TEXT    NOT NULL,
  subsystem                TEXT    NOT NULL,
  value                    REAL,
  threshold                REAL,
  repeat_count             INTEGER NOT NULL CHECK (repeat_count >= 1),
  first_time_unix_ns       INTEGER NOT NULL,
  measurement_time_unix_ns INTEGER NOT NULL,
  compute_time_unix_ns     INTEGER NOT NULL,
  message                  TEXT    NOT NULL,
  acknowledged             INTEGER NOT NULL DEFAULT 0,
  acknowledged_by          TEXT,
  acknowledged_time_unix_ns INTEGER,
  cleared                  INTEGER NOT NULL DEFAULT 0,
  PRIMARY KEY (spacecraft_id, sequence)
);

CREATE TABLE checkpoints (
  spacecraft_id            TEXT    NOT NULL PRIMARY KEY,
  last_sequence            INTEGER NOT NULL,
  measurement_time_unix_ns INTEGER NOT NULL,
  compute_time_unix_ns     INTEGER NOT NULL,
  state_blob               BLOB    NOT NULL
);
)sql";

// Version 2: alerts carry the unit of value/threshold; time-ordered alert queries across all
// spacecraft get an index; diagnosis results are stored.
constexpr absl::string_view kSchemaV2 = R"sql(
ALTER TABLE alerts ADD COLUMN unit TEXT NOT NULL DEFAULT '';
CREATE INDEX alerts_by_time ON alerts (measurement_time_unix_ns, spacecraft_id, sequence);

CREATE TABLE diagnoses (
  id                   INTEGER PRIMARY KEY,
  spacecraft_id        TEXT    NOT NULL,
  from_time_unix_ns    INTEGER NOT NULL,
  to_time_unix_ns      INTEGER NOT NULL,
  compute_time_unix_ns INTEGER NOT NULL,
  verdict              TEXT    NOT NULL,
  report_json          TEXT    NOT NULL
);
CREATE INDEX diagnoses_by_spacecraft ON diagnoses (spacecraft_id, id);
)sql";

// Version 3: a frame is identified by (spacecraft, station, sequence); existing frames belong to
// the station "default"; the measurement time is unique per spacecraft and orders the frames
// for the filter. service_state holds the service's own small facts (the storage probe).
constexpr absl::string_view kSchemaV3 = R"sql(
CREATE TABLE telemetry_frames_v3 (
  spacecraft_id            TEXT    NOT NULL,
  station_id               TEXT    NOT NULL,
  sequence                 INTEGER NOT NULL,
  measurement_time_unix_ns INTEGER NOT NULL,
  payload                  BLOB    NOT NULL,
  PRIMARY KEY (spacecraft_id, station_id, sequence)
);
INSERT INTO telemetry_frames_v3
  SELECT spacecraft_id, 'default', sequence, measurement_time_unix_ns, payload
  FROM telemetry_frames;
DROP TABLE telemetry_frames;
ALTER TABLE telemetry_frames_v3 RENAME TO telemetry_frames;
CREATE UNIQUE INDEX telemetry_frames_by_time
  ON telemetry_frames (spacecraft_id, measurement_time_unix_ns);

CREATE TABLE service_state (
  key   TEXT PRIMARY KEY,
  value ANY
);
)sql";

// Version 4: alerts carry the measurement time at which the service cleared them (NULL while
// not cleared, and for alerts cleared before this version).
constexpr absl::string_view kSchemaV4 = R"sql(
ALTER TABLE alerts ADD COLUMN cleared_time_unix_ns INTEGER;
)sql";

// Version 5: diagnoses carry the number of frames diagnosed. Diagnoses stored before get the
// count of the archived frames in their span [from, to] (the first and last frame diagnosed): a
// diagnosis read every archived frame of its span, and no frame can be archived later inside a
// span (a frame's time must be after the spacecraft's last archived one).
constexpr absl::string_view kSchemaV5 = R"sql(
ALTER TABLE diagnoses ADD COLUMN frames INTEGER NOT NULL DEFAULT 0;
UPDATE diagnoses SET frames = (
  SELECT COUNT(*) FROM telemetry_frames AS t
  WHERE t.spacecraft_id = diagnoses.spacecraft_id
    AND t.measurement_time_unix_ns BETWEEN diagnoses.from_time_unix_ns
                                       AND diagnoses.to_time_unix_ns);
)sql";

// Version 6: the reorder window. A row superseded by a re-run over a late frame keeps its values
// and gets the wall-clock time of the re-run (kept for audit, never deleted); late frames wait in
// late_frames until a re-run applies them (written in the transaction that archives them, so a
// restart still re-runs); window_checkpoints holds the session checkpoints re-runs start from.
constexpr absl::string_view kSchemaV6 = R"sql(
ALTER TABLE coefficients ADD COLUMN revised_time_unix_ns INTEGER;
ALTER TABLE alerts ADD COLUMN revised_time_unix_ns INTEGER;
CREATE TABLE late_frames (
  spacecraft_id            TEXT    NOT NULL,
  measurement_time_unix_ns INTEGER NOT NULL,
  PRIMARY KEY (spacecraft_id, measurement_time_unix_ns)
) WITHOUT ROWID;
CREATE TABLE window_checkpoints (
  spacecraft_id            TEXT    NOT NULL,
  applied_time_unix_ns     INTEGER NOT NULL,
  compute_time_unix_ns     INTEGER NOT NULL,
  state_blob               BLOB    NOT NULL,
  PRIMARY KEY (spacecraft_id, applied_time_unix_ns)
);
)sql";

// Version 7: the per-step estimate archive (storage/estimate_store.h). One row per measurement
// step, keyed by spacecraft and measurement time (a re-applied step replaces its row; the table
// is clustered on the key, so a time range of one spacecraft is one contiguous read). Attitude
// q_in_b scalar first [1] and its 1-sigma about the body axes [arcsec], NULL when the output is
// not valid; the star-tracker innovations of each gyro by gyro id (two components and their
// 1-sigma [arcsec], NULL when none were formed for it) with the session's gyro order in
// innovation_gyro_order ("1,2,3"; NULL when none were formed).
constexpr absl::string_view kSchemaV7 = R"sql(
CREATE TABLE estimates (
  spacecraft_id                  TEXT    NOT NULL,
  measurement_time_unix_ns       INTEGER NOT NULL,
  compute_time_unix_ns           INTEGER NOT NULL,
  state                          TEXT    NOT NULL,
  attitude_valid                 INTEGER NOT NULL,
  q0                             REAL,
  q1                             REAL,
  q2                             REAL,
  q3                             REAL,
  sigma_x_arcsec                 REAL,
  sigma_y_arcsec                 REAL,
  sigma_z_arcsec                 REAL,
  output_reference_gyro_id       INTEGER,
  output_second_gyro_id          INTEGER,
  attitude_invalid_reason        TEXT    NOT NULL,
  star_tracker_used              INTEGER NOT NULL,
  star_tracker_test_ratio        REAL,
  last_star_tracker_time_unix_ns INTEGER,
  innovation_gyro_order          TEXT,
  innovation_g1_1_arcsec         REAL,
  innovation_g1_2_arcsec         REAL,
  innovation_sigma_g1_1_arcsec   REAL,
  innovation_sigma_g1_2_arcsec   REAL,
  innovation_g2_1_arcsec         REAL,
  innovation_g2_2_arcsec         REAL,
  innovation_sigma_g2_1_arcsec   REAL,
  innovation_sigma_g2_2_arcsec   REAL,
  innovation_g3_1_arcsec         REAL,
  innovation_g3_2_arcsec         REAL,
  innovation_sigma_g3_1_arcsec   REAL,
  innovation_sigma_g3_2_arcsec   REAL,
  innovation_g4_1_arcsec         REAL,
  innovation_g4_2_arcsec         REAL,
  innovation_sigma_g4_1_arcsec   REAL,
  innovation_sigma_g4_2_arcsec   REAL,
  PRIMARY KEY (spacecraft_id, measurement_time_unix_ns)
) WITHOUT ROWID;
)sql";

// Version 8: the basis terms of each coefficient estimate (storage/basis_terms_column.h), a JSON
// array; NULL for a gyro without basis terms and for the rows stored before.
constexpr absl::string_view kSchemaV8 = kCoefficientBasisTermsColumn;

// Version 9: the attitude error estimate of each step (estimate_store.h): the correction the
// star-tracker update applied to the attitude about the body axes x, y, z and its 1-sigma
// [arcsec]; NULL at a step without a star-tracker update and for the rows stored before.
constexpr absl::string_view kSchemaV9 = R"sql(
ALTER TABLE estimates ADD COLUMN attitude_error_x_arcsec REAL;
ALTER TABLE estimates ADD COLUMN attitude_error_y_arcsec REAL;
ALTER TABLE estimates ADD COLUMN attitude_error_z_arcsec REAL;
ALTER TABLE estimates ADD COLUMN attitude_error_sigma_x_arcsec REAL;
ALTER TABLE estimates ADD COLUMN attitude_error_sigma_y_arcsec REAL;
ALTER TABLE estimates ADD COLUMN attitude_error_sigma_z_arcsec REAL;
)sql";

// The value columns of coefficients in versions 1-9, in layout order (frozen: version 10 moves
// them to coefficient_values under these names); each has its sigma column
// "<name>_sigma_<unit>" (k0_deg_h: k0_sigma_deg_h).
constexpr absl::string_view kVersion9ValueColumns[][2] = {
    {"k0", "deg_h"},     {"c1x", "deg_h"},  {"c1y", "deg_h"},  {"c1z", "deg_h"},
    {"c2x", "deg_h"},    {"c2y", "deg_h"},  {"c2z", "deg_h"},  {"mu12", "deg_h"},
    {"mu23", "deg_h"},   {"mu31", "deg_h"}, {"nu23", "deg_h"}, {"nu31", "deg_h"},
    {"nu12", "deg_h"},   {"misalignment_x", "arcsec"},        {"misalignment_y", "arcsec"},
    {"misalignment_z", "arcsec"}};
// Frozen schema history, end.

// Version 10, SQLite: the table rebuilt without the value columns (the order of the remaining
// columns is PostgreSQL's after its DROP COLUMNs, so both engines agree).
constexpr absl::string_view kSqliteCoefficientsV10 = R"sql(
CREATE TABLE coefficients_v10 (
  id                       INTEGER PRIMARY KEY,
  spacecraft_id            TEXT    NOT NULL,
  gyro_id                  INTEGER NOT NULL CHECK (gyro_id >= 1),
  measurement_time_unix_ns INTEGER NOT NULL,
  compute_time_unix_ns     INTEGER NOT NULL,
  model_name               TEXT    NOT NULL,
  revised_time_unix_ns     INTEGER,
  basis_terms_json         TEXT
);
INSERT INTO coefficients_v10
  SELECT id, spacecraft_id, gyro_id, measurement_time_unix_ns, compute_time_unix_ns, model_name,
         revised_time_unix_ns, basis_terms_json
  FROM coefficients;
DROP TABLE coefficients;
ALTER TABLE coefficients_v10 RENAME TO coefficients;
CREATE INDEX coefficients_by_time
  ON coefficients (spacecraft_id, measurement_time_unix_ns, gyro_id);
)sql";

}  // namespace

std::string KeyedCoefficientValuesMigration(Dialect dialect) {
  const bool sqlite = dialect == Dialect::kSqlite;
  std::string sql = absl::StrCat(
      "CREATE TABLE coefficient_values (\n"
      "  coefficient_id ", sqlite ? "INTEGER" : "BIGINT", " NOT NULL,\n"
      "  term_key       TEXT NOT NULL,\n"
      "  value          ", sqlite ? "REAL" : "DOUBLE PRECISION", ",\n"
      "  sigma          ", sqlite ? "REAL" : "DOUBLE PRECISION", ",\n"
      "  PRIMARY KEY (coefficient_id, term_key)\n)", sqlite ? " WITHOUT ROWID" : "", ";\n");
  std::string drops;
  for (const auto& [name, unit] : kVersion9ValueColumns) {
    const std::string value = absl::StrCat(name, "_", unit);
    const std::string sigma = absl::StrCat(name, "_sigma_", unit);
    absl::StrAppend(&sql, "INSERT INTO coefficient_values SELECT id, '", value, "', ", value, ", ",
                    sigma, " FROM coefficients;\n");
    absl::StrAppend(&drops, drops.empty() ? "ALTER TABLE coefficients " : ",\n  ",
                    "DROP COLUMN ", value, ", DROP COLUMN ", sigma);
  }
  if (sqlite) {
    absl::StrAppend(&sql, kSqliteCoefficientsV10);
  } else {
    absl::StrAppend(&sql, drops, ";\n");
  }
  return sql;
}

std::string ReadmissionsMigration(Dialect dialect) {
  const char* integer = dialect == Dialect::kSqlite ? "INTEGER" : "BIGINT";
  return absl::StrCat(
      "ALTER TABLE diagnoses ADD COLUMN config_version ", integer, ";\n"
      "ALTER TABLE diagnoses ADD COLUMN model_name TEXT;\n"
      "CREATE TABLE gyro_readmissions (\n"
      "  spacecraft_id        TEXT NOT NULL,\n"
      "  after_time_unix_ns   ", integer, " NOT NULL,\n"
      "  gyro_id              ", integer, " NOT NULL CHECK (gyro_id >= 1),\n"
      "  compute_time_unix_ns ", integer, " NOT NULL,\n"
      "  operator_name        TEXT NOT NULL,\n"
      "  PRIMARY KEY (spacecraft_id, after_time_unix_ns, gyro_id)\n"
      ");\n");
}

std::string DiagnosisOriginMigration(Dialect dialect) {
  const char* integer = dialect == Dialect::kSqlite ? "INTEGER" : "BIGINT";
  return absl::StrCat(
      "ALTER TABLE diagnoses ADD COLUMN requested_by TEXT NOT NULL DEFAULT '';\n"
      "ALTER TABLE diagnoses ADD COLUMN answers_alert ", integer, " NOT NULL DEFAULT 0;\n");
}

std::string AutoDiagnosisCancelsMigration(Dialect dialect) {
  const char* integer = dialect == Dialect::kSqlite ? "INTEGER" : "BIGINT";
  return absl::StrCat(
      "CREATE TABLE auto_diagnosis_cancels (\n"
      "  spacecraft_id       TEXT NOT NULL,\n"
      "  config_version      ", integer, " NOT NULL CHECK (config_version >= 1),\n"
      "  answers_alert       ", integer, " NOT NULL,\n"
      "  cancel_time_unix_ns ", integer, " NOT NULL,\n"
      "  PRIMARY KEY (spacecraft_id, config_version)\n"
      ");\n");
}

std::string OrbitsMigration(Dialect dialect) {
  const char* integer = dialect == Dialect::kSqlite ? "INTEGER" : "BIGINT";
  const char* id = dialect == Dialect::kSqlite
                       ? "INTEGER PRIMARY KEY"
                       : "BIGINT GENERATED BY DEFAULT AS IDENTITY PRIMARY KEY";
  return absl::StrCat(
      "CREATE TABLE orbits (\n"
      "  id                   ", id, ",\n"
      "  spacecraft_id        TEXT NOT NULL,\n"
      "  from_time_unix_ns    ", integer, " NOT NULL,\n"
      "  to_time_unix_ns      ", integer, " NOT NULL,\n"
      "  upload_time_unix_ns  ", integer, " NOT NULL,\n"
      "  states               ", integer, " NOT NULL,\n"
      "  uploaded_by          TEXT NOT NULL DEFAULT '',\n"
      "  oem_text             TEXT NOT NULL\n"
      ");\n"
      "CREATE INDEX orbits_by_spacecraft ON orbits (spacecraft_id, to_time_unix_ns);\n");
}

namespace {

// Version 10: coefficient values keyed by term (KeyedCoefficientValuesMigration).
const std::string& SchemaV10() {
  static const std::string* const sql =
      new std::string(KeyedCoefficientValuesMigration(Dialect::kSqlite));
  return *sql;
}

// Migration n takes the schema from version n to n + 1.
absl::string_view Migration(int n) {
  static constexpr absl::string_view kFrozen[] = {kSchemaV1, kSchemaV2, kSchemaV3,
                                                  kSchemaV4, kSchemaV5, kSchemaV6,
                                                  kSchemaV7, kSchemaV8, kSchemaV9};
  static const std::string* const v11 = new std::string(ReadmissionsMigration(Dialect::kSqlite));
  static const std::string* const v12 =
      new std::string(DiagnosisOriginMigration(Dialect::kSqlite));
  static const std::string* const v13 =
      new std::string(AutoDiagnosisCancelsMigration(Dialect::kSqlite));
  static const std::string* const v14 = new std::string(OrbitsMigration(Dialect::kSqlite));
  static_assert(std::size(kFrozen) + 5 == kCurrentSchemaVersion);
  const int built = n - static_cast<int>(std::size(kFrozen));
  if (built < 0) return kFrozen[n];
  if (built == 0) return SchemaV10();
  if (built == 1) return *v11;
  if (built == 2) return *v12;
  return built == 3 ? absl::string_view(*v13) : absl::string_view(*v14);
}

absl::StatusOr<int> ReadUserVersion(Transaction& txn) {
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare("PRAGMA user_version"));
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return absl::InternalError("PRAGMA user_version returned no row");
  const int64_t version = st->ColumnInt64(0);
  st->Reset();
  return static_cast<int>(version);
}

absl::Status CheckKnownVersion(int version, const Database& db) {
  if (version > kCurrentSchemaVersion) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "database %s has schema version %d, newer than this program's %d: upgrade the program",
        db.path(), version, kCurrentSchemaVersion));
  }
  if (version < 0) {
    return absl::FailedPreconditionError(
        absl::StrFormat("database %s has invalid schema version %d", db.path(), version));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<int> SchemaVersion(Database& db) {
  if (db.dialect() == Dialect::kPostgres) return PostgresSchemaVersion(db);
  ASSIGN_OR_RETURN(Transaction txn, db.Begin(TransactionMode::kDeferred));
  return ReadUserVersion(txn);
}

absl::Status MigrateTo(Database& db, int target_version) {
  if (target_version < 0 || target_version > kCurrentSchemaVersion) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "target schema version = %d: must be in [0, %d]", target_version, kCurrentSchemaVersion));
  }
  if (db.dialect() == Dialect::kPostgres) return MigratePostgresTo(db, target_version);
  // Cheap check first so that an up-to-date database needs no write lock.
  ASSIGN_OR_RETURN(int version, SchemaVersion(db));
  RETURN_IF_ERROR(CheckKnownVersion(version, db));
  while (version < target_version) {
    ASSIGN_OR_RETURN(Transaction txn, db.Begin(TransactionMode::kImmediate));
    // Another connection may have migrated meanwhile; trust only what the write lock sees.
    ASSIGN_OR_RETURN(version, ReadUserVersion(txn));
    RETURN_IF_ERROR(CheckKnownVersion(version, db));
    if (version >= target_version) break;
    RETURN_IF_ERROR(txn.Execute(Migration(version)));
    RETURN_IF_ERROR(txn.Execute(absl::StrCat("PRAGMA user_version = ", version + 1)));
    RETURN_IF_ERROR(txn.Commit());
    ++version;
  }
  if (version > target_version) {
    return absl::FailedPreconditionError(
        absl::StrFormat("database %s has schema version %d, newer than the requested %d", db.path(),
                        version, target_version));
  }
  return absl::OkStatus();
}

absl::Status MigrateToCurrent(Database& db) { return MigrateTo(db, kCurrentSchemaVersion); }

int64_t TimeToUnixNanos(absl::Time t) {
  if (t == absl::InfinitePast()) return std::numeric_limits<int64_t>::min();
  if (t == absl::InfiniteFuture()) return std::numeric_limits<int64_t>::max();
  // absl::ToUnixNanos floors, and saturates outside the int64 range.
  return absl::ToUnixNanos(t);
}

absl::Time UnixNanosToTime(int64_t unix_ns) {
  if (unix_ns == std::numeric_limits<int64_t>::min()) return absl::InfinitePast();
  if (unix_ns == std::numeric_limits<int64_t>::max()) return absl::InfiniteFuture();
  return absl::FromUnixNanos(unix_ns);
}

absl::Status ValidateSpacecraftId(absl::string_view id, absl::string_view field) {
  if (id.empty()) return absl::InvalidArgumentError(absl::StrCat(field, ": empty"));
  return absl::OkStatus();
}

absl::Status ValidateStorableTime(absl::Time t, absl::string_view field) {
  static const absl::Time kEarliest = absl::FromUnixNanos(std::numeric_limits<int64_t>::min() + 1);
  static const absl::Time kLatest = absl::FromUnixNanos(std::numeric_limits<int64_t>::max() - 1);
  if (t < kEarliest || t > kLatest) {
    return absl::InvalidArgumentError(
        absl::StrCat(field, " = ", estimator::FormatUtc(t),
                     ": must be a finite instant between years 1678 and 2262"));
  }
  return absl::OkStatus();
}

}  // namespace esg::storage
