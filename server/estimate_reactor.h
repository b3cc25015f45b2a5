// The SubscribeEstimates reactor: paged replay, end-of-replay marker and live estimates merged.
//
// Subscribes to the live feed first, then replays the stored estimates at or after `since` (per
// spacecraft in id order, each in measurement-time order) one page at a time, reading the next
// page only once the previous one is written (a slow client holds at most a page of the replay),
// then releases the live estimates that arrived meanwhile, then (replay_marker) queues the
// end-of-replay marker. Replay and live are merged without gap (everything committed before the
// subscription is stored, everything committed after is published to it) or duplicate: until
// the live estimates buffered during the replay are released, a record is queued only if no
// record of the same (spacecraft, measurement time) with the same or a later compute time was
// (a re-run's recomputed step has a later compute time, so it still goes out). Afterwards live
// estimates are queued as published. A subscriber with kMaxQueuedEstimates live estimates
// waiting is finished with RESOURCE_EXHAUSTED, as slow alert subscribers are.
#ifndef ESG_SERVER_ESTIMATE_REACTOR_H_
#define ESG_SERVER_ESTIMATE_REACTOR_H_

#include "absl/status/status.h"
#include "esg/v1/estimation_service.pb.h"
#include "grpcpp/support/server_callback.h"
#include "server/call_counter.h"
#include "server/estimation_core.h"
#include "server/queue_budget.h"

namespace esg::server {

// `hold` not OK (the role, the routing scope or the caller's subscription slot refused): the
// stream finishes at once with its status.
grpc::ServerWriteReactor<esg::v1::EstimateRecord>* NewEstimateReactor(
    CallCounter* calls, EstimationCore* core, const esg::v1::EstimateSubscription& request,
    absl::StatusOr<SubscriptionHold> hold);

}  // namespace esg::server

#endif  // ESG_SERVER_ESTIMATE_REACTOR_H_
