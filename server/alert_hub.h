// Live fan-out of alert changes (new alert, repeat, acknowledgement, clear) to SubscribeAlerts
// streams (docs/service.md "Alerts"): a Hub (hub.h) of alert records. Publishers call Publish
// after the change is committed; a subscriber's callback runs under the hub's lock and must only
// queue the record. Every published change is also logged (LogAlert), so the log holds each
// alert's life.
#ifndef ESG_SERVER_ALERT_HUB_H_
#define ESG_SERVER_ALERT_HUB_H_

#include "server/hub.h"
#include "storage/records.h"

namespace esg::server {

// One log line (server/log.h) for an alert state: spacecraft, sequence, severity, reason,
// subsystem, repeats, first..latest occurrence, acknowledgement and clearing, message. Level
// ERROR for an active DISTRESS or CRITICAL alert, WARN for an active WARNING, else INFO.
void LogAlert(const storage::AlertRecord& record);

// A subscription started after CloseAll stays open.
class AlertHub : public Hub<storage::AlertRecord> {
 public:
  AlertHub() : Hub(AfterClose::kKeepNewSubscribers) {}

  // Logs the record (LogAlert) unless !log (a change another server committed and logged) and
  // hands it to the matching subscribers.
  void Publish(const storage::AlertRecord& record, bool log = true) {
    if (log) LogAlert(record);
    Hub::Publish(record);
  }
};

}  // namespace esg::server

#endif  // ESG_SERVER_ALERT_HUB_H_
