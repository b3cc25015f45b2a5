// The one mapping from absl::Status to grpc::Status (STYLE §3.3 rule 3): the codes are numerically
// identical in both libraries and are converted explicitly; the message is passed through. No
// other file of the project builds a grpc::Status.
#ifndef ESG_SERVER_GRPC_STATUS_H_
#define ESG_SERVER_GRPC_STATUS_H_

#include "absl/status/status.h"
#include "grpcpp/support/status.h"

namespace esg::server {

// OK -> grpc::Status::OK; every other code -> the gRPC code of the same name with the message.
grpc::Status ToGrpcStatus(const absl::Status& status);

}  // namespace esg::server

#endif  // ESG_SERVER_GRPC_STATUS_H_
