// Tests of storage/coefficient_store.h: round trip of all 16 values and sigmas with NaN and of the
// basis terms (storage/basis_terms_column.h), the per-gyro and time-window filters, the SI <-> deg/h, arcsec conversions, argument errors.
#include "storage/coefficient_store.h"

#include <cmath>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/basis_term.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "nlohmann/json.hpp"
#include "gtest/gtest.h"
#include "storage/postgres_db.h"
#include "storage/schema.h"
#include "storage/sqlite_db.h"
#include "storage/storage.h"
#include "tests/storage/backend.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/status_matchers.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::BackendTest;
using ::esg::storage::testing::IsOkAndHolds;
using ::esg::storage::testing::QueryDouble;
using ::esg::storage::testing::QueryInt;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

CoefficientRecord Record(const std::string& id, int gyro, double at_seconds) {
  CoefficientRecord r;
  r.spacecraft_id = id;
  r.gyro_id = gyro;
  r.measurement_time = T(at_seconds);
  r.compute_time = T(at_seconds + 1.5);
  r.model_name = "model10";
  for (int i = 0; i < kNumCoefficientValues; ++i) {
    r.values.push_back(0.01 * (i + 1) + gyro + at_seconds * 1e-6);
    r.sigmas.push_back(0.001 * (i + 1));
  }
  return r;
}

std::vector<int> Gyros(const std::vector<CoefficientRecord>& records) {
  std::vector<int> out;
  for (const CoefficientRecord& r : records) out.push_back(r.gyro_id);
  return out;
}

// The CoefficientStore tests run on both engines (tests/storage/backend.h).
class CoefficientStoreTest : public BackendTest {};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(CoefficientStoreTest);

TEST_P(CoefficientStoreTest, RoundTripsValuesSigmasAndNaN) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientRecord written = Record("RDK-1", 2, 600);
  written.values[estimator::kThetaMu] = std::nan("");   // not estimated
  written.sigmas[estimator::kThetaNu + 1] = std::nan("");  // unknown
  ASSERT_THAT((*storage)->coefficients().Append(written), IsOk());

  absl::StatusOr<std::vector<CoefficientRecord>> read = (*storage)->coefficients().History(
      "RDK-1", 0, absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_THAT(read, IsOk());
  ASSERT_EQ(read->size(), 1u);
  const CoefficientRecord& r = (*read)[0];
  EXPECT_EQ(r.spacecraft_id, "RDK-1");
  EXPECT_EQ(r.gyro_id, 2);
  EXPECT_EQ(r.measurement_time, T(600));
  EXPECT_EQ(r.compute_time, T(601.5));
  EXPECT_EQ(r.model_name, "model10");
  ASSERT_EQ(r.values.size(), written.values.size());
  ASSERT_EQ(r.sigmas.size(), written.sigmas.size());
  for (int i = 0; i < kNumCoefficientValues; ++i) {
    if (std::isnan(written.values[i])) {
      EXPECT_TRUE(std::isnan(r.values[i])) << i;
    } else {
      // SI -> the column's unit -> SI: equal up to the two conversions.
      EXPECT_DOUBLE_EQ(r.values[i], written.values[i]) << i;
    }
    if (std::isnan(written.sigmas[i])) {
      EXPECT_TRUE(std::isnan(r.sigmas[i])) << i;
    } else {
      EXPECT_DOUBLE_EQ(r.sigmas[i], written.sigmas[i]) << i;
    }
  }
}

TEST_P(CoefficientStoreTest, EachComponentLandsInTheRowOfItsTermKey) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientRecord written = Record("RDK-1", 1, 0);
  ASSERT_THAT((*storage)->coefficients().Append(written), IsOk());
  // What a user of plain SQL sees: the record's SI values in the unit each term key names.
  using estimator::RadPerSecToDegPerHour;
  using estimator::RadToArcsec;
  using ::testing::DoubleEq;
  Database& db = (*storage)->database();
  auto value = [&db](const std::string& column, const std::string& key) {
    return QueryDouble(db, absl::StrCat("SELECT ", column,
                                        " FROM coefficient_values WHERE term_key = '", key, "'"));
  };
  EXPECT_THAT(value("value", "k0_deg_h"),
              IsOkAndHolds(DoubleEq(RadPerSecToDegPerHour(written.values[estimator::kThetaK0]))));
  EXPECT_THAT(value("value", "c2y_deg_h"),
              IsOkAndHolds(
                  DoubleEq(RadPerSecToDegPerHour(written.values[estimator::kThetaC2 + 1]))));
  EXPECT_THAT(value("value", "misalignment_z_arcsec"),
              IsOkAndHolds(DoubleEq(RadToArcsec(written.values[kCoefficientMisalignment + 2]))));
  EXPECT_THAT(value("sigma", "nu31_deg_h"),
              IsOkAndHolds(
                  DoubleEq(RadPerSecToDegPerHour(written.sigmas[estimator::kThetaNu + 1]))));
  EXPECT_THAT(QueryInt(db, "SELECT COUNT(*) FROM coefficient_values"),
              IsOkAndHolds(kNumCoefficientValues));
}

// The drift coefficients of schema versions 1-9: the 13 of eq. (1), (10) as released then, the
// first 13 of the table (a term added to the table later is not in those databases).
constexpr int kVersion9Drift = 13;
constexpr int kVersion9Values = kVersion9Drift + 3;

// The coefficient table of schema versions 1-9 (one column per value and per sigma, schema.h),
// written as an earlier program did: every value in its column's unit, NULL for NaN and for
// absent sigmas.
std::string Version9Insert(const CoefficientRecord& r) {
  const char* const stems[kVersion9Values] = {
      "k0",   "c1x",  "c1y",  "c1z",  "c2x",  "c2y",  "c2z",  "mu12",
      "mu23", "mu31", "nu23", "nu31", "nu12", "misalignment_x", "misalignment_y",
      "misalignment_z"};
  auto cell = [](int i, double si) -> std::string {
    if (std::isnan(si)) return "NULL";
    const double column = i < kVersion9Drift ? estimator::RadPerSecToDegPerHour(si)
                                             : estimator::RadToArcsec(si);
    return absl::StrFormat("%.17g", column);
  };
  std::string columns, values;
  for (int i = 0; i < kVersion9Values; ++i) {
    const std::string unit = i < kVersion9Drift ? "deg_h" : "arcsec";
    // The record's index of the column: the misalignment follows every drift term of the table.
    const int k = i < kVersion9Drift ? i : kCoefficientMisalignment + (i - kVersion9Drift);
    absl::StrAppend(&columns, ", ", stems[i], "_", unit, ", ", stems[i], "_sigma_", unit);
    absl::StrAppend(&values, ", ", cell(i, r.values[k]), ", ",
                    r.sigmas.empty() ? "NULL" : cell(i, r.sigmas[k]));
  }
  return absl::StrCat(
      "INSERT INTO coefficients (spacecraft_id, gyro_id, measurement_time_unix_ns, "
      "compute_time_unix_ns, model_name",
      columns, ") VALUES ('", r.spacecraft_id, "', ", r.gyro_id, ", ",
      TimeToUnixNanos(r.measurement_time), ", ", TimeToUnixNanos(r.compute_time), ", '",
      r.model_name, "'", values, ")");
}

// Doubles equal bit for bit (NaN equal to NaN): what an export of them prints is then the same.
void ExpectSameRecords(const std::vector<CoefficientRecord>& a,
                       const std::vector<CoefficientRecord>& b) {
  ASSERT_EQ(a.size(), b.size());
  auto same = [](const std::vector<double>& x, const std::vector<double>& y) {
    if (x.size() != y.size()) return false;
    for (size_t i = 0; i < x.size(); ++i) {
      if (!(x[i] == y[i] || (std::isnan(x[i]) && std::isnan(y[i])))) return false;
    }
    return true;
  };
  for (size_t k = 0; k < a.size(); ++k) {
    EXPECT_EQ(a[k].spacecraft_id, b[k].spacecraft_id) << k;
    EXPECT_EQ(a[k].gyro_id, b[k].gyro_id) << k;
    EXPECT_EQ(a[k].measurement_time, b[k].measurement_time) << k;
    EXPECT_EQ(a[k].compute_time, b[k].compute_time) << k;
    EXPECT_EQ(a[k].model_name, b[k].model_name) << k;
    EXPECT_TRUE(same(a[k].values, b[k].values)) << k;
    EXPECT_TRUE(same(a[k].sigmas, b[k].sigmas)) << k;
    EXPECT_EQ(a[k].revised_time, b[k].revised_time) << k;
  }
}

// A database an earlier program wrote at schema version 9 (values in 32 columns) opens on either
// engine with its coefficients moved to coefficient_values, and reads back (History and pages,
// as the history RPC and the export read them) exactly what the same records read back from a
// database written at the current version.
TEST_P(CoefficientStoreTest, AVersion9DatabaseReadsBackTheSameHistoryAfterTheMigration) {
  std::vector<CoefficientRecord> records = {Record("OLD-9", 1, 60), Record("OLD-9", 2, 60),
                                            Record("OLD-9", 1, 120)};
  records[1].values[estimator::kThetaMu + 2] = std::nan("");  // not estimated
  records[2].sigmas.clear();                               // no sigmas
  records[2].values[estimator::kThetaK0] = -1.0 / 3.0;          // 17 digits survive the SQL text
  // A term added to the table after version 9 is not estimated in its databases (NaN).
  for (CoefficientRecord& r : records) {
    for (int i = kVersion9Drift; i < estimator::kNumDriftCoefficients; ++i) {
      r.values[i] = std::nan("");
      if (!r.sigmas.empty()) r.sigmas[i] = std::nan("");
    }
  }
  const std::string old_path = NewDatabase();
  {
    std::unique_ptr<Database> db;
    if (GetParam() == ::esg::storage::testing::Backend::kSqlite) {
      absl::StatusOr<std::unique_ptr<SqliteDatabase>> opened = SqliteDatabase::Open(old_path);
      ASSERT_THAT(opened, IsOk());
      db = *std::move(opened);
    } else {
      absl::StatusOr<std::unique_ptr<PostgresDatabase>> opened = PostgresDatabase::Open(old_path);
      ASSERT_THAT(opened, IsOk());
      db = *std::move(opened);
    }
    ASSERT_THAT(MigrateTo(*db, 9), IsOk());
    for (const CoefficientRecord& r : records) {
      ASSERT_THAT(db->Execute(Version9Insert(r)), IsOk()) << Version9Insert(r);
    }
    ASSERT_THAT(db->Execute("UPDATE coefficients SET revised_time_unix_ns = 5 WHERE gyro_id = 2"),
                IsOk());
  }
  records[1].revised_time = UnixNanosToTime(5);
  absl::StatusOr<std::unique_ptr<Storage>> old_storage = Storage::Open(old_path);
  ASSERT_THAT(old_storage, IsOk());
  EXPECT_THAT(SchemaVersion((*old_storage)->database()), IsOkAndHolds(kCurrentSchemaVersion));
  EXPECT_THAT(QueryInt((*old_storage)->database(), "SELECT COUNT(*) FROM coefficient_values"),
              IsOkAndHolds(3 * kVersion9Values));
  absl::StatusOr<std::unique_ptr<Storage>> new_storage = Storage::Open(NewDatabase());
  ASSERT_THAT(new_storage, IsOk());
  for (const CoefficientRecord& r : records) {
    ASSERT_THAT((*new_storage)->coefficients().Append(r), IsOk());
  }
  ASSERT_THAT((*new_storage)->database().Execute(
                  "UPDATE coefficients SET revised_time_unix_ns = 5 WHERE gyro_id = 2"),
              IsOk());
  for (bool include_revised : {false, true}) {
    absl::StatusOr<std::vector<CoefficientRecord>> migrated =
        (*old_storage)->coefficients().History("OLD-9", 0, absl::InfinitePast(),
                                               absl::InfiniteFuture(), include_revised);
    absl::StatusOr<std::vector<CoefficientRecord>> written =
        (*new_storage)->coefficients().History("OLD-9", 0, absl::InfinitePast(),
                                               absl::InfiniteFuture(), include_revised);
    ASSERT_THAT(migrated, IsOk());
    ASSERT_THAT(written, IsOk());
    ASSERT_EQ(migrated->size(), include_revised ? 3u : 2u);
    ExpectSameRecords(*migrated, *written);
    // And the values are the ones written (NaN where not estimated, no sigmas on the last).
    if (!include_revised) continue;
    EXPECT_TRUE(std::isnan((*migrated)[1].values[estimator::kThetaMu + 2]));
    EXPECT_THAT((*migrated)[2].sigmas, IsEmpty());
    EXPECT_EQ((*migrated)[1].revised_time, UnixNanosToTime(5));
    // Within 4 ulps as EXPECT_DOUBLE_EQ, and NaN (a term version 9 did not have) where NaN.
    auto same = [](double a, double b) {
      return std::isnan(b) ? std::isnan(a) : ::testing::Matcher<double>(::testing::DoubleEq(b)).Matches(a);
    };
    for (int i = 0; i < kNumCoefficientValues; ++i) {
      EXPECT_TRUE(same((*migrated)[2].values[i], records[2].values[i])) << i;
      EXPECT_TRUE(same((*migrated)[0].sigmas[i], records[0].sigmas[i])) << i;
    }
  }
  absl::StatusOr<CoefficientPage> page = (*old_storage)->coefficients().HistoryPage(
      "OLD-9", 0, absl::InfinitePast(), absl::InfiniteFuture(), std::nullopt, 1, true);
  ASSERT_THAT(page, IsOk());
  ASSERT_TRUE(page->next.has_value());
  absl::StatusOr<std::vector<CoefficientRecord>> first = (*new_storage)->coefficients().History(
      "OLD-9", 1, T(60), T(61));
  ASSERT_THAT(first, IsOk());
  ExpectSameRecords(page->records, *first);
}

TEST_P(CoefficientStoreTest, EmptySigmasReadBackEmpty) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientRecord written = Record("RDK-1", 1, 0);
  written.sigmas.clear();
  ASSERT_THAT((*storage)->coefficients().Append(written), IsOk());
  absl::StatusOr<std::vector<CoefficientRecord>> read = (*storage)->coefficients().History(
      "RDK-1", 1, absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_THAT(read, IsOk());
  ASSERT_EQ(read->size(), 1u);
  EXPECT_THAT((*read)[0].sigmas, IsEmpty());
  EXPECT_THAT((*read)[0].values, ::testing::Pointwise(::testing::DoubleEq(), written.values));
}

// Two basis terms of different kinds: an orbital harmonic (unit of s: 1) calibrated, and a ramp
// (unit of s: h in the configuration, s in SI) held at its value.
std::vector<estimator::BasisTerm> TwoBasisTerms() {
  estimator::BasisTerm orbit;
  orbit.kind = estimator::BasisKind::kOrbitalHarmonic;
  orbit.axis = 2;
  orbit.harmonic = 2;
  orbit.sine = true;
  orbit.period = 5400.0;
  orbit.epoch = T(123.25);
  orbit.value = estimator::DegPerHourToRadPerSec(0.0125);
  orbit.sigma = estimator::DegPerHourToRadPerSec(0.0004);
  estimator::BasisTerm ramp;
  ramp.kind = estimator::BasisKind::kRamp;
  ramp.axis = 3;
  ramp.epoch = T(0);
  ramp.value = estimator::DegPerHourToRadPerSec(0.002) / 3600.0;  // 0.002 deg/h per h
  ramp.sigma = 0.0;
  return {orbit, ramp};
}

TEST_P(CoefficientStoreTest, BasisTermsRoundTripAndTheColumnHoldsTheConfigurationUnits) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientRecord with_terms = Record("RDK-1", 1, 60);
  with_terms.basis_terms = TwoBasisTerms();
  ASSERT_THAT((*storage)->coefficients().Append(with_terms), IsOk());
  ASSERT_THAT((*storage)->coefficients().Append(Record("RDK-1", 2, 60)), IsOk());

  absl::StatusOr<CoefficientPage> page = (*storage)->coefficients().HistoryPage(
      "RDK-1", 0, absl::InfinitePast(), absl::InfiniteFuture(), std::nullopt, 10);
  ASSERT_THAT(page, IsOk());
  ASSERT_EQ(page->records.size(), 2u);
  EXPECT_THAT(page->records[1].basis_terms, IsEmpty());
  const std::vector<estimator::BasisTerm>& read = page->records[0].basis_terms;
  ASSERT_EQ(read.size(), 2u);
  for (size_t k = 0; k < read.size(); ++k) {
    const estimator::BasisTerm& w = with_terms.basis_terms[k];
    EXPECT_EQ(read[k].kind, w.kind) << k;
    EXPECT_EQ(read[k].axis, w.axis) << k;
    EXPECT_EQ(read[k].exponents, w.exponents) << k;
    EXPECT_EQ(read[k].index, w.index) << k;
    EXPECT_EQ(read[k].harmonic, w.harmonic) << k;
    EXPECT_EQ(read[k].sine, w.sine) << k;
    EXPECT_EQ(read[k].period, w.period) << k;
    EXPECT_EQ(read[k].epoch, w.epoch) << k;
    EXPECT_DOUBLE_EQ(read[k].value, w.value) << k;
    EXPECT_DOUBLE_EQ(read[k].sigma, w.sigma) << k;
  }
  // A user of plain SQL reads deg/h per unit of the regressor, as the configuration writes it.
  absl::StatusOr<std::string> column = testing::QueryText(
      (*storage)->database(), "SELECT basis_terms_json FROM coefficients WHERE gyro_id = 1");
  ASSERT_THAT(column, IsOk());
  const nlohmann::json terms = nlohmann::json::parse(*column);
  ASSERT_EQ(terms.size(), 2u);
  EXPECT_EQ(terms[0]["label"], "orbit sin 2 -> y");
  EXPECT_NEAR(terms[0]["value_deg_h"].get<double>(), 0.0125, 1e-15);
  EXPECT_NEAR(terms[0]["sigma_deg_h"].get<double>(), 0.0004, 1e-15);
  EXPECT_EQ(terms[1]["kind"], "ramp");
  EXPECT_NEAR(terms[1]["value_deg_h"].get<double>(), 0.002, 1e-15);  // per hour of ramp
  EXPECT_EQ(terms[1]["sigma_deg_h"].get<double>(), 0.0);
  EXPECT_THAT(QueryInt((*storage)->database(),
                       "SELECT COUNT(*) FROM coefficients WHERE basis_terms_json IS NULL"),
              IsOkAndHolds(1));
}

TEST_P(CoefficientStoreTest, AnUnreadableBasisTermsColumnIsDataLossNamingIt) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientRecord r = Record("RDK-1", 1, 60);
  r.basis_terms = TwoBasisTerms();
  ASSERT_THAT((*storage)->coefficients().Append(r), IsOk());
  for (const char* text : {"'not json'", "'[{\"kind\": \"orbital_harmonic\"}]'",
                           "'[{\"kind\": \"warp\", \"axis\": 1}]'"}) {
    ASSERT_THAT((*storage)->database().Execute(
                    absl::StrCat("UPDATE coefficients SET basis_terms_json = ", text)),
                IsOk());
    EXPECT_THAT((*storage)->coefficients().History("RDK-1", 0, absl::InfinitePast(),
                                                   absl::InfiniteFuture()),
                StatusIs(absl::StatusCode::kDataLoss, HasSubstr("coefficients.basis_terms_json")))
        << text;
  }
}

TEST_P(CoefficientStoreTest, HistoryFiltersByGyroAndHalfOpenWindowInTimeOrder) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientStore& store = (*storage)->coefficients();
  // Inserted out of time order on purpose.
  for (const auto& [gyro, at] : std::vector<std::pair<int, double>>{
           {2, 120}, {1, 120}, {1, 0}, {2, 60}, {3, 240}, {1, 60}}) {
    ASSERT_THAT(store.Append(Record("RDK-1", gyro, at)), IsOk());
  }
  ASSERT_THAT(store.Append(Record("RDK-2", 1, 60)), IsOk());

  absl::StatusOr<std::vector<CoefficientRecord>> all =
      store.History("RDK-1", 0, absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_THAT(all, IsOk());
  EXPECT_THAT(Gyros(*all), ElementsAre(1, 1, 2, 1, 2, 3));  // by (time, gyro)
  for (size_t i = 1; i < all->size(); ++i) {
    EXPECT_LE((*all)[i - 1].measurement_time, (*all)[i].measurement_time);
  }
  absl::StatusOr<std::vector<CoefficientRecord>> gyro1 = store.History("RDK-1", 1, T(60), T(120));
  ASSERT_THAT(gyro1, IsOk());
  ASSERT_EQ(gyro1->size(), 1u);  // T(120) is excluded
  EXPECT_EQ((*gyro1)[0].measurement_time, T(60));
  EXPECT_THAT(store.History("RDK-1", 4, absl::InfinitePast(), absl::InfiniteFuture()),
              IsOkAndHolds(IsEmpty()));
  EXPECT_THAT(store.History("RDK-1", -1, T(0), T(1)),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("gyro_id")));
}

// A history reads each record with its own values and sigmas, whole and in pages of any size
// (one query joins the records to their rows of coefficient_values): three gyros at 25 times,
// every value different, some without sigmas, some with NaN, some with basis terms, some
// revised; one record whose value rows are gone reads all NaN without sigmas, and a row of a
// term key this program does not know is skipped.
TEST_P(CoefficientStoreTest, AHistoryReadsEachRecordWithItsOwnValuesWholeAndInPages) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientStore& store = (*storage)->coefficients();
  std::vector<CoefficientRecord> written;
  for (int step = 0; step < 25; ++step) {
    for (int gyro = 1; gyro <= 3; ++gyro) {
      CoefficientRecord r = Record("RDK-1", gyro, 60.0 * step);
      const int n = static_cast<int>(written.size());
      for (int i = 0; i < kNumCoefficientValues; ++i) {
        r.values[i] = 1e-7 * (n * kNumCoefficientValues + i + 1);
        r.sigmas[i] = 1e-9 * (n * kNumCoefficientValues + i + 1);
      }
      if (n % 5 == 1) r.sigmas.clear();
      if (n % 7 == 2) r.values[n % kNumCoefficientValues] = std::nan("");
      if (n % 4 == 3) r.basis_terms = TwoBasisTerms();
      ASSERT_THAT(store.Append(r), IsOk());
      written.push_back(std::move(r));
    }
  }
  Database& db = (*storage)->database();
  // Gyro 3 at every sixth step is revised (the rows are numbered from 1 in insertion order).
  ASSERT_THAT(db.Execute("UPDATE coefficients SET revised_time_unix_ns = 7 "
                         "WHERE gyro_id = 3 AND (id - 3) % 18 = 0"),
              IsOk());
  for (size_t k = 2; k < written.size(); k += 18) written[k].revised_time = UnixNanosToTime(7);
  // Record 40 lost its value rows; record 41 has a row of an unknown term.
  ASSERT_THAT(db.Execute("DELETE FROM coefficient_values WHERE coefficient_id = 41"), IsOk());
  written[40].values.assign(kNumCoefficientValues, std::nan(""));
  written[40].sigmas.clear();
  ASSERT_THAT(db.Execute("INSERT INTO coefficient_values (coefficient_id, term_key, value, sigma) "
                         "VALUES (42, 'k9_deg_h', 1.0, 2.0)"),
              IsOk());

  for (bool include_revised : {false, true}) {
    std::vector<CoefficientRecord> expected;
    for (const CoefficientRecord& r : written) {
      if (include_revised || r.revised_time == absl::InfinitePast()) expected.push_back(r);
    }
    absl::StatusOr<std::vector<CoefficientRecord>> whole =
        store.History("RDK-1", 0, absl::InfinitePast(), absl::InfiniteFuture(), include_revised);
    ASSERT_THAT(whole, IsOk());
    ASSERT_EQ(whole->size(), expected.size());
    for (size_t k = 0; k < expected.size(); ++k) {
      const CoefficientRecord& got = (*whole)[k];
      const CoefficientRecord& want = expected[k];
      EXPECT_EQ(got.gyro_id, want.gyro_id) << k;
      EXPECT_EQ(got.measurement_time, want.measurement_time) << k;
      EXPECT_EQ(got.revised_time, want.revised_time) << k;
      EXPECT_EQ(got.basis_terms.size(), want.basis_terms.size()) << k;
      ASSERT_EQ(got.values.size(), want.values.size()) << k;
      ASSERT_EQ(got.sigmas.size(), want.sigmas.size()) << k;
      for (int i = 0; i < kNumCoefficientValues; ++i) {
        if (std::isnan(want.values[i])) {
          EXPECT_TRUE(std::isnan(got.values[i])) << k << " " << i;
        } else {
          EXPECT_DOUBLE_EQ(got.values[i], want.values[i]) << k << " " << i;
        }
        if (!want.sigmas.empty()) EXPECT_DOUBLE_EQ(got.sigmas[i], want.sigmas[i]) << k << " " << i;
      }
    }
    // Pages of any size give the same records bit for bit, and one gyro's history its part.
    for (int64_t limit : {1, 4, 7, 1000}) {
      std::vector<CoefficientRecord> paged;
      std::optional<CoefficientCursor> after;
      do {
        absl::StatusOr<CoefficientPage> page =
            store.HistoryPage("RDK-1", 0, absl::InfinitePast(), absl::InfiniteFuture(), after,
                              limit, include_revised);
        ASSERT_THAT(page, IsOk());
        ASSERT_LE(page->records.size(), static_cast<size_t>(limit));
        for (CoefficientRecord& r : page->records) paged.push_back(std::move(r));
        after = page->next;
      } while (after.has_value());
      SCOPED_TRACE(limit);
      ExpectSameRecords(paged, *whole);
    }
    absl::StatusOr<std::vector<CoefficientRecord>> gyro2 =
        store.History("RDK-1", 2, absl::InfinitePast(), absl::InfiniteFuture(), include_revised);
    ASSERT_THAT(gyro2, IsOk());
    std::vector<CoefficientRecord> gyro2_of_whole;
    for (const CoefficientRecord& r : *whole) {
      if (r.gyro_id == 2) gyro2_of_whole.push_back(r);
    }
    ExpectSameRecords(*gyro2, gyro2_of_whole);
  }
}

TEST_P(CoefficientStoreTest, RejectsMalformedRecords) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientStore& store = (*storage)->coefficients();
  CoefficientRecord r = Record("RDK-1", 0, 0);
  EXPECT_THAT(store.Append(r),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("gyro_id = 0")));
  r = Record("RDK-1", 1, 0);
  r.values.pop_back();
  EXPECT_THAT(store.Append(r),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr(absl::StrCat("values: ", kNumCoefficientValues - 1, " entries"))));
  r = Record("RDK-1", 1, 0);
  r.sigmas.resize(kNumCoefficientValues - 3);
  EXPECT_THAT(store.Append(r), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("sigmas")));
  r = Record("RDK-1", 1, 0);
  r.model_name.clear();
  EXPECT_THAT(store.Append(r),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("model_name")));
  r = Record("", 1, 0);
  EXPECT_THAT(store.Append(r),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("spacecraft_id")));
  r = Record("RDK-1", 1, 0);
  r.basis_terms = TwoBasisTerms();
  r.basis_terms[1].axis = 4;
  EXPECT_THAT(store.Append(r), StatusIs(absl::StatusCode::kInvalidArgument,
                                        HasSubstr("coefficients.basis_terms[1]")));
  EXPECT_THAT(store.History("RDK-1", 0, absl::InfinitePast(), absl::InfiniteFuture()),
              IsOkAndHolds(IsEmpty()));
}

TEST(CoefficientValues, ConvertsEstimatorSiToTheStoredUnitsAndBack) {
  estimator::DriftCoefficients drift;
  drift.k0 = estimator::DegPerHourToRadPerSec(0.12);
  drift.C1 = Eigen::Vector3d(estimator::DegPerHourToRadPerSec(0.1),
                             estimator::DegPerHourToRadPerSec(-0.2),
                             estimator::DegPerHourToRadPerSec(0.05));
  drift.C2 = Eigen::Vector3d(estimator::DegPerHourToRadPerSec(-0.5), 0.0, 0.0);
  drift.mu = Eigen::Vector3d(0.0, estimator::DegPerHourToRadPerSec(0.01), 0.0);
  drift.nu = Eigen::Vector3d(0.0, 0.0, estimator::DegPerHourToRadPerSec(0.02));
  const Eigen::Vector3d misalignment_b(estimator::ArcsecToRad(10.0), estimator::ArcsecToRad(-20.0),
                                       estimator::ArcsecToRad(30.0));
  const std::vector<double> values = ToCoefficientValues(drift, misalignment_b);
  ASSERT_EQ(values.size(), static_cast<size_t>(kNumCoefficientValues));
  // SI, in the layout of records.h.
  EXPECT_EQ(values[estimator::kThetaK0], drift.k0);
  EXPECT_EQ(values[estimator::kThetaC1 + 1], drift.C1[1]);
  EXPECT_EQ(values[estimator::kThetaC2], drift.C2[0]);
  EXPECT_EQ(values[estimator::kThetaMu + 1], drift.mu[1]);  // mu23
  EXPECT_EQ(values[estimator::kThetaNu + 2], drift.nu[2]);  // nu12
  EXPECT_EQ(values[kCoefficientMisalignment + 1], misalignment_b[1]);

  estimator::DriftCoefficients back;
  Eigen::Vector3d misalignment_back;
  ASSERT_THAT(FromCoefficientValues(values, &back, &misalignment_back), IsOk());
  EXPECT_TRUE(back.AsVector().isApprox(drift.AsVector(), 1e-14));
  EXPECT_TRUE(misalignment_back.isApprox(misalignment_b, 1e-14));
  EXPECT_THAT(FromCoefficientValues(absl::MakeConstSpan(values).subspan(1), &back,
                                    &misalignment_back),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("15 entries")));
}

}  // namespace
}  // namespace esg::storage
