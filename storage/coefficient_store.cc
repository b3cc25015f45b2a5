// Coefficient histories; contract in coefficient_store.h.
#include "storage/coefficient_store.h"

#include <array>
#include <cmath>
#include <limits>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "estimator/model_terms.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"
#include "storage/basis_terms_column.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

// Fixed leading columns, then the value columns, the sigma columns (records.h) and the basis
// terms.
constexpr int kNumLeadingColumns = 5;
constexpr int kBasisColumn = kNumLeadingColumns + 2 * kNumCoefficientValues;

std::string AllColumns() {
  return absl::StrCat(
      "spacecraft_id, gyro_id, measurement_time_unix_ns, compute_time_unix_ns, model_name, ",
      absl::StrJoin(CoefficientColumns(), ", "), ", ",
      absl::StrJoin(CoefficientSigmaColumns(), ", "), ", basis_terms_json");
}

const std::string& InsertSql() {
  static const std::string* const sql = [] {
    std::string params;
    for (int i = 1; i <= kBasisColumn + 1; ++i) {
      absl::StrAppend(&params, i == 1 ? "" : ", ", "?", i);
    }
    return new std::string(
        absl::StrCat("INSERT INTO coefficients (", AllColumns(), ") VALUES (", params, ")"));
  }();
  return *sql;
}

// Current rows only, unless ?9 is 1 (revised ones too).
const std::string& HistorySql(bool one_gyro) {
  static const std::string* const all = new std::string(absl::StrCat(
      "SELECT ", AllColumns(),
      ", revised_time_unix_ns FROM coefficients WHERE spacecraft_id = ?1 "
      "AND measurement_time_unix_ns >= ?2 AND measurement_time_unix_ns < ?3 "
      "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) ORDER BY measurement_time_unix_ns, gyro_id, id"));
  static const std::string* const one = new std::string(absl::StrCat(
      "SELECT ", AllColumns(),
      ", revised_time_unix_ns FROM coefficients WHERE spacecraft_id = ?1 "
      "AND measurement_time_unix_ns >= ?2 AND measurement_time_unix_ns < ?3 AND gyro_id = ?4 "
      "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) ORDER BY measurement_time_unix_ns, gyro_id, id"));
  return one_gyro ? *one : *all;
}

// A page: the history order continued strictly after a cursor (row values, SQLite >= 3.15), the
// revision time and row id appended as the last columns.
const std::string& HistoryPageSql(bool one_gyro) {
  static const std::string* const all = new std::string(absl::StrCat(
      "SELECT ", AllColumns(),
      ", revised_time_unix_ns, id FROM coefficients WHERE spacecraft_id = ?1 "
      "AND measurement_time_unix_ns >= ?2 AND measurement_time_unix_ns < ?3 "
      "AND (measurement_time_unix_ns, gyro_id, id) > (?4, ?5, ?6) "
      "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) "
      "ORDER BY measurement_time_unix_ns, gyro_id, id LIMIT ?7"));
  static const std::string* const one = new std::string(absl::StrCat(
      "SELECT ", AllColumns(),
      ", revised_time_unix_ns, id FROM coefficients WHERE spacecraft_id = ?1 "
      "AND measurement_time_unix_ns >= ?2 AND measurement_time_unix_ns < ?3 "
      "AND (measurement_time_unix_ns, gyro_id, id) > (?4, ?5, ?6) AND gyro_id = ?8 "
      "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) "
      "ORDER BY measurement_time_unix_ns, gyro_id, id LIMIT ?7"));
  return one_gyro ? *one : *all;
}

// Column of revised_time_unix_ns in the history queries, and of the row id in a page's.
constexpr int kRevisedColumn = kBasisColumn + 1;
constexpr int kRowIdColumn = kRevisedColumn + 1;

// Records are SI; each column holds the unit its name carries (records.h): deg/h for the 13
// drift terms, arcsec for the misalignment. NaN passes through.
double ToColumnUnit(int index, double si) {
  return index < kCoefficientMisalignment ? estimator::RadPerSecToDegPerHour(si)
                                          : estimator::RadToArcsec(si);
}
double FromColumnUnit(int index, double column) {
  return index < kCoefficientMisalignment ? estimator::DegPerHourToRadPerSec(column)
                                          : estimator::ArcsecToRad(column);
}

// The record of the current row (columns in the order of AllColumns()); DataLoss when its basis
// terms do not read.
absl::StatusOr<CoefficientRecord> ReadRecord(const Statement& st) {
  CoefficientRecord r;
  r.spacecraft_id = st.ColumnText(0);
  r.gyro_id = static_cast<int>(st.ColumnInt64(1));
  r.measurement_time = UnixNanosToTime(st.ColumnInt64(2));
  r.compute_time = UnixNanosToTime(st.ColumnInt64(3));
  r.model_name = st.ColumnText(4);
  r.values.resize(kNumCoefficientValues);
  bool any_sigma = false;
  std::vector<double> sigmas(kNumCoefficientValues);
  for (int i = 0; i < kNumCoefficientValues; ++i) {
    const int value_column = kNumLeadingColumns + i;
    const int sigma_column = value_column + kNumCoefficientValues;
    r.values[i] = FromColumnUnit(i, st.ColumnDoubleOrNaN(value_column));
    sigmas[i] = FromColumnUnit(i, st.ColumnDoubleOrNaN(sigma_column));
    any_sigma = any_sigma || !st.ColumnIsNull(sigma_column);
  }
  if (any_sigma) r.sigmas = std::move(sigmas);
  if (!st.ColumnIsNull(kBasisColumn)) {
    ASSIGN_OR_RETURN(r.basis_terms, BasisTermsFromColumn(st.ColumnText(kBasisColumn)));
  }
  if (!st.ColumnIsNull(kRevisedColumn)) {
    r.revised_time = UnixNanosToTime(st.ColumnInt64(kRevisedColumn));
  }
  return r;
}

absl::Status Validate(const CoefficientRecord& r) {
  RETURN_IF_ERROR(ValidateSpacecraftId(r.spacecraft_id, "coefficients.spacecraft_id"));
  if (r.gyro_id < 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("coefficients.gyro_id = ", r.gyro_id, ": must be >= 1"));
  }
  if (r.model_name.empty()) {
    return absl::InvalidArgumentError("coefficients.model_name: empty");
  }
  if (r.values.size() != kNumCoefficientValues) {
    return absl::InvalidArgumentError(absl::StrCat("coefficients.values: ", r.values.size(),
                                                   " entries, expected ",
                                                   kNumCoefficientValues));
  }
  if (!r.sigmas.empty() && r.sigmas.size() != kNumCoefficientValues) {
    return absl::InvalidArgumentError(absl::StrCat("coefficients.sigmas: ", r.sigmas.size(),
                                                   " entries, expected 0 or ",
                                                   kNumCoefficientValues));
  }
  for (size_t k = 0; k < r.basis_terms.size(); ++k) {
    RETURN_IF_ERROR(estimator::ValidateBasisTerm(
        r.basis_terms[k], absl::StrCat("coefficients.basis_terms[", k, "]")));
  }
  RETURN_IF_ERROR(ValidateStorableTime(r.measurement_time, "coefficients.measurement_time"));
  return ValidateStorableTime(r.compute_time, "coefficients.compute_time");
}

// The column names of the values (sigma = false) or of the sigmas, in layout order.
std::array<std::string, kNumCoefficientValues> MakeColumns(bool sigma) {
  std::array<std::string, kNumCoefficientValues> columns;
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    columns[term.theta_index] =
        sigma ? estimator::FixedTermSigmaColumn(term) : estimator::FixedTermValueColumn(term);
  }
  const char* const axes[3] = {"x", "y", "z"};
  for (int i = 0; i < 3; ++i) {
    columns[kCoefficientMisalignment + i] =
        absl::StrCat("misalignment_", axes[i], sigma ? "_sigma_arcsec" : "_arcsec");
  }
  return columns;
}

}  // namespace

const std::array<std::string, kNumCoefficientValues>& CoefficientColumns() {
  static const auto* const columns =
      new std::array<std::string, kNumCoefficientValues>(MakeColumns(/*sigma=*/false));
  return *columns;
}

const std::array<std::string, kNumCoefficientValues>& CoefficientSigmaColumns() {
  static const auto* const columns =
      new std::array<std::string, kNumCoefficientValues>(MakeColumns(/*sigma=*/true));
  return *columns;
}

std::vector<double> ToCoefficientValues(const estimator::DriftCoefficients& drift,
                                        const Eigen::Vector3d& misalignment_b) {
  std::vector<double> values(kNumCoefficientValues);
  const estimator::DriftVector theta = drift.AsVector();
  for (int i = 0; i < estimator::kNumDriftCoefficients; ++i) values[i] = theta[i];
  for (int i = 0; i < 3; ++i) values[kCoefficientMisalignment + i] = misalignment_b[i];
  return values;
}

absl::Status FromCoefficientValues(absl::Span<const double> values,
                                   estimator::DriftCoefficients* drift,
                                   Eigen::Vector3d* misalignment_b) {
  if (values.size() != kNumCoefficientValues) {
    return absl::InvalidArgumentError(absl::StrCat("coefficient values: ", values.size(),
                                                   " entries, expected ",
                                                   kNumCoefficientValues));
  }
  estimator::DriftVector theta;
  for (int i = 0; i < estimator::kNumDriftCoefficients; ++i) theta[i] = values[i];
  *drift = estimator::DriftCoefficients::FromVector(theta);
  for (int i = 0; i < 3; ++i) (*misalignment_b)[i] = values[kCoefficientMisalignment + i];
  return absl::OkStatus();
}

absl::Status CoefficientStore::Append(const CoefficientRecord& record) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  RETURN_IF_ERROR(Append(txn, record));
  return txn.Commit();
}

absl::Status CoefficientStore::Append(Transaction& txn, const CoefficientRecord& record) {
  RETURN_IF_ERROR(Validate(record));
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(InsertSql()));
  st->BindText(1, record.spacecraft_id)
      .BindInt64(2, record.gyro_id)
      .BindInt64(3, TimeToUnixNanos(record.measurement_time))
      .BindInt64(4, TimeToUnixNanos(record.compute_time))
      .BindText(5, record.model_name);
  for (int i = 0; i < kNumCoefficientValues; ++i) {
    const int value_index = kNumLeadingColumns + 1 + i;
    const int sigma_index = value_index + kNumCoefficientValues;
    st->BindDouble(value_index, ToColumnUnit(i, record.values[i]));
    if (record.sigmas.empty()) {
      st->BindNull(sigma_index);
    } else {
      st->BindDouble(sigma_index, ToColumnUnit(i, record.sigmas[i]));
    }
  }
  if (record.basis_terms.empty()) {
    st->BindNull(kBasisColumn + 1);
  } else {
    st->BindText(kBasisColumn + 1, BasisTermsToColumn(record.basis_terms));
  }
  return st->Run();
}

absl::StatusOr<std::vector<CoefficientRecord>> CoefficientStore::History(
    absl::string_view spacecraft_id, int gyro_id, absl::Time from, absl::Time to,
    bool include_revised) {
  if (gyro_id < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("gyro_id = ", gyro_id, ": must be >= 1, or 0 for all gyros"));
  }
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(HistorySql(gyro_id != 0)));
  st->BindText(1, spacecraft_id).BindInt64(2, TimeToUnixNanos(from)).BindInt64(3, TimeToUnixNanos(to));
  if (gyro_id != 0) st->BindInt64(4, gyro_id);
  st->BindInt64(9, include_revised ? 1 : 0);
  std::vector<CoefficientRecord> out;
  while (true) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    ASSIGN_OR_RETURN(CoefficientRecord record, ReadRecord(*st));
    out.push_back(std::move(record));
  }
  return out;
}

absl::StatusOr<CoefficientPage> CoefficientStore::HistoryPage(
    absl::string_view spacecraft_id, int gyro_id, absl::Time from, absl::Time to,
    const std::optional<CoefficientCursor>& after, int64_t limit, bool include_revised) {
  if (gyro_id < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("gyro_id = ", gyro_id, ": must be >= 1, or 0 for all gyros"));
  }
  if (limit <= 0) {
    return absl::InvalidArgumentError(absl::StrCat("limit = ", limit, ": must be positive"));
  }
  // Before every row: no stored time, gyro id or row id is below these.
  const CoefficientCursor start = after.value_or(
      CoefficientCursor{std::numeric_limits<int64_t>::min(), 0, 0});
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(HistoryPageSql(gyro_id != 0)));
  st->BindText(1, spacecraft_id)
      .BindInt64(2, TimeToUnixNanos(from))
      .BindInt64(3, TimeToUnixNanos(to))
      .BindInt64(4, start.measurement_time_unix_ns)
      .BindInt64(5, start.gyro_id)
      .BindInt64(6, start.row_id)
      .BindInt64(7, limit + 1);
  if (gyro_id != 0) st->BindInt64(8, gyro_id);
  st->BindInt64(9, include_revised ? 1 : 0);
  CoefficientPage page;
  CoefficientCursor last;
  while (true) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    if (static_cast<int64_t>(page.records.size()) == limit) {
      page.next = last;  // a row beyond the page exists
      break;
    }
    ASSIGN_OR_RETURN(CoefficientRecord record, ReadRecord(*st));
    page.records.push_back(std::move(record));
    last.measurement_time_unix_ns = st->ColumnInt64(2);
    last.gyro_id = st->ColumnInt64(1);
    last.row_id = st->ColumnInt64(kRowIdColumn);
  }
  return page;
}

}  // namespace esg::storage
