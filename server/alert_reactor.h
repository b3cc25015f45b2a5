// The SubscribeAlerts reactor: replay, end-of-replay marker and live alerts merged.
//
// Subscribes to the live feed first, then replays the store, then releases the live alerts that
// arrived meanwhile, then (replay_marker) queues the end-of-replay marker; every alert state
// (sequence, repeat_count, acknowledged, cleared) is sent at most once and never after a newer
// state of the same alert. Live alerts published after the marker was queued follow it.
#ifndef ESG_SERVER_ALERT_REACTOR_H_
#define ESG_SERVER_ALERT_REACTOR_H_

#include "absl/status/status.h"
#include "esg/v1/attitude.pb.h"
#include "esg/v1/estimation_service.pb.h"
#include "grpcpp/support/server_callback.h"
#include "server/call_counter.h"
#include "server/estimation_core.h"
#include "server/queue_budget.h"

namespace esg::server {

// `hold` not OK (the role, the routing scope or the caller's subscription slot refused): the
// stream finishes at once with its status.
grpc::ServerWriteReactor<esg::v1::Alert>* NewAlertReactor(CallCounter* calls, EstimationCore* core,
                                                          const esg::v1::AlertSubscription& request,
                                                          absl::StatusOr<SubscriptionHold> hold);

}  // namespace esg::server

#endif  // ESG_SERVER_ALERT_REACTOR_H_
