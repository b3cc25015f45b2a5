// Live fan-out of per-step estimates (docs/service.md "Per-step estimates") to SubscribeEstimates
// streams: a Hub (hub.h) of estimate records. The apply worker publishes a job's estimates after
// the transaction that stores them has committed, in measurement-time order; a re-run publishes
// the steps it recomputed again. A subscription started after CloseAll is closed at once.
#ifndef ESG_SERVER_ESTIMATE_HUB_H_
#define ESG_SERVER_ESTIMATE_HUB_H_

#include "server/hub.h"
#include "storage/records.h"

namespace esg::server {

using EstimateHub = Hub<storage::EstimateRecord>;

}  // namespace esg::server

#endif  // ESG_SERVER_ESTIMATE_HUB_H_
