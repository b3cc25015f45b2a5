// Live fan-out of alert changes (new alert, repeat, acknowledgement, clear) to SubscribeAlerts
// streams (docs/service.md "Alerts"). Publishers call Publish after the change is committed;
// a subscriber's callback runs under the hub's lock and must only queue the record. Every
// published change is also logged (LogAlert), so the log holds each alert's life.
#ifndef ESG_SERVER_ALERT_HUB_H_
#define ESG_SERVER_ALERT_HUB_H_

#include <cstdint>
#include <functional>
#include <map>
#include <string>

#include "absl/base/thread_annotations.h"
#include "absl/synchronization/mutex.h"
#include "storage/records.h"

namespace esg::server {

// One log line (server/log.h) for an alert state: spacecraft, sequence, severity, reason,
// subsystem, repeats, first..latest occurrence, acknowledgement and clearing, message. Level
// ERROR for an active DISTRESS or CRITICAL alert, WARN for an active WARNING, else INFO.
void LogAlert(const storage::AlertRecord& record);

class AlertHub {
 public:
  using Listener = std::function<void(const storage::AlertRecord&)>;
  using Closer = std::function<void()>;

  // spacecraft_id empty: every spacecraft. `close` is called by CloseAll (server shutdown).
  // Returns an id for Unsubscribe.
  int64_t Subscribe(std::string spacecraft_id, Listener listener, Closer close);
  // After it returns, the listener is never called again.
  void Unsubscribe(int64_t id);
  // Logs the record (LogAlert) unless !log (a change another server committed and logged) and
  // hands it to the matching subscribers.
  void Publish(const storage::AlertRecord& record, bool log = true);
  // Calls every subscriber's closer (they finish their streams).
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
  std::map<int64_t, Subscriber> subscribers_ ABSL_GUARDED_BY(mu_);
};

}  // namespace esg::server

#endif  // ESG_SERVER_ALERT_HUB_H_
