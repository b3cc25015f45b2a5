// The one mapping from absl::Status to grpc::Status: the codes are numerically
// identical in both libraries and are converted explicitly; the message is passed through. No
// other file of the project builds a grpc::Status. A status may also ask for a retry delay, sent
// as the trailing metadata grpc-retry-pushback-ms (gRPC's retry design A6), which a client's
// retry policy waits for before its next attempt.
#ifndef ESG_SERVER_GRPC_STATUS_H_
#define ESG_SERVER_GRPC_STATUS_H_

#include <cstdint>
#include <optional>
#include <string>

#include "absl/status/status.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "grpcpp/server_context.h"
#include "grpcpp/support/status.h"

namespace esg::server {

// The longest message a status or an ack's rejection carries [bytes]. A message echoes values
// of the request; a 1 MB field echoed whole made gRPC answer RESOURCE_EXHAUSTED (metadata too
// large) in place of the INVALID_ARGUMENT naming the field.
inline constexpr size_t kMaxStatusMessageBytes = 1024;

// BoundedText(message, kMaxStatusMessageBytes) (log.h): the head of a longer message, cut at a
// character boundary, and " ... (N bytes cut)".
std::string BoundedMessage(absl::string_view message);

// OK -> grpc::Status::OK; every other code -> the gRPC code of the same name with the message,
// bounded by BoundedMessage.
grpc::Status ToGrpcStatus(const absl::Status& status);

// The trailing metadata key a retry delay travels in: milliseconds, a non-negative integer.
inline constexpr char kRetryPushbackKey[] = "grpc-retry-pushback-ms";

// `status` (not OK) marked as worth retrying after `delay`, rounded up to whole milliseconds
// (a negative delay counts as 0). Returned as is when OK.
absl::Status WithRetryDelay(absl::Status status, absl::Duration delay);

// The retry delay WithRetryDelay put on `status`, in whole milliseconds (>= 0); nullopt when it
// has none. A refused telemetry frame carries it in its ack (Rejection.retry_after_ms).
std::optional<int64_t> RetryDelayMs(const absl::Status& status);

// ToGrpcStatus(status), after adding to `context`'s trailing metadata the retry delay that
// WithRetryDelay put on `status`, if any. Call it right before the call's Finish.
grpc::Status ToGrpcStatus(const absl::Status& status, grpc::ServerContextBase& context);

}  // namespace esg::server

#endif  // ESG_SERVER_GRPC_STATUS_H_
