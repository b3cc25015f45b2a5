// Live fan-out of per-step estimates (docs/service.md "Per-step estimates") to SubscribeEstimates
// streams. The apply worker publishes a job's estimates after the transaction that stores them
// has committed, in measurement-time order; a re-run publishes the steps it recomputed again.
// A subscriber's listener runs under the hub's lock and must only queue the record.
#ifndef ESG_SERVER_ESTIMATE_HUB_H_
#define ESG_SERVER_ESTIMATE_HUB_H_

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/synchronization/mutex.h"
#include "storage/records.h"

namespace esg::server {

class EstimateHub {
 public:
  using Listener = std::function<void(const storage::EstimateRecord&)>;
  using Closer = std::function<void()>;

  // spacecraft_id empty: every spacecraft. `close` is called by CloseAll (server shutdown), or
  // at once (after registering) when the hub is already closed, so that no subscription started
  // during shutdown stays open. Returns an id for Unsubscribe.
  int64_t Subscribe(std::string spacecraft_id, Listener listener, Closer close);
  // After it returns, the listener is never called again.
  void Unsubscribe(int64_t id);
  // Hands each record, in order, to the matching subscribers.
  void Publish(const std::vector<storage::EstimateRecord>& records);
  // Calls every subscriber's closer (they finish their streams); later subscriptions are closed
  // as they come.
  void CloseAll();
  // Number of subscribers.
  int size();

 private:
  struct Subscriber {
    std::string spacecraft_id;
    Listener listener;
    Closer close;
  };
  absl::Mutex mu_;
  int64_t next_id_ ABSL_GUARDED_BY(mu_) = 1;
  bool closed_ ABSL_GUARDED_BY(mu_) = false;
  std::map<int64_t, Subscriber> subscribers_ ABSL_GUARDED_BY(mu_);
};

}  // namespace esg::server

#endif  // ESG_SERVER_ESTIMATE_HUB_H_
