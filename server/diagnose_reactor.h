// The Diagnose reactor (server streaming: progress updates, then the result).
//
// Diagnose: the diagnosis runs on its own thread (it takes seconds; gRPC threads must not
// block). Progress updates are coalesced: at most one write in flight, the newest update waiting.
// The final update carries the result; an error finishes the call with its status. When the
// call is cancelled (the client went away, its deadline passed, the server shuts down) or a
// write fails, the diagnosis is told through its cancellation predicate, stops at its next
// check and stores nothing; the call then finishes with CANCELLED. The permit (the caller's
// diagnosis slot) is given back as soon as the worker is done.
#ifndef ESG_SERVER_DIAGNOSE_REACTOR_H_
#define ESG_SERVER_DIAGNOSE_REACTOR_H_

#include "absl/status/statusor.h"
#include "esg/v1/estimation_service.pb.h"
#include "grpcpp/server_context.h"
#include "grpcpp/support/server_callback.h"
#include "server/call_counter.h"
#include "server/call_limiter.h"
#include "server/estimation_core.h"

namespace esg::server {

// `permit` holds the caller's slot, or why the call is refused (role, limit). `context` is the
// call's (for the retry delay of a refusal, grpc_status.h).
grpc::ServerWriteReactor<esg::v1::DiagnoseUpdate>* NewDiagnoseReactor(
    CallCounter* calls, grpc::CallbackServerContext* context, EstimationCore* core,
    esg::v1::DiagnoseRequest request, absl::StatusOr<CallLimiter::Permit> permit);

}  // namespace esg::server

#endif  // ESG_SERVER_DIAGNOSE_REACTOR_H_
