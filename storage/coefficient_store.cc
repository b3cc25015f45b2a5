// Coefficient histories; contract in coefficient_store.h.
#include "storage/coefficient_store.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string>
#include <utility>

#include "absl/container/flat_hash_map.h"
#include "absl/strings/str_cat.h"
#include "estimator/model_terms.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"
#include "storage/basis_terms_column.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

// The columns of table coefficients a history reads, in this order; the values are rows of
// coefficient_values keyed by term (schema.h version 10).
constexpr char kColumns[] =
    "spacecraft_id, gyro_id, measurement_time_unix_ns, compute_time_unix_ns, model_name, "
    "basis_terms_json, revised_time_unix_ns, id";
constexpr int kBasisColumn = 5;
constexpr int kRevisedColumn = 6;
constexpr int kRowIdColumn = 7;

constexpr char kInsertSql[] =
    "INSERT INTO coefficients (spacecraft_id, gyro_id, measurement_time_unix_ns, "
    "compute_time_unix_ns, model_name, basis_terms_json) VALUES (?1, ?2, ?3, ?4, ?5, ?6) "
    "RETURNING id";

// All values of one coefficient row in one statement: ?1 the row id, then (term key, value,
// sigma) per value of the layout.
const std::string& InsertValuesSql() {
  static const std::string* const sql = [] {
    std::string rows;
    for (int i = 0; i < kNumCoefficientValues; ++i) {
      absl::StrAppend(&rows, i == 0 ? "" : ", ", "(?1, ?", 2 + 3 * i, ", ?", 3 + 3 * i, ", ?",
                      4 + 3 * i, ")");
    }
    return new std::string(absl::StrCat(
        "INSERT INTO coefficient_values (coefficient_id, term_key, value, sigma) VALUES ", rows));
  }();
  return *sql;
}

// Current rows only, unless ?9 is 1 (revised ones too).
const std::string& HistorySql(bool one_gyro) {
  static const std::string* const all = new std::string(absl::StrCat(
      "SELECT ", kColumns,
      " FROM coefficients WHERE spacecraft_id = ?1 "
      "AND measurement_time_unix_ns >= ?2 AND measurement_time_unix_ns < ?3 "
      "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) ORDER BY measurement_time_unix_ns, gyro_id, id"));
  static const std::string* const one = new std::string(absl::StrCat(
      "SELECT ", kColumns,
      " FROM coefficients WHERE spacecraft_id = ?1 "
      "AND measurement_time_unix_ns >= ?2 AND measurement_time_unix_ns < ?3 AND gyro_id = ?4 "
      "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) ORDER BY measurement_time_unix_ns, gyro_id, id"));
  return one_gyro ? *one : *all;
}

// A page: the history order continued strictly after a cursor (row values, SQLite >= 3.15).
const std::string& HistoryPageSql(bool one_gyro) {
  static const std::string* const all = new std::string(absl::StrCat(
      "SELECT ", kColumns,
      " FROM coefficients WHERE spacecraft_id = ?1 "
      "AND measurement_time_unix_ns >= ?2 AND measurement_time_unix_ns < ?3 "
      "AND (measurement_time_unix_ns, gyro_id, id) > (?4, ?5, ?6) "
      "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) "
      "ORDER BY measurement_time_unix_ns, gyro_id, id LIMIT ?7"));
  static const std::string* const one = new std::string(absl::StrCat(
      "SELECT ", kColumns,
      " FROM coefficients WHERE spacecraft_id = ?1 "
      "AND measurement_time_unix_ns >= ?2 AND measurement_time_unix_ns < ?3 "
      "AND (measurement_time_unix_ns, gyro_id, id) > (?4, ?5, ?6) AND gyro_id = ?8 "
      "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) "
      "ORDER BY measurement_time_unix_ns, gyro_id, id LIMIT ?7"));
  return one_gyro ? *one : *all;
}

// The values of a history's records in one query, joined to the records by their row id: the
// rows of coefficient_values (coefficient_id, term_key, value, sigma) of every record of the
// spacecraft in the window [?2, ?3), and of gyro ?4 alone when one gyro is asked. Revised records
// are not filtered out: the records query decides which records there are, and a record revised
// between the two queries still finds its values.
const std::string& HistoryValuesSql(bool one_gyro) {
  static const std::string* const all = new std::string(
      "SELECT v.coefficient_id, v.term_key, v.value, v.sigma "
      "FROM coefficients c JOIN coefficient_values v ON v.coefficient_id = c.id "
      "WHERE c.spacecraft_id = ?1 "
      "AND c.measurement_time_unix_ns >= ?2 AND c.measurement_time_unix_ns < ?3");
  static const std::string* const one =
      new std::string(absl::StrCat(*all, " AND c.gyro_id = ?4"));
  return one_gyro ? *one : *all;
}

// The values of one page's records: those of the records strictly after the page's cursor
// (?4, ?5, ?6) up to its last record (?7, ?8, ?9) inclusive in the history order, of gyro ?10
// alone when one gyro is asked; ?2 and ?3 bound their times (the later of the window's start and
// the cursor's time, the last record's time), so that the index coefficients_by_time covers it.
const std::string& PageValuesSql(bool one_gyro) {
  static const std::string* const all = new std::string(
      "SELECT v.coefficient_id, v.term_key, v.value, v.sigma "
      "FROM coefficients c JOIN coefficient_values v ON v.coefficient_id = c.id "
      "WHERE c.spacecraft_id = ?1 "
      "AND c.measurement_time_unix_ns >= ?2 AND c.measurement_time_unix_ns <= ?3 "
      "AND (c.measurement_time_unix_ns, c.gyro_id, c.id) > (?4, ?5, ?6) "
      "AND (c.measurement_time_unix_ns, c.gyro_id, c.id) <= (?7, ?8, ?9)");
  static const std::string* const one =
      new std::string(absl::StrCat(*all, " AND c.gyro_id = ?10"));
  return one_gyro ? *one : *all;
}

// Records are SI; each value is stored in the unit its key carries (records.h): deg/h for the
// drift terms, arcsec for the misalignment. NaN passes through.
double ToColumnUnit(int index, double si) {
  return index < kCoefficientMisalignment ? estimator::RadPerSecToDegPerHour(si)
                                          : estimator::RadToArcsec(si);
}
double FromColumnUnit(int index, double column) {
  return index < kCoefficientMisalignment ? estimator::DegPerHourToRadPerSec(column)
                                          : estimator::ArcsecToRad(column);
}

// Layout index of a term key (CoefficientColumns()); -1 for a key this program does not know.
int LayoutIndex(absl::string_view term_key) {
  static const auto* const index = [] {
    auto* m = new absl::flat_hash_map<std::string, int>;
    for (int i = 0; i < kNumCoefficientValues; ++i) (*m)[CoefficientColumns()[i]] = i;
    return m;
  }();
  const auto it = index->find(term_key);
  return it == index->end() ? -1 : it->second;
}

// The record of the current row of a history query (columns kColumns) without its values;
// DataLoss when its basis terms do not read.
absl::StatusOr<CoefficientRecord> ReadRecord(const Statement& st) {
  CoefficientRecord r;
  r.spacecraft_id = st.ColumnText(0);
  r.gyro_id = static_cast<int>(st.ColumnInt64(1));
  r.measurement_time = UnixNanosToTime(st.ColumnInt64(2));
  r.compute_time = UnixNanosToTime(st.ColumnInt64(3));
  r.model_name = st.ColumnText(4);
  if (!st.ColumnIsNull(kBasisColumn)) {
    ASSIGN_OR_RETURN(r.basis_terms, BasisTermsFromColumn(st.ColumnText(kBasisColumn)));
  }
  if (!st.ColumnIsNull(kRevisedColumn)) {
    r.revised_time = UnixNanosToTime(st.ColumnInt64(kRevisedColumn));
  }
  return r;
}

// Steps a values query (HistoryValuesSql, PageValuesSql: coefficient_id, term_key, value, sigma)
// and puts each value into the record of `records` whose row id is at the same position of
// `ids`; rows of other records (revised ones the history leaves out) and of term keys this
// program does not know are skipped. A value without a row reads NaN; sigmas that are all NULL
// (or have no row) read back as empty.
absl::Status ReadValues(Statement& st, const std::vector<int64_t>& ids,
                        std::vector<CoefficientRecord>* records) {
  absl::flat_hash_map<int64_t, size_t> position;
  position.reserve(ids.size());
  for (size_t k = 0; k < ids.size(); ++k) position[ids[k]] = k;
  std::vector<std::vector<double>> sigmas(ids.size());
  std::vector<bool> any_sigma(ids.size(), false);
  for (size_t k = 0; k < ids.size(); ++k) {
    (*records)[k].values.assign(kNumCoefficientValues, std::numeric_limits<double>::quiet_NaN());
    sigmas[k].assign(kNumCoefficientValues, std::numeric_limits<double>::quiet_NaN());
  }
  while (true) {
    ASSIGN_OR_RETURN(bool row, st.Step());
    if (!row) break;
    const auto it = position.find(st.ColumnInt64(0));
    if (it == position.end()) continue;
    const int i = LayoutIndex(st.ColumnText(1));
    if (i < 0) continue;
    const size_t k = it->second;
    (*records)[k].values[i] = FromColumnUnit(i, st.ColumnDoubleOrNaN(2));
    sigmas[k][i] = FromColumnUnit(i, st.ColumnDoubleOrNaN(3));
    if (!st.ColumnIsNull(3)) any_sigma[k] = true;
  }
  for (size_t k = 0; k < ids.size(); ++k) {
    if (any_sigma[k]) (*records)[k].sigmas = std::move(sigmas[k]);
  }
  return absl::OkStatus();
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
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(kInsertSql));
  st->BindText(1, record.spacecraft_id)
      .BindInt64(2, record.gyro_id)
      .BindInt64(3, TimeToUnixNanos(record.measurement_time))
      .BindInt64(4, TimeToUnixNanos(record.compute_time))
      .BindText(5, record.model_name);
  if (record.basis_terms.empty()) {
    st->BindNull(6);
  } else {
    st->BindText(6, BasisTermsToColumn(record.basis_terms));
  }
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return absl::InternalError("INSERT INTO coefficients returned no id");
  const int64_t id = st->ColumnInt64(0);
  st->Reset();
  ASSIGN_OR_RETURN(Statement * values, txn.Prepare(InsertValuesSql()));
  values->BindInt64(1, id);
  for (int i = 0; i < kNumCoefficientValues; ++i) {
    values->BindText(2 + 3 * i, CoefficientColumns()[i])
        .BindDouble(3 + 3 * i, ToColumnUnit(i, record.values[i]));
    if (record.sigmas.empty()) {
      values->BindNull(4 + 3 * i);
    } else {
      values->BindDouble(4 + 3 * i, ToColumnUnit(i, record.sigmas[i]));
    }
  }
  return values->Run();
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
  std::vector<int64_t> ids;
  while (true) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    ASSIGN_OR_RETURN(CoefficientRecord record, ReadRecord(*st));
    out.push_back(std::move(record));
    ids.push_back(st->ColumnInt64(kRowIdColumn));
  }
  st->Reset();
  if (out.empty()) return out;
  // The values of all of them in one more query (not one per record).
  ASSIGN_OR_RETURN(Statement * values, txn.Prepare(HistoryValuesSql(gyro_id != 0)));
  values->BindText(1, spacecraft_id)
      .BindInt64(2, TimeToUnixNanos(from))
      .BindInt64(3, TimeToUnixNanos(to));
  if (gyro_id != 0) values->BindInt64(4, gyro_id);
  RETURN_IF_ERROR(ReadValues(*values, ids, &out));
  values->Reset();
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
  std::vector<int64_t> ids;
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
    ids.push_back(last.row_id);
  }
  st->Reset();
  if (page.records.empty()) return page;
  // The values of the page's records in one more query (not one per record): those between the
  // cursor and the page's last record.
  ASSIGN_OR_RETURN(Statement * values, txn.Prepare(PageValuesSql(gyro_id != 0)));
  values->BindText(1, spacecraft_id)
      .BindInt64(2, std::max(TimeToUnixNanos(from), start.measurement_time_unix_ns))
      .BindInt64(3, last.measurement_time_unix_ns)
      .BindInt64(4, start.measurement_time_unix_ns)
      .BindInt64(5, start.gyro_id)
      .BindInt64(6, start.row_id)
      .BindInt64(7, last.measurement_time_unix_ns)
      .BindInt64(8, last.gyro_id)
      .BindInt64(9, last.row_id);
  if (gyro_id != 0) values->BindInt64(10, gyro_id);
  RETURN_IF_ERROR(ReadValues(*values, ids, &page.records));
  values->Reset();
  return page;
}

}  // namespace esg::storage
