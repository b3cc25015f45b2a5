// ExportReactor: the server-streaming export calls (ExportCoefficientHistory, ExportTelemetry).
//
// Export streams: `next` produces the next chunk (nullopt: the export is complete) on the callback
// thread, since a chunk is one bounded SQLite read (EstimationCore::kExportChunkSize records),
// like a unary list call. One write in flight: the next chunk is read only once the client took
// the previous one (gRPC flow control), so a slow client holds no more than one chunk. An error
// finishes the call with its status after the chunks already sent; a client that goes away
// ends it with CANCELLED. The caller's export slot (CallLimiter) is held until the call is
// finished.
#ifndef ESG_SERVER_EXPORT_REACTOR_H_
#define ESG_SERVER_EXPORT_REACTOR_H_

#include <functional>
#include <optional>
#include <string>
#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "grpcpp/support/server_callback.h"
#include "server/call_counter.h"
#include "server/call_limiter.h"
#include "server/grpc_status.h"

namespace esg::server {

template <typename Response>
class ExportReactor : public grpc::ServerWriteReactor<Response> {
 public:
  using Next = std::function<absl::StatusOr<std::optional<Response>>()>;
  // `admitted`: the caller and its export slot, or the refusal the call finishes with at once.
  ExportReactor(CallCounter* calls,
                absl::StatusOr<std::pair<std::string, CallLimiter::Permit>> admitted, Next next)
      : token_(calls), next_(std::move(next)) {
    if (!admitted.ok()) {
      this->Finish(ToGrpcStatus(admitted.status()));
      return;
    }
    permit_ = std::move(admitted->second);
    WriteNext();
  }

  void OnWriteDone(bool ok) override {
    if (!ok) {
      FinishWith(absl::CancelledError("the client went away"));
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
      FinishWith(chunk.status());
      return;
    }
    if (!chunk->has_value()) {
      FinishWith(absl::OkStatus());
      return;
    }
    current_ = std::move(**chunk);
    this->StartWrite(&current_);
  }

  // The slot first: a client that starts its next export on the status is not refused.
  void FinishWith(const absl::Status& status) {
    permit_.Release();
    this->Finish(ToGrpcStatus(status));
  }

  Next next_;
  Response current_;  // the chunk being written
  CallLimiter::Permit permit_;
};

}  // namespace esg::server

#endif  // ESG_SERVER_EXPORT_REACTOR_H_
