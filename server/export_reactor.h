// ExportReactor: the server-streaming export calls (ExportCoefficientHistory, ExportTelemetry).
//
// Export streams: `next` produces the next chunk (nullopt: the export is complete) on the callback
// thread, since a chunk is one bounded SQLite read (EstimationCore::kExportChunkSize records),
// like a unary list call. One write in flight: the next chunk is read only once the client took
// the previous one (gRPC flow control), so a slow client holds no more than one chunk. An error
// finishes the call with its status after the chunks already sent; a client that goes away
// ends it with CANCELLED.
#ifndef ESG_SERVER_EXPORT_REACTOR_H_
#define ESG_SERVER_EXPORT_REACTOR_H_

#include <functional>
#include <optional>
#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "grpcpp/support/server_callback.h"
#include "server/call_counter.h"
#include "server/grpc_status.h"

namespace esg::server {

template <typename Response>
class ExportReactor : public grpc::ServerWriteReactor<Response> {
 public:
  using Next = std::function<absl::StatusOr<std::optional<Response>>()>;
  ExportReactor(CallCounter* calls, const absl::Status& auth, Next next)
      : token_(calls), next_(std::move(next)) {
    if (!auth.ok()) {
      this->Finish(ToGrpcStatus(auth));
      return;
    }
    WriteNext();
  }

  void OnWriteDone(bool ok) override {
    if (!ok) {
      this->Finish(ToGrpcStatus(absl::CancelledError("the client went away")));
      return;
    }
    WriteNext();
  }

  void OnDone() override { delete this; }

 private:
  CallCounter::Token token_;
  void WriteNext() {
    absl::StatusOr<std::optional<Response>> chunk = next_();
    if (!chunk.ok()) {
      this->Finish(ToGrpcStatus(chunk.status()));
      return;
    }
    if (!chunk->has_value()) {
      this->Finish(ToGrpcStatus(absl::OkStatus()));
      return;
    }
    current_ = std::move(**chunk);
    this->StartWrite(&current_);
  }

  Next next_;
  Response current_;  // the chunk being written
};

}  // namespace esg::server

#endif  // ESG_SERVER_EXPORT_REACTOR_H_
