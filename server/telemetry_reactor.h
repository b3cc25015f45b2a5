// The StreamTelemetry reactor (bidi: frames in, acks out).
//
// Acks leave in frame order; an ack waiting for durability holds back the ones behind it. At
// most kMaxInFlight frames are waiting for their ack before the stream stops reading (flow
// control back to the client).
#ifndef ESG_SERVER_TELEMETRY_REACTOR_H_
#define ESG_SERVER_TELEMETRY_REACTOR_H_

#include <string>

#include "absl/status/status.h"
#include "esg/v1/estimation_service.pb.h"
#include "esg/v1/telemetry.pb.h"
#include "grpcpp/support/server_callback.h"
#include "server/call_counter.h"
#include "server/estimation_core.h"

namespace esg::server {

// `scope`: the spacecraft the stream is routed by (server/spacecraft_scope.h), or empty. `auth`
// not OK: the stream finishes at once with it. When ingest closes (EstimationCore::CloseIngest,
// the first step of a shutdown) the stream stops reading, sends the acks of the frames it has
// queued once they are committed, and finishes with UNAVAILABLE and a retry delay (trailing
// metadata grpc-retry-pushback-ms, on `context`).
grpc::ServerBidiReactor<esg::v1::TelemetryFrame, esg::v1::TelemetryAck>* NewTelemetryReactor(
    grpc::CallbackServerContext* context, CallCounter* calls, EstimationCore* core,
    const absl::Status& auth, std::string peer, std::string scope);

}  // namespace esg::server

#endif  // ESG_SERVER_TELEMETRY_REACTOR_H_
