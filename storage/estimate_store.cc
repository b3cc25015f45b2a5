// The per-step estimate archive; contract in estimate_store.h, columns in schema.cc (versions 7
// and 9).
#include "storage/estimate_store.h"

#include <cmath>
#include <limits>
#include <string>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

constexpr int kMaxGyroId = 4;

// Leading columns (0-based in a SELECT, ?1.. in the INSERT), then per gyro id 1..4 the
// innovation's two components and their two sigmas, then the attitude error estimate about body
// x, y, z and its 1-sigma (version 9).
constexpr char kColumns[] =
    "spacecraft_id, measurement_time_unix_ns, compute_time_unix_ns, state, attitude_valid, "
    "q0, q1, q2, q3, sigma_x_arcsec, sigma_y_arcsec, sigma_z_arcsec, "
    "output_reference_gyro_id, output_second_gyro_id, attitude_invalid_reason, "
    "star_tracker_used, star_tracker_test_ratio, last_star_tracker_time_unix_ns, "
    "innovation_gyro_order, "
    "innovation_g1_1_arcsec, innovation_g1_2_arcsec, "
    "innovation_sigma_g1_1_arcsec, innovation_sigma_g1_2_arcsec, "
    "innovation_g2_1_arcsec, innovation_g2_2_arcsec, "
    "innovation_sigma_g2_1_arcsec, innovation_sigma_g2_2_arcsec, "
    "innovation_g3_1_arcsec, innovation_g3_2_arcsec, "
    "innovation_sigma_g3_1_arcsec, innovation_sigma_g3_2_arcsec, "
    "innovation_g4_1_arcsec, innovation_g4_2_arcsec, "
    "innovation_sigma_g4_1_arcsec, innovation_sigma_g4_2_arcsec, "
    "attitude_error_x_arcsec, attitude_error_y_arcsec, attitude_error_z_arcsec, "
    "attitude_error_sigma_x_arcsec, attitude_error_sigma_y_arcsec, "
    "attitude_error_sigma_z_arcsec";
constexpr int kSpacecraftColumn = 0;
constexpr int kTimeColumn = 1;
constexpr int kComputeColumn = 2;
constexpr int kStateColumn = 3;
constexpr int kValidColumn = 4;
constexpr int kQColumn = 5;
constexpr int kSigmaColumn = 9;
constexpr int kPairColumn = 12;
constexpr int kInvalidReasonColumn = 14;
constexpr int kUsedColumn = 15;
constexpr int kRatioColumn = 16;
constexpr int kLastStarTrackerColumn = 17;
constexpr int kOrderColumn = 18;
constexpr int kInnovationColumn = 19;  // gyro g's four columns start at 19 + 4 (g - 1)
constexpr int kAttitudeErrorColumn = kInnovationColumn + 4 * kMaxGyroId;
constexpr int kAttitudeErrorSigmaColumn = kAttitudeErrorColumn + 3;
constexpr int kNumColumns = kAttitudeErrorSigmaColumn + 3;

const std::string& InsertSql() {
  static const std::string* const sql = [] {
    std::string params;
    for (int i = 1; i <= kNumColumns; ++i) absl::StrAppend(&params, i == 1 ? "" : ", ", "?", i);
    // Every column but the key (spacecraft_id, measurement_time_unix_ns) is replaced.
    std::string updates;
    for (absl::string_view column : absl::StrSplit(kColumns, ',', absl::SkipWhitespace())) {
      column = absl::StripAsciiWhitespace(column);
      if (column == "spacecraft_id" || column == "measurement_time_unix_ns") continue;
      absl::StrAppend(&updates, updates.empty() ? "" : ", ", column, " = excluded.", column);
    }
    return new std::string(absl::StrCat("INSERT INTO estimates (", kColumns, ") VALUES (", params,
                                        ") ON CONFLICT (spacecraft_id, measurement_time_unix_ns) "
                                        "DO UPDATE SET ",
                                        updates));
  }();
  return *sql;
}

// ?1 spacecraft, [?2, ?3) time span, ?4 after (exclusive), ?5 limit.
const std::string& PageSql() {
  static const std::string* const sql = new std::string(
      absl::StrCat("SELECT ", kColumns,
                   " FROM estimates WHERE spacecraft_id = ?1 AND measurement_time_unix_ns >= ?2 "
                   "AND measurement_time_unix_ns < ?3 AND measurement_time_unix_ns > ?4 "
                   "ORDER BY measurement_time_unix_ns LIMIT ?5"));
  return *sql;
}

absl::Status Validate(const EstimateRecord& r) {
  RETURN_IF_ERROR(ValidateSpacecraftId(r.spacecraft_id, "estimates.spacecraft_id"));
  if (r.state.empty()) return absl::InvalidArgumentError("estimates.state: empty");
  RETURN_IF_ERROR(ValidateStorableTime(r.measurement_time, "estimates.measurement_time"));
  RETURN_IF_ERROR(ValidateStorableTime(r.compute_time, "estimates.compute_time"));
  if (r.last_star_tracker_time != absl::InfinitePast()) {
    RETURN_IF_ERROR(
        ValidateStorableTime(r.last_star_tracker_time, "estimates.last_star_tracker_time"));
  }
  if (r.attitude_valid) {
    for (double v : r.q_in_b) {
      if (!std::isfinite(v)) return absl::InvalidArgumentError("estimates.q_in_b: not finite");
    }
    for (double v : r.sigma_b) {
      if (!std::isfinite(v)) return absl::InvalidArgumentError("estimates.sigma_b: not finite");
    }
    for (int id : r.output_pair) {
      if (id < 1 || id > kMaxGyroId) {
        return absl::InvalidArgumentError(
            absl::StrCat("estimates.output_pair: gyro id ", id, " outside 1..4"));
      }
    }
  }
  bool seen[kMaxGyroId + 1] = {};
  for (size_t i = 0; i < r.star_tracker_innovations.size(); ++i) {
    const int id = r.star_tracker_innovations[i].gyro_id;
    if (id < 1 || id > kMaxGyroId || seen[id]) {
      return absl::InvalidArgumentError(absl::StrCat("estimates.star_tracker_innovations[", i,
                                                     "].gyro_id = ", id,
                                                     ": must be 1..4 and not repeated"));
    }
    seen[id] = true;
  }
  if (r.has_attitude_error) {
    for (size_t k = 0; k < 3; ++k) {
      if (!std::isfinite(r.attitude_error_b[k])) {
        return absl::InvalidArgumentError(
            absl::StrCat("estimates.attitude_error_b[", k, "]: not finite"));
      }
      if (!std::isfinite(r.attitude_error_sigma_b[k]) || r.attitude_error_sigma_b[k] < 0.0) {
        return absl::InvalidArgumentError(absl::StrCat("estimates.attitude_error_sigma_b[", k,
                                                       "] = ", r.attitude_error_sigma_b[k],
                                                       ": must be finite and >= 0"));
      }
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<EstimateRecord> ReadRecord(const Statement& st) {
  EstimateRecord r;
  r.spacecraft_id = st.ColumnText(kSpacecraftColumn);
  r.measurement_time = UnixNanosToTime(st.ColumnInt64(kTimeColumn));
  r.compute_time = UnixNanosToTime(st.ColumnInt64(kComputeColumn));
  r.state = st.ColumnText(kStateColumn);
  r.attitude_valid = st.ColumnInt64(kValidColumn) != 0;
  if (r.attitude_valid) {
    for (int i = 0; i < 4; ++i) r.q_in_b[i] = st.ColumnDoubleOrNaN(kQColumn + i);
    for (int i = 0; i < 3; ++i) {
      r.sigma_b[i] = estimator::ArcsecToRad(st.ColumnDoubleOrNaN(kSigmaColumn + i));
    }
    for (int i = 0; i < 2; ++i)
      r.output_pair[i] = static_cast<int>(st.ColumnInt64(kPairColumn + i));
  }
  r.attitude_invalid_reason = st.ColumnText(kInvalidReasonColumn);
  r.star_tracker_used = st.ColumnInt64(kUsedColumn) != 0;
  r.star_tracker_test_ratio = st.ColumnDoubleOrNaN(kRatioColumn);
  if (!st.ColumnIsNull(kLastStarTrackerColumn)) {
    r.last_star_tracker_time = UnixNanosToTime(st.ColumnInt64(kLastStarTrackerColumn));
  }
  if (!st.ColumnIsNull(kOrderColumn)) {
    for (absl::string_view part : absl::StrSplit(st.ColumnText(kOrderColumn), ',')) {
      int id = 0;
      if (!absl::SimpleAtoi(part, &id) || id < 1 || id > kMaxGyroId) {
        return absl::DataLossError(absl::StrCat("estimates of '", r.spacecraft_id,
                                                "': innovation_gyro_order '",
                                                st.ColumnText(kOrderColumn), "' is not gyro ids"));
      }
      const int first = kInnovationColumn + 4 * (id - 1);
      if (st.ColumnIsNull(first)) {
        return absl::DataLossError(absl::StrCat("estimates of '", r.spacecraft_id,
                                                "': innovation of gyro ", id, " missing"));
      }
      GyroInnovationRecord g;
      g.gyro_id = id;
      for (int k = 0; k < 2; ++k) {
        g.innovation[k] = estimator::ArcsecToRad(st.ColumnDoubleOrNaN(first + k));
        g.sigma[k] = estimator::ArcsecToRad(st.ColumnDoubleOrNaN(first + 2 + k));
      }
      r.star_tracker_innovations.push_back(g);
    }
  }
  // The six columns are written together; a row from before version 9 has none.
  r.has_attitude_error = !st.ColumnIsNull(kAttitudeErrorColumn);
  if (r.has_attitude_error) {
    for (int k = 0; k < 3; ++k) {
      r.attitude_error_b[k] =
          estimator::ArcsecToRad(st.ColumnDoubleOrNaN(kAttitudeErrorColumn + k));
      r.attitude_error_sigma_b[k] =
          estimator::ArcsecToRad(st.ColumnDoubleOrNaN(kAttitudeErrorSigmaColumn + k));
    }
  }
  return r;
}

// The row-count statement `sql` (?1 spacecraft, ?2 bound) in `txn`; returns the rows changed.
absl::StatusOr<int64_t> RunDelete(Transaction& txn, const char* sql,
                                  absl::string_view spacecraft_id, int64_t bound) {
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(sql));
  st->BindText(1, spacecraft_id).BindInt64(2, bound);
  RETURN_IF_ERROR(st->Run());
  return txn.ChangedRows();
}

}  // namespace

absl::Status EstimateStore::Put(const EstimateRecord& record) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  RETURN_IF_ERROR(Put(txn, record));
  return txn.Commit();
}

absl::Status EstimateStore::Put(Transaction& txn, const EstimateRecord& r) {
  RETURN_IF_ERROR(Validate(r));
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(InsertSql()));
  // Parameters are 1-based: column c binds ?c+1.
  st->BindText(kSpacecraftColumn + 1, r.spacecraft_id)
      .BindInt64(kTimeColumn + 1, TimeToUnixNanos(r.measurement_time))
      .BindInt64(kComputeColumn + 1, TimeToUnixNanos(r.compute_time))
      .BindText(kStateColumn + 1, r.state)
      .BindInt64(kValidColumn + 1, r.attitude_valid ? 1 : 0)
      .BindText(kInvalidReasonColumn + 1, r.attitude_invalid_reason)
      .BindInt64(kUsedColumn + 1, r.star_tracker_used ? 1 : 0)
      .BindDouble(kRatioColumn + 1, r.star_tracker_test_ratio);
  for (int i = 0; i < 4; ++i) {
    if (r.attitude_valid) {
      st->BindDouble(kQColumn + 1 + i, r.q_in_b[i]);
    } else {
      st->BindNull(kQColumn + 1 + i);
    }
  }
  for (int i = 0; i < 3; ++i) {
    if (r.attitude_valid) {
      st->BindDouble(kSigmaColumn + 1 + i, estimator::RadToArcsec(r.sigma_b[i]));
    } else {
      st->BindNull(kSigmaColumn + 1 + i);
    }
  }
  for (int i = 0; i < 2; ++i) {
    if (r.attitude_valid) {
      st->BindInt64(kPairColumn + 1 + i, r.output_pair[i]);
    } else {
      st->BindNull(kPairColumn + 1 + i);
    }
  }
  if (r.last_star_tracker_time == absl::InfinitePast()) {
    st->BindNull(kLastStarTrackerColumn + 1);
  } else {
    st->BindInt64(kLastStarTrackerColumn + 1, TimeToUnixNanos(r.last_star_tracker_time));
  }
  for (int c = kInnovationColumn; c < kNumColumns; ++c) st->BindNull(c + 1);
  if (r.has_attitude_error) {
    for (int k = 0; k < 3; ++k) {
      st->BindDouble(kAttitudeErrorColumn + 1 + k, estimator::RadToArcsec(r.attitude_error_b[k]));
      st->BindDouble(kAttitudeErrorSigmaColumn + 1 + k,
                     estimator::RadToArcsec(r.attitude_error_sigma_b[k]));
    }
  }
  if (r.star_tracker_innovations.empty()) {
    st->BindNull(kOrderColumn + 1);
  } else {
    std::string order;
    for (const GyroInnovationRecord& g : r.star_tracker_innovations) {
      absl::StrAppend(&order, order.empty() ? "" : ",", g.gyro_id);
      const int first = kInnovationColumn + 4 * (g.gyro_id - 1) + 1;
      for (int k = 0; k < 2; ++k) {
        st->BindDouble(first + k, estimator::RadToArcsec(g.innovation[k]));
        st->BindDouble(first + 2 + k, estimator::RadToArcsec(g.sigma[k]));
      }
    }
    st->BindText(kOrderColumn + 1, order);
  }
  return st->Run();
}

absl::StatusOr<int64_t> EstimateStore::DeleteAfter(Transaction& txn,
                                                   absl::string_view spacecraft_id,
                                                   absl::Time after) {
  const int64_t bound =
      after == absl::InfinitePast() ? std::numeric_limits<int64_t>::min() : TimeToUnixNanos(after);
  return RunDelete(txn,
                   "DELETE FROM estimates WHERE spacecraft_id = ?1 "
                   "AND measurement_time_unix_ns > ?2",
                   spacecraft_id, bound);
}

absl::StatusOr<int64_t> EstimateStore::DeleteBefore(Transaction& txn,
                                                    absl::string_view spacecraft_id,
                                                    absl::Time before) {
  return RunDelete(txn,
                   "DELETE FROM estimates WHERE spacecraft_id = ?1 "
                   "AND measurement_time_unix_ns < ?2",
                   spacecraft_id, TimeToUnixNanos(before));
}

absl::StatusOr<EstimatePage> EstimateStore::Page(absl::string_view spacecraft_id, absl::Time from,
                                                 absl::Time to,
                                                 const std::optional<absl::Time>& after,
                                                 int64_t limit) {
  if (limit <= 0) {
    return absl::InvalidArgumentError(absl::StrCat("limit = ", limit, ": must be positive"));
  }
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(PageSql()));
  st->BindText(1, spacecraft_id)
      .BindInt64(2, TimeToUnixNanos(from))
      .BindInt64(3, TimeToUnixNanos(to))
      .BindInt64(4,
                 after.has_value() ? TimeToUnixNanos(*after) : std::numeric_limits<int64_t>::min())
      .BindInt64(5, limit + 1);
  EstimatePage page;
  while (true) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    if (static_cast<int64_t>(page.records.size()) == limit) {
      page.next = page.records.back().measurement_time;  // a row beyond the page exists
      break;
    }
    ASSIGN_OR_RETURN(EstimateRecord r, ReadRecord(*st));
    page.records.push_back(std::move(r));
  }
  return page;
}

absl::StatusOr<int64_t> EstimateStore::Count(absl::string_view spacecraft_id, absl::Time from,
                                             absl::Time to) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT COUNT(*) FROM estimates WHERE spacecraft_id = ?1 "
                               "AND measurement_time_unix_ns >= ?2 "
                               "AND measurement_time_unix_ns < ?3"));
  st->BindText(1, spacecraft_id)
      .BindInt64(2, TimeToUnixNanos(from))
      .BindInt64(3, TimeToUnixNanos(to));
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return absl::InternalError("COUNT(*) returned no row");
  return st->ColumnInt64(0);
}

}  // namespace esg::storage
