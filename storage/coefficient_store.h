// Histories of estimated gyro model coefficients (table coefficients, a row per estimate, and
// coefficient_values, a row per component keyed by its name in the layout of records.h: k0, C1,
// C2, mu, nu in deg/h, misalignment in arcsec; docs/physics.md, eq. (1), (8)-(10)), plus the
// conversions between that layout and the estimator's SI DriftCoefficients.
#ifndef ESG_STORAGE_COEFFICIENT_STORE_H_
#define ESG_STORAGE_COEFFICIENT_STORE_H_

#include <cstdint>
#include <optional>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "absl/types/span.h"
#include "estimator/drift_model.h"
#include "storage/records.h"
#include "storage/database.h"

namespace esg::storage {

// Estimator values -> the 16-value layout of records.h (SI, no conversion): drift [rad/s], then
// the misalignment rotation vector about body axes [rad]. Also right for 1-sigma values.
std::vector<double> ToCoefficientValues(const estimator::DriftCoefficients& drift,
                                        const Eigen::Vector3d& misalignment_b);
// The inverse. InvalidArgument unless values.size() == kNumCoefficientValues.
absl::Status FromCoefficientValues(absl::Span<const double> values,
                                   estimator::DriftCoefficients* drift,
                                   Eigen::Vector3d* misalignment_b);

// Position of a record in the history order (measurement_time, gyro_id, insertion): a page of a
// paged read continues strictly after it.
struct CoefficientCursor {
  int64_t measurement_time_unix_ns = 0;
  int64_t gyro_id = 0;
  int64_t row_id = 0;  // insertion order
};

struct CoefficientPage {
  std::vector<CoefficientRecord> records;
  // Cursor of the last record when more records follow in the range; nullopt on the last page.
  std::optional<CoefficientCursor> next;
};

// Thread-safe (through Database). Methods without a Transaction argument run in their own
// transaction; the overloads taking one join the caller's.
class CoefficientStore {
 public:
  explicit CoefficientStore(Database* db) : db_(db) {}

  // Appends one estimate. InvalidArgument (naming the field) if spacecraft_id or model_name is
  // empty, gyro_id < 1, values.size() != kNumCoefficientValues, sigmas is neither empty nor of
  // that size, or a time is not storable. NaN values are stored as NULL and read back as NaN;
  // empty sigmas are stored as NULLs, and sigmas that are all NULL read back as empty.
  absl::Status Append(const CoefficientRecord& record);
  absl::Status Append(Transaction& txn, const CoefficientRecord& record);

  // Estimates of the spacecraft with from <= measurement_time < to, for one gyro or for all
  // (gyro_id == 0), ordered by (measurement_time, gyro_id, insertion). Current estimates only,
  // unless include_revised (then also those a re-run over a late frame superseded, with their
  // revised_time).
  absl::StatusOr<std::vector<CoefficientRecord>> History(absl::string_view spacecraft_id,
                                                         int gyro_id, absl::Time from,
                                                         absl::Time to,
                                                         bool include_revised = false);

  // One page of History(spacecraft_id, gyro_id, from, to): up to `limit` (> 0, else
  // InvalidArgument naming limit) records strictly after `after` (nullopt: from the first), in
  // the same order. Reads limit + 1 rows to know whether more follow; the cost of a page does
  // not grow with its position (the index coefficients_by_time).
  absl::StatusOr<CoefficientPage> HistoryPage(absl::string_view spacecraft_id, int gyro_id,
                                              absl::Time from, absl::Time to,
                                              const std::optional<CoefficientCursor>& after,
                                              int64_t limit, bool include_revised = false);

 private:
  Database* db_;  // not owned
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_COEFFICIENT_STORE_H_
