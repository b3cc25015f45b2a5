// RETURN_IF_ERROR / ASSIGN_OR_RETURN with Abseil's semantics (absent from Abseil 20220623).
#ifndef ESG_ESTIMATOR_STATUS_MACROS_H_
#define ESG_ESTIMATOR_STATUS_MACROS_H_

#include "absl/status/status.h"
#include "absl/status/statusor.h"

#define ESG_STATUS_CONCAT_INNER_(a, b) a##b
#define ESG_STATUS_CONCAT_(a, b) ESG_STATUS_CONCAT_INNER_(a, b)

#define RETURN_IF_ERROR(expr)                         \
  do {                                                \
    ::absl::Status esg_status_tmp_ = (expr);          \
    if (!esg_status_tmp_.ok()) return esg_status_tmp_; \
  } while (0)

#define ASSIGN_OR_RETURN(lhs, expr) \
  ESG_ASSIGN_OR_RETURN_IMPL_(ESG_STATUS_CONCAT_(esg_statusor_, __LINE__), lhs, expr)

#define ESG_ASSIGN_OR_RETURN_IMPL_(statusor, lhs, expr) \
  auto statusor = (expr);                               \
  if (!statusor.ok()) return statusor.status();         \
  lhs = std::move(statusor).value()

#endif  // ESG_ESTIMATOR_STATUS_MACROS_H_
