// Tests of storage/schema.h: fresh schema, migration of a hand-made version-1 file with data,
// refusal of newer files, column naming, and the instant encoding.
#include "storage/schema.h"

#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/records.h"
#include "storage/sqlite_db.h"
#include "storage/storage.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::Alert;
using ::esg::storage::testing::IsOkAndHolds;
using ::esg::storage::testing::QueryInt;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::esg::testing::TempDir;
using ::testing::ElementsAre;
using ::testing::ElementsAreArray;
using ::testing::HasSubstr;
using ::testing::IsEmpty;
using ::testing::IsSupersetOf;

std::vector<std::string> Columns(Database& db, const std::string& table) {
  std::vector<std::string> names;
  absl::StatusOr<Transaction> txn = db.Begin(TransactionMode::kDeferred);
  EXPECT_THAT(txn, IsOk());
  if (!txn.ok()) return names;
  absl::StatusOr<Statement*> st = txn->Prepare("SELECT name FROM pragma_table_info(?1)");
  EXPECT_THAT(st, IsOk());
  if (!st.ok()) return names;
  (*st)->BindText(1, table);
  while (true) {
    absl::StatusOr<bool> row = (*st)->Step();
    EXPECT_THAT(row, IsOk());
    if (!row.ok() || !*row) break;
    names.push_back((*st)->ColumnText(0));
  }
  return names;
}

std::vector<std::string> Tables(Database& db) {
  std::vector<std::string> names;
  absl::StatusOr<Transaction> txn = db.Begin(TransactionMode::kDeferred);
  EXPECT_THAT(txn, IsOk());
  if (!txn.ok()) return names;
  absl::StatusOr<Statement*> st =
      txn->Prepare("SELECT name FROM sqlite_schema WHERE type = 'table' ORDER BY name");
  EXPECT_THAT(st, IsOk());
  if (!st.ok()) return names;
  while (true) {
    absl::StatusOr<bool> row = (*st)->Step();
    EXPECT_THAT(row, IsOk());
    if (!row.ok() || !*row) break;
    names.push_back((*st)->ColumnText(0));
  }
  return names;
}

// The version-1 layout written out independently of schema.cc, as an old program left it.
std::string HandMadeV1Sql() {
  // Version 1's coefficient columns, frozen as an old program wrote them: not the current terms
  // (estimator/model_terms.h), so a new term does not change what a version-1 database is.
  static constexpr const char* kStems[][2] = {
      {"k0", "deg_h"},   {"c1x", "deg_h"},  {"c1y", "deg_h"},  {"c1z", "deg_h"},
      {"c2x", "deg_h"},  {"c2y", "deg_h"},  {"c2z", "deg_h"},  {"mu12", "deg_h"},
      {"mu23", "deg_h"}, {"mu31", "deg_h"}, {"nu23", "deg_h"}, {"nu31", "deg_h"},
      {"nu12", "deg_h"}, {"misalignment_x", "arcsec"}, {"misalignment_y", "arcsec"},
      {"misalignment_z", "arcsec"}};
  std::vector<std::string> coefficient_columns;
  for (const auto& [stem, unit] : kStems) {
    coefficient_columns.push_back(absl::StrCat(stem, "_", unit, " REAL"));
  }
  for (const auto& [stem, unit] : kStems) {
    coefficient_columns.push_back(absl::StrCat(stem, "_sigma_", unit, " REAL"));
  }
  return absl::StrCat(
      "CREATE TABLE spacecraft_configs (spacecraft_id TEXT NOT NULL, version INTEGER NOT NULL, "
      "updated_time_unix_ns INTEGER NOT NULL, config_json TEXT NOT NULL, "
      "PRIMARY KEY (spacecraft_id, version));"
      "CREATE TABLE telemetry_frames (spacecraft_id TEXT NOT NULL, sequence INTEGER NOT NULL, "
      "measurement_time_unix_ns INTEGER NOT NULL, payload BLOB NOT NULL, "
      "PRIMARY KEY (spacecraft_id, sequence));"
      "CREATE TABLE coefficients (id INTEGER PRIMARY KEY, spacecraft_id TEXT NOT NULL, "
      "gyro_id INTEGER NOT NULL, measurement_time_unix_ns INTEGER NOT NULL, "
      "compute_time_unix_ns INTEGER NOT NULL, model_name TEXT NOT NULL, ",
      absl::StrJoin(coefficient_columns, ", "),
      ");"
      "CREATE TABLE alerts (spacecraft_id TEXT NOT NULL, sequence INTEGER NOT NULL, "
      "severity TEXT NOT NULL, reason TEXT NOT NULL, subsystem TEXT NOT NULL, value REAL, "
      "threshold REAL, repeat_count INTEGER NOT NULL, first_time_unix_ns INTEGER NOT NULL, "
      "measurement_time_unix_ns INTEGER NOT NULL, compute_time_unix_ns INTEGER NOT NULL, "
      "message TEXT NOT NULL, acknowledged INTEGER NOT NULL DEFAULT 0, acknowledged_by TEXT, "
      "acknowledged_time_unix_ns INTEGER, cleared INTEGER NOT NULL DEFAULT 0, "
      "PRIMARY KEY (spacecraft_id, sequence));"
      "CREATE TABLE checkpoints (spacecraft_id TEXT NOT NULL PRIMARY KEY, "
      "last_sequence INTEGER NOT NULL, measurement_time_unix_ns INTEGER NOT NULL, "
      "compute_time_unix_ns INTEGER NOT NULL, state_blob BLOB NOT NULL);"
      // Data an old program wrote: one frame, one alert (no unit yet), one checkpoint.
      "INSERT INTO telemetry_frames VALUES ('SC-OLD', 7, ",
      TimeToUnixNanos(T(420)),
      ", x'00ff');"
      "INSERT INTO alerts (spacecraft_id, sequence, severity, reason, subsystem, value, "
      "threshold, repeat_count, first_time_unix_ns, measurement_time_unix_ns, "
      "compute_time_unix_ns, message) VALUES ('SC-OLD', 1, 'WARNING', 'PAIR_MISMATCH', 'gyro2', "
      "12.0, 10.0, 3, ",
      TimeToUnixNanos(T(60)), ", ", TimeToUnixNanos(T(180)), ", ", TimeToUnixNanos(T(181)),
      ", 'old alert');"
      "INSERT INTO checkpoints VALUES ('SC-OLD', 7, ",
      TimeToUnixNanos(T(420)), ", ", TimeToUnixNanos(T(421)),
      ", x'0102');"
      "PRAGMA user_version = 1;");
}

TEST(Schema, FreshDatabaseIsMigratedToTheCurrentVersion) {
  TempDir dir;
  absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(dir.File("a.db"));
  ASSERT_THAT(db, IsOk());
  EXPECT_THAT(SchemaVersion(**db), IsOkAndHolds(0));
  ASSERT_THAT(MigrateToCurrent(**db), IsOk());
  EXPECT_THAT(SchemaVersion(**db), IsOkAndHolds(kCurrentSchemaVersion));
  EXPECT_THAT(Tables(**db), IsSupersetOf({"alerts", "checkpoints", "coefficients", "diagnoses",
                                          "estimates", "spacecraft_configs",
                                          "telemetry_frames"}));
  // Idempotent.
  EXPECT_THAT(MigrateToCurrent(**db), IsOk());
  EXPECT_THAT(SchemaVersion(**db), IsOkAndHolds(kCurrentSchemaVersion));
}

// Version 10: the coefficient rows keep their identity, times, model, revision and basis terms;
// each value is a row of coefficient_values keyed by its name with its unit (records.h), the
// names of the value columns of versions 1-9.
TEST(Schema, CoefficientValuesAreKeyedByTermNamedWithTheirUnitsInLayoutOrder) {
  TempDir dir;
  absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(dir.File("a.db"));
  ASSERT_THAT(db, IsOk());
  ASSERT_THAT(MigrateToCurrent(**db), IsOk());
  EXPECT_THAT(Columns(**db, "coefficients"),
              ElementsAre("id", "spacecraft_id", "gyro_id", "measurement_time_unix_ns",
                          "compute_time_unix_ns", "model_name", "revised_time_unix_ns",
                          "basis_terms_json"));
  EXPECT_THAT(Columns(**db, "coefficient_values"),
              ElementsAre("coefficient_id", "term_key", "value", "sigma"));
  // Spot-check the documented names (records.h) so a reordering cannot pass silently.
  EXPECT_EQ(CoefficientColumns()[estimator::kThetaK0], "k0_deg_h");
  EXPECT_EQ(CoefficientColumns()[estimator::kThetaC1 + 2], "c1z_deg_h");
  EXPECT_EQ(CoefficientColumns()[estimator::kThetaC2], "c2x_deg_h");
  EXPECT_EQ(CoefficientColumns()[estimator::kThetaMu], "mu12_deg_h");
  EXPECT_EQ(CoefficientColumns()[estimator::kThetaNu], "nu23_deg_h");
  EXPECT_EQ(CoefficientColumns()[kCoefficientMisalignment + 1], "misalignment_y_arcsec");
  EXPECT_EQ(CoefficientSigmaColumns()[estimator::kThetaNu + 2], "nu12_sigma_deg_h");
}

TEST(Schema, HandMadeVersion1FileIsMigratedWithItsData) {
  TempDir dir;
  const std::string path = dir.File("v1.db");
  {
    absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(path);
    ASSERT_THAT(db, IsOk());
    ASSERT_THAT((*db)->Execute(HandMadeV1Sql()), IsOk());
    EXPECT_THAT(SchemaVersion(**db), IsOkAndHolds(1));
  }
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(SchemaVersion((*storage)->database()), IsOkAndHolds(kCurrentSchemaVersion));

  // Old data is intact; the new alert column has its default.
  absl::StatusOr<AlertRecord> old_alert = (*storage)->alerts().Get("SC-OLD", 1);
  ASSERT_THAT(old_alert, IsOk());
  EXPECT_EQ(old_alert->reason, "PAIR_MISMATCH");
  EXPECT_EQ(old_alert->repeat_count, 3);
  EXPECT_EQ(old_alert->first_time, T(60));
  EXPECT_EQ(old_alert->measurement_time, T(180));
  EXPECT_EQ(old_alert->unit, "");
  EXPECT_FALSE(old_alert->acknowledged);
  EXPECT_THAT((*storage)->archive().HighestSequence("SC-OLD"),
              IsOkAndHolds(std::optional<int64_t>(7)));
  absl::StatusOr<CheckpointRecord> checkpoint = (*storage)->sessions().GetCheckpoint("SC-OLD");
  ASSERT_THAT(checkpoint, IsOk());
  EXPECT_EQ(checkpoint->state_blob, std::string("\x01\x02", 2));

  // New features work on the migrated file: units on alerts, numbering continues, diagnoses.
  absl::StatusOr<int64_t> next = (*storage)->alerts().Append(Alert("SC-OLD", 600));
  EXPECT_THAT(next, IsOkAndHolds(2));
  absl::StatusOr<AlertRecord> new_alert = (*storage)->alerts().Get("SC-OLD", 2);
  ASSERT_THAT(new_alert, IsOk());
  EXPECT_EQ(new_alert->unit, "arcsec");
  DiagnosisRecord diagnosis;
  diagnosis.spacecraft_id = "SC-OLD";
  diagnosis.from_time = T(0);
  diagnosis.to_time = T(3600);
  diagnosis.compute_time = T(4000);
  diagnosis.verdict = "unexplained";
  diagnosis.report_json = "{}";
  EXPECT_THAT((*storage)->diagnoses().Put(diagnosis), IsOk());
}

// A version-4 file, as the program before version 5 left it: diagnoses without a frame count.
// Migrated, each diagnosis gets the number of archived frames of its spacecraft in its span
// (first..last frame diagnosed, inclusive); new diagnoses store the count they are given.
TEST(Schema, Version4DiagnosesGetTheFrameCountOfTheirSpanWhenMigrated) {
  TempDir dir;
  const std::string path = dir.File("v4.db");
  {
    absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(path);
    ASSERT_THAT(db, IsOk());
    ASSERT_THAT(MigrateTo(**db, 4), IsOk());
    EXPECT_THAT(Columns(**db, "diagnoses"), ::testing::Not(::testing::Contains("frames")));
    // SC-A: frames every 60 s at 60..6000 s (100 frames); SC-B: 10 frames over the same times.
    std::string sql;
    for (int k = 1; k <= 100; ++k) {
      absl::StrAppend(&sql, "INSERT INTO telemetry_frames VALUES ('SC-A', 'default', ", k, ", ",
                      TimeToUnixNanos(T(60.0 * k)), ", x'00');");
    }
    for (int k = 1; k <= 10; ++k) {
      absl::StrAppend(&sql, "INSERT INTO telemetry_frames VALUES ('SC-B', 'gs-1', ", k, ", ",
                      TimeToUnixNanos(T(60.0 * k)), ", x'00');");
    }
    // Diagnoses over SC-A's 60..6000 s (100 frames), 600..1200 s (11 frames) and SC-B's whole
    // archive (10 frames).
    auto diagnosis = [](const char* id, double from_s, double to_s) {
      return absl::StrCat(
          "INSERT INTO diagnoses (spacecraft_id, from_time_unix_ns, to_time_unix_ns, "
          "compute_time_unix_ns, verdict, report_json) VALUES ('",
          id, "', ", TimeToUnixNanos(T(from_s)), ", ", TimeToUnixNanos(T(to_s)), ", ",
          TimeToUnixNanos(T(9000)), ", 'none', '{}');");
    };
    absl::StrAppend(&sql, diagnosis("SC-A", 60, 6000), diagnosis("SC-A", 600, 1200),
                    diagnosis("SC-B", 60, 600));
    ASSERT_THAT((*db)->Execute(sql), IsOk());
    EXPECT_THAT(SchemaVersion(**db), IsOkAndHolds(4));
  }
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(SchemaVersion((*storage)->database()), IsOkAndHolds(kCurrentSchemaVersion));
  absl::StatusOr<std::vector<DiagnosisRecord>> a = (*storage)->diagnoses().List("SC-A");
  ASSERT_THAT(a, IsOk());
  ASSERT_EQ(a->size(), 2u);
  EXPECT_EQ((*a)[0].frames, 100);
  EXPECT_EQ((*a)[1].frames, 11);
  EXPECT_EQ((*a)[1].from_time, T(600));
  absl::StatusOr<std::vector<DiagnosisRecord>> b =
      (*storage)->diagnoses().ListSummaries("SC-B", 0, 10);
  ASSERT_THAT(b, IsOk());
  ASSERT_EQ(b->size(), 1u);
  EXPECT_EQ((*b)[0].frames, 10);
  // A new diagnosis on the migrated file keeps the count it is given.
  DiagnosisRecord fresh;
  fresh.spacecraft_id = "SC-A";
  fresh.from_time = T(60);
  fresh.to_time = T(120);
  fresh.compute_time = T(9100);
  fresh.verdict = "none";
  fresh.report_json = "{}";
  fresh.frames = 2;
  absl::StatusOr<int64_t> id = (*storage)->diagnoses().Put(fresh);
  ASSERT_THAT(id, IsOk());
  absl::StatusOr<DiagnosisRecord> got = (*storage)->diagnoses().Get(*id);
  ASSERT_THAT(got, IsOk());
  EXPECT_EQ(got->frames, 2);
}

// A version-6 file, as the program before the per-step estimate archive left it (frames,
// coefficients with a revised row, an alert, a checkpoint, a late frame and a window
// checkpoint): Storage::Open migrates it to the current version, keeps every row, and the new
// estimates table is empty and takes records.
TEST(Schema, Version6FileOpensMigratedWithItsDataAndAnEmptyEstimateArchive) {
  TempDir dir;
  const std::string path = dir.File("v6.db");
  {
    absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(path);
    ASSERT_THAT(db, IsOk());
    ASSERT_THAT(MigrateTo(**db, 6), IsOk());
    EXPECT_THAT(Tables(**db), ::testing::Not(::testing::Contains("estimates")));
    std::string sql;
    for (int k = 1; k <= 5; ++k) {
      absl::StrAppend(&sql, "INSERT INTO telemetry_frames VALUES ('SC-6', 'default', ", k, ", ",
                      TimeToUnixNanos(T(60.0 * k)), ", x'00');");
      absl::StrAppend(&sql,
                      "INSERT INTO coefficients (spacecraft_id, gyro_id, "
                      "measurement_time_unix_ns, compute_time_unix_ns, model_name, k0_deg_h, "
                      "revised_time_unix_ns) VALUES ('SC-6', 1, ",
                      TimeToUnixNanos(T(60.0 * k)), ", ", TimeToUnixNanos(T(9000)),
                      ", 'model10', 0.25, ", k == 5 ? "1" : "NULL", ");");
    }
    absl::StrAppend(&sql, "INSERT INTO checkpoints VALUES ('SC-6', 5, ",
                    TimeToUnixNanos(T(300)), ", ", TimeToUnixNanos(T(9000)), ", x'0102');",
                    "INSERT INTO late_frames VALUES ('SC-6', ", TimeToUnixNanos(T(90)), ");",
                    "INSERT INTO window_checkpoints VALUES ('SC-6', ", TimeToUnixNanos(T(60)),
                    ", ", TimeToUnixNanos(T(9000)), ", x'03');");
    ASSERT_THAT((*db)->Execute(sql), IsOk());
    ASSERT_THAT(SchemaVersion(**db), IsOkAndHolds(6));
  }
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  Database& db = (*storage)->database();
  EXPECT_THAT(SchemaVersion(db), IsOkAndHolds(kCurrentSchemaVersion));
  EXPECT_THAT(QueryInt(db, "SELECT COUNT(*) FROM telemetry_frames"), IsOkAndHolds(5));
  absl::StatusOr<std::vector<CoefficientRecord>> current = (*storage)->coefficients().History(
      "SC-6", 0, absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_THAT(current, IsOk());
  EXPECT_EQ(current->size(), 4u);
  EXPECT_THAT((*storage)->reorder().LateFrames("SC-6"),
              IsOkAndHolds(ElementsAreArray({T(90)})));
  EXPECT_THAT((*storage)->sessions().GetCheckpoint("SC-6"), IsOk());
  EXPECT_THAT((*storage)->estimates().Count("SC-6"), IsOkAndHolds(0));
  EstimateRecord r;
  r.spacecraft_id = "SC-6";
  r.measurement_time = T(360);
  r.compute_time = T(9001);
  r.state = "CALIBRATING";
  ASSERT_THAT((*storage)->estimates().Put(r), IsOk());
  EXPECT_THAT((*storage)->estimates().Count("SC-6"), IsOkAndHolds(1));
}

// Version 8 adds the basis terms of each coefficient estimate: rows stored before read back with
// none, and new rows carry theirs.
TEST(Schema, CoefficientsOfAVersion7FileReadBackWithoutBasisTermsAfterTheMigration) {
  TempDir dir;
  const std::string path = dir.File("v7.db");
  {
    absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(path);
    ASSERT_THAT(db, IsOk());
    ASSERT_THAT(MigrateTo(**db, 7), IsOk());
    ASSERT_THAT((*db)->Execute(absl::StrCat(
                    "INSERT INTO coefficients (spacecraft_id, gyro_id, measurement_time_unix_ns, "
                    "compute_time_unix_ns, model_name, k0_deg_h) VALUES ('SC-7', 2, ",
                    TimeToUnixNanos(T(60)), ", ", TimeToUnixNanos(T(61)), ", 'model10', 0.25)")),
                IsOk());
  }
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(SchemaVersion((*storage)->database()), IsOkAndHolds(kCurrentSchemaVersion));
  CoefficientRecord added;
  added.spacecraft_id = "SC-7";
  added.gyro_id = 2;
  added.measurement_time = T(120);
  added.compute_time = T(121);
  added.model_name = "model10";
  added.values.assign(kNumCoefficientValues, 0.0);
  estimator::BasisTerm term;  // a case-fixed drift along x, calibrated
  term.value = 1e-8;
  term.sigma = 1e-9;
  added.basis_terms = {term};
  ASSERT_THAT((*storage)->coefficients().Append(added), IsOk());
  absl::StatusOr<std::vector<CoefficientRecord>> read = (*storage)->coefficients().History(
      "SC-7", 2, absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_THAT(read, IsOk());
  ASSERT_EQ(read->size(), 2u);
  EXPECT_THAT((*read)[0].basis_terms, IsEmpty());
  ASSERT_EQ((*read)[1].basis_terms.size(), 1u);
  EXPECT_DOUBLE_EQ((*read)[1].basis_terms[0].value, 1e-8);
}

// Version 9 adds the attitude error estimate of each step: a row stored before reads back
// without one (its six columns NULL), and new rows carry theirs, in arcsec columns named with
// their axis.
TEST(Schema, EstimatesOfAVersion8FileReadBackWithoutAnAttitudeErrorAfterTheMigration) {
  TempDir dir;
  const std::string path = dir.File("v8.db");
  {
    absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(path);
    ASSERT_THAT(db, IsOk());
    ASSERT_THAT(MigrateTo(**db, 8), IsOk());
    EXPECT_THAT(Columns(**db, "estimates"),
                ::testing::Not(::testing::Contains("attitude_error_x_arcsec")));
    ASSERT_THAT((*db)->Execute(absl::StrCat(
                    "INSERT INTO estimates (spacecraft_id, measurement_time_unix_ns, "
                    "compute_time_unix_ns, state, attitude_valid, q0, q1, q2, q3, sigma_x_arcsec, "
                    "sigma_y_arcsec, sigma_z_arcsec, output_reference_gyro_id, "
                    "output_second_gyro_id, attitude_invalid_reason, star_tracker_used) "
                    "VALUES ('SC-8', ",
                    TimeToUnixNanos(T(60)), ", ", TimeToUnixNanos(T(61)),
                    ", 'CALIBRATING', 1, 1, 0, 0, 0, 4.5, 4.5, 20, 1, 2, '', 1)")),
                IsOk());
  }
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(SchemaVersion((*storage)->database()), IsOkAndHolds(kCurrentSchemaVersion));
  const std::vector<std::string> columns = Columns((*storage)->database(), "estimates");
  ASSERT_GE(columns.size(), 6u);
  EXPECT_THAT(std::vector<std::string>(columns.end() - 6, columns.end()),
              ElementsAreArray({"attitude_error_x_arcsec", "attitude_error_y_arcsec",
                                "attitude_error_z_arcsec", "attitude_error_sigma_x_arcsec",
                                "attitude_error_sigma_y_arcsec", "attitude_error_sigma_z_arcsec"}));
  EstimateRecord added;
  added.spacecraft_id = "SC-8";
  added.measurement_time = T(120);
  added.compute_time = T(121);
  added.state = "CALIBRATING";
  added.has_attitude_error = true;
  added.attitude_error_b = {estimator::ArcsecToRad(1.5), estimator::ArcsecToRad(-2.0),
                            estimator::ArcsecToRad(8.0)};
  added.attitude_error_sigma_b = {estimator::ArcsecToRad(2.0), estimator::ArcsecToRad(2.5),
                                  estimator::ArcsecToRad(12.0)};
  ASSERT_THAT((*storage)->estimates().Put(added), IsOk());
  absl::StatusOr<EstimatePage> page = (*storage)->estimates().Page(
      "SC-8", absl::InfinitePast(), absl::InfiniteFuture(), std::nullopt, 10);
  ASSERT_THAT(page, IsOk());
  ASSERT_EQ(page->records.size(), 2u);
  EXPECT_TRUE(page->records[0].attitude_valid);
  EXPECT_FALSE(page->records[0].has_attitude_error);
  ASSERT_TRUE(page->records[1].has_attitude_error);
  EXPECT_NEAR(estimator::RadToArcsec(page->records[1].attitude_error_b[2]), 8.0, 1e-12);
  EXPECT_NEAR(estimator::RadToArcsec(page->records[1].attitude_error_sigma_b[0]), 2.0, 1e-12);
}

// A version-11 file: its diagnoses read back as requested ones (requested_by empty, answering no
// alert) after the migration to version 12.
TEST(Schema, Version11DiagnosesReadBackAsRequestedOnes) {
  TempDir dir;
  const std::string path = dir.File("v11.db");
  {
    absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(path);
    ASSERT_THAT(db, IsOk());
    ASSERT_THAT(MigrateTo(**db, 11), IsOk());
    EXPECT_THAT(Columns(**db, "diagnoses"), ::testing::Not(::testing::Contains("requested_by")));
    ASSERT_THAT((*db)->Execute(absl::StrCat(
                    "INSERT INTO diagnoses (spacecraft_id, from_time_unix_ns, to_time_unix_ns, "
                    "compute_time_unix_ns, verdict, report_json, frames, config_version, "
                    "model_name) VALUES ('SC-A', ",
                    TimeToUnixNanos(T(60)), ", ", TimeToUnixNanos(T(600)), ", ",
                    TimeToUnixNanos(T(900)), ", 'rotor_displacement', '{}', 10, 1, '10+11');")),
                IsOk());
  }
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(SchemaVersion((*storage)->database()), IsOkAndHolds(kCurrentSchemaVersion));
  absl::StatusOr<std::vector<DiagnosisRecord>> old = (*storage)->diagnoses().List("SC-A");
  ASSERT_THAT(old, IsOk());
  ASSERT_EQ(old->size(), 1u);
  EXPECT_EQ((*old)[0].requested_by, "");
  EXPECT_EQ((*old)[0].answers_alert, 0);
  EXPECT_EQ((*old)[0].config_version, 1);
}

// A version-10 file: its diagnoses read back without the configuration they ran on (0 and empty:
// ApplyDiagnosis refuses them), new ones store it; readmissions of excluded gyros are stored and
// listed by time, the same gyro after the same time once.
TEST(Schema, Version10DiagnosesHaveNoConfigurationAndReadmissionsAreStoredAfterTheMigration) {
  TempDir dir;
  const std::string path = dir.File("v10.db");
  {
    absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(path);
    ASSERT_THAT(db, IsOk());
    ASSERT_THAT(MigrateTo(**db, 10), IsOk());
    EXPECT_THAT(Columns(**db, "diagnoses"), ::testing::Not(::testing::Contains("config_version")));
    ASSERT_THAT((*db)->Execute(absl::StrCat(
                    "INSERT INTO diagnoses (spacecraft_id, from_time_unix_ns, to_time_unix_ns, "
                    "compute_time_unix_ns, verdict, report_json, frames) VALUES ('SC-A', ",
                    TimeToUnixNanos(T(60)), ", ", TimeToUnixNanos(T(600)), ", ",
                    TimeToUnixNanos(T(900)), ", 'rotor_displacement', '{}', 10);")),
                IsOk());
  }
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(SchemaVersion((*storage)->database()), IsOkAndHolds(kCurrentSchemaVersion));
  absl::StatusOr<std::vector<DiagnosisRecord>> old = (*storage)->diagnoses().List("SC-A");
  ASSERT_THAT(old, IsOk());
  ASSERT_EQ(old->size(), 1u);
  EXPECT_EQ((*old)[0].config_version, 0);
  EXPECT_EQ((*old)[0].model_name, "");
  DiagnosisRecord fresh = (*old)[0];
  fresh.config_version = 3;
  fresh.model_name = "10+11";
  ASSERT_THAT((*storage)->diagnoses().Put(fresh), IsOk());
  absl::StatusOr<std::vector<DiagnosisRecord>> summaries =
      (*storage)->diagnoses().ListSummaries("SC-A", 0, 10);
  ASSERT_THAT(summaries, IsOk());
  ASSERT_EQ(summaries->size(), 2u);
  EXPECT_EQ((*summaries)[1].config_version, 3);
  EXPECT_EQ((*summaries)[1].model_name, "10+11");

  ReadmissionRecord later{"SC-A", 3, T(7200), T(9000), "alice"};
  ReadmissionRecord earlier{"SC-A", 2, T(3600), T(9100), "bob"};
  ASSERT_THAT((*storage)->sessions().PutReadmission(later), IsOk());
  ASSERT_THAT((*storage)->sessions().PutReadmission(earlier), IsOk());
  EXPECT_THAT((*storage)->sessions().PutReadmission(later),
              StatusIs(absl::StatusCode::kAlreadyExists, HasSubstr("gyro_id")));
  ReadmissionRecord bad = later;
  bad.gyro_id = 5;
  EXPECT_THAT((*storage)->sessions().PutReadmission(bad),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("readmission.gyro_id")));
  absl::StatusOr<std::vector<ReadmissionRecord>> listed =
      (*storage)->sessions().ListReadmissions("SC-A");
  ASSERT_THAT(listed, IsOk());
  ASSERT_EQ(listed->size(), 2u);
  EXPECT_EQ((*listed)[0].gyro_id, 2);
  EXPECT_EQ((*listed)[0].after_time, T(3600));
  EXPECT_EQ((*listed)[0].operator_name, "bob");
  EXPECT_EQ((*listed)[1].gyro_id, 3);
  EXPECT_EQ((*listed)[1].compute_time, T(9000));
  EXPECT_THAT((*storage)->sessions().ListReadmissions("SC-B"), IsOkAndHolds(IsEmpty()));
}

// A version-12 file gains auto_diagnosis_cancels at version 13: an operator's cancel of the
// automatic diagnosis is stored per spacecraft and configuration version, the first kept.
TEST(Schema, Version12FileGainsTheAutoDiagnosisCancels) {
  TempDir dir;
  const std::string path = dir.File("v12.db");
  {
    absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(path);
    ASSERT_THAT(db, IsOk());
    ASSERT_THAT(MigrateTo(**db, 12), IsOk());
    EXPECT_THAT(Columns(**db, "auto_diagnosis_cancels"), IsEmpty());
  }
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(SchemaVersion((*storage)->database()), IsOkAndHolds(kCurrentSchemaVersion));
  EXPECT_THAT(Columns((*storage)->database(), "auto_diagnosis_cancels"),
              ElementsAre("spacecraft_id", "config_version", "answers_alert",
                          "cancel_time_unix_ns"));
  DiagnosisStore& diagnoses = (*storage)->diagnoses();
  EXPECT_THAT(diagnoses.AutoCancelled("SC-A", 2), IsOkAndHolds(false));
  ASSERT_THAT(diagnoses.PutAutoCancel({"SC-A", 2, 7, T(100)}), IsOk());
  ASSERT_THAT(diagnoses.PutAutoCancel({"SC-A", 2, 9, T(200)}), IsOk());  // the first stays
  EXPECT_THAT(diagnoses.AutoCancelled("SC-A", 2), IsOkAndHolds(true));
  EXPECT_THAT(diagnoses.AutoCancelled("SC-A", 3), IsOkAndHolds(false));
  EXPECT_THAT(diagnoses.AutoCancelled("SC-B", 2), IsOkAndHolds(false));
}

TEST(Schema, StepwiseMigrationReachesTheSameLayoutAsAFreshOne) {
  TempDir dir;
  absl::StatusOr<std::unique_ptr<Database>> stepwise = SqliteDatabase::Open(dir.File("s.db"));
  absl::StatusOr<std::unique_ptr<Database>> fresh = SqliteDatabase::Open(dir.File("f.db"));
  ASSERT_THAT(stepwise, IsOk());
  ASSERT_THAT(fresh, IsOk());
  ASSERT_THAT(MigrateTo(**stepwise, 1), IsOk());
  EXPECT_THAT(SchemaVersion(**stepwise), IsOkAndHolds(1));
  EXPECT_THAT(Columns(**stepwise, "alerts"), ::testing::Not(::testing::Contains("unit")));
  ASSERT_THAT(MigrateToCurrent(**stepwise), IsOk());
  ASSERT_THAT(MigrateToCurrent(**fresh), IsOk());
  for (const std::string table :
       {"alerts", "diagnoses", "telemetry_frames", "checkpoints", "coefficients", "estimates"}) {
    EXPECT_THAT(Columns(**stepwise, table), ElementsAreArray(Columns(**fresh, table))) << table;
  }
  EXPECT_THAT(MigrateTo(**stepwise, kCurrentSchemaVersion + 1),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("target schema version")));
  EXPECT_THAT(MigrateTo(**stepwise, 1),
              StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("newer")));
}

TEST(Schema, NewerDatabaseThanTheCodeIsRefused) {
  TempDir dir;
  const std::string path = dir.File("future.db");
  {
    absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(path);
    ASSERT_THAT(db, IsOk());
    ASSERT_THAT(
        (*db)->Execute(absl::StrCat("CREATE TABLE from_the_future (x); PRAGMA user_version = ",
                                    kCurrentSchemaVersion + 1)),
        IsOk());
    EXPECT_THAT(MigrateToCurrent(**db),
                StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("newer")));
  }
  EXPECT_THAT(Storage::Open(path),
              StatusIs(absl::StatusCode::kFailedPrecondition,
                       HasSubstr(absl::StrCat("schema version ", kCurrentSchemaVersion + 1))));
  // The refused file was left alone.
  absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(path);
  ASSERT_THAT(db, IsOk());
  EXPECT_THAT(SchemaVersion(**db), IsOkAndHolds(kCurrentSchemaVersion + 1));
  EXPECT_THAT(QueryInt(**db, "SELECT COUNT(*) FROM sqlite_schema WHERE name = 'alerts'"),
              IsOkAndHolds(int64_t{0}));
}

TEST(Schema, InstantsRoundTripAsUnixNanoseconds) {
  const absl::Time t = T(0.123456789);
  EXPECT_EQ(TimeToUnixNanos(t), int64_t{1551398400123456789});
  EXPECT_EQ(UnixNanosToTime(TimeToUnixNanos(t)), t);
  // Sub-nanosecond parts are truncated toward the past, also before 1970.
  EXPECT_EQ(TimeToUnixNanos(absl::UnixEpoch() - absl::Nanoseconds(1) / 4), -1);
  EXPECT_EQ(TimeToUnixNanos(absl::InfinitePast()), std::numeric_limits<int64_t>::min());
  EXPECT_EQ(TimeToUnixNanos(absl::InfiniteFuture()), std::numeric_limits<int64_t>::max());
  EXPECT_EQ(UnixNanosToTime(std::numeric_limits<int64_t>::min()), absl::InfinitePast());
  EXPECT_EQ(UnixNanosToTime(std::numeric_limits<int64_t>::max()), absl::InfiniteFuture());
}

TEST(Schema, OnlyFiniteRepresentableInstantsAreStorable) {
  EXPECT_THAT(ValidateStorableTime(T(0), "x"), IsOk());
  EXPECT_THAT(ValidateStorableTime(absl::InfiniteFuture(), "alert.first_time"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("alert.first_time")));
  EXPECT_THAT(ValidateStorableTime(absl::FromUnixSeconds(int64_t{1} << 40), "t"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("1678 and 2262")));
  EXPECT_THAT(ValidateSpacecraftId("", "frame.spacecraft_id"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("frame.spacecraft_id")));
}

}  // namespace
}  // namespace esg::storage
