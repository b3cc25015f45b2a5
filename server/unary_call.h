// Unary calls of the esg.v1.EstimationService: the reactor that counts the call, and Unary, which
// runs the call's work on the callback thread once the caller is authorized.
#ifndef ESG_SERVER_UNARY_CALL_H_
#define ESG_SERVER_UNARY_CALL_H_

#include <cstdint>
#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "grpcpp/support/server_callback.h"
#include "server/call_counter.h"
#include "server/grpc_status.h"
#include "server/memory_release.h"

namespace esg::server {

// The reactor of a unary call: counted until gRPC is done with the call (its response sent).
class UnaryReactor : public grpc::ServerUnaryReactor {
 public:
  explicit UnaryReactor(CallCounter* calls) : token_(calls) {}
  // Before Finish: the response's size, noted as freed (memory_release.h) once gRPC is done
  // with the call, which frees the response then.
  void FreesOnDone(int64_t bytes) { freed_on_done_ = bytes; }
  void OnDone() override {
    NoteFreedMemory(freed_on_done_);
    delete this;
  }

 private:
  CallCounter::Token token_;
  int64_t freed_on_done_ = 0;
};

// Unary rpcs: run `work` (returning absl::StatusOr<Response>) and finish (with the retry delay
// the status asks for in `context`'s trailing metadata).
template <typename Response, typename Work>
grpc::ServerUnaryReactor* Unary(CallCounter* calls, grpc::CallbackServerContext* context,
                                absl::Status auth, Response* response, Work work) {
  grpc::ServerUnaryReactor* reactor = new UnaryReactor(calls);
  if (!auth.ok()) {
    reactor->Finish(ToGrpcStatus(auth));
    return reactor;
  }
  absl::StatusOr<Response> result = work();
  if (result.ok()) *response = std::move(*result);
  reactor->Finish(ToGrpcStatus(result.status(), *context));
  return reactor;
}

}  // namespace esg::server

#endif  // ESG_SERVER_UNARY_CALL_H_
