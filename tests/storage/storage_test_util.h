// Small builders shared by the storage tests (tests/storage/*_test.cc), both engines: the query
// helpers take a Database of either kind, so their SQL must run on SQLite and PostgreSQL alike.
#ifndef ESG_TESTS_STORAGE_STORAGE_TEST_UTIL_H_
#define ESG_TESTS_STORAGE_STORAGE_TEST_UTIL_H_

#include <cmath>
#include <cstdint>
#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "gmock/gmock.h"
#include "storage/records.h"
#include "storage/sqlite_db.h"

namespace esg::storage::testing {

// Matches an OK absl::StatusOr<T> whose value matches `matcher`.
MATCHER_P(IsOkAndHolds, matcher, "") {
  if (!arg.ok()) {
    *result_listener << "status is " << arg.status().ToString();
    return false;
  }
  return ::testing::ExplainMatchResult(matcher, *arg, result_listener);
}

// 2019-03-01T00:00:00Z plus `seconds`.
inline absl::Time T(double seconds) {
  return absl::FromUnixSeconds(1551398400) + absl::Seconds(seconds);
}

inline ArchivedFrame Frame(const std::string& spacecraft_id, int64_t sequence) {
  ArchivedFrame f;
  f.spacecraft_id = spacecraft_id;
  f.sequence = sequence;
  f.measurement_time = T(60.0 * static_cast<double>(sequence));
  // Binary payload with an embedded NUL, so blob handling is exercised.
  f.payload = absl::StrCat("frame", sequence, std::string(1, '\0'), "\xff", spacecraft_id);
  return f;
}

inline AlertRecord Alert(const std::string& spacecraft_id, double at_seconds,
                         const std::string& reason = "INNOVATION_TEST") {
  AlertRecord a;
  a.spacecraft_id = spacecraft_id;
  a.severity = "WARNING";
  a.reason = reason;
  a.subsystem = "star_tracker";
  a.value = 42.5;
  a.threshold = 30.0;
  a.unit = "arcsec";
  a.first_time = T(at_seconds);
  a.measurement_time = T(at_seconds);
  a.compute_time = T(at_seconds + 0.25);
  a.message = "innovation beyond k_d sigma";
  return a;
}

// The first column of the first row of `sql` as text ("" if no row), read in its own
// transaction.
inline absl::StatusOr<std::string> QueryText(Database& db, const std::string& sql) {
  absl::StatusOr<Transaction> txn = db.Begin(TransactionMode::kDeferred);
  if (!txn.ok()) return txn.status();
  absl::StatusOr<Statement*> st = txn->Prepare(sql);
  if (!st.ok()) return st.status();
  absl::StatusOr<bool> row = (*st)->Step();
  if (!row.ok()) return row.status();
  return *row ? (*st)->ColumnText(0) : std::string();
}

inline absl::StatusOr<int64_t> QueryInt(Database& db, const std::string& sql) {
  absl::StatusOr<Transaction> txn = db.Begin(TransactionMode::kDeferred);
  if (!txn.ok()) return txn.status();
  absl::StatusOr<Statement*> st = txn->Prepare(sql);
  if (!st.ok()) return st.status();
  absl::StatusOr<bool> row = (*st)->Step();
  if (!row.ok()) return row.status();
  return *row ? (*st)->ColumnInt64(0) : int64_t{-1};
}

inline absl::StatusOr<double> QueryDouble(Database& db, const std::string& sql) {
  absl::StatusOr<Transaction> txn = db.Begin(TransactionMode::kDeferred);
  if (!txn.ok()) return txn.status();
  absl::StatusOr<Statement*> st = txn->Prepare(sql);
  if (!st.ok()) return st.status();
  absl::StatusOr<bool> row = (*st)->Step();
  if (!row.ok()) return row.status();
  return *row ? (*st)->ColumnDoubleOrNaN(0) : std::nan("");
}

}  // namespace esg::storage::testing

#endif  // ESG_TESTS_STORAGE_STORAGE_TEST_UTIL_H_
