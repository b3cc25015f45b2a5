// The log line of an alert state (see alert_hub.h).
#include "server/alert_hub.h"

#include <initializer_list>
#include <string>

#include "absl/strings/str_cat.h"
#include "server/log.h"
#include "server/log_throttle.h"
#include "server/proto_mapping.h"

namespace esg::server {

void LogAlert(const storage::AlertRecord& r) {
  std::string state;
  if (r.acknowledged) {
    absl::StrAppend(&state, ", acknowledged by ", r.acknowledged_by, " at ",
                    FormatUtc(r.acknowledged_time));
  }
  if (r.cleared) {
    absl::StrAppend(&state, ", cleared",
                    r.cleared_time != absl::InfinitePast()
                        ? absl::StrCat(" at ", FormatUtc(r.cleared_time))
                        : std::string());
  }
  // The log level follows the severity while the alert is active; a cleared one is news only.
  const char* level = r.cleared                                             ? "INFO"
                      : r.severity == "CRITICAL" || r.severity == "DISTRESS" ? "ERROR"
                      : r.severity == "WARNING"                             ? "WARN"
                                                                            : "INFO";
  // event: alert_raised (first occurrence), alert_repeated, alert_acknowledged, alert_cleared.
  const char* event = r.cleared             ? "alert_cleared"
                      : r.acknowledged      ? "alert_acknowledged"
                      : r.repeat_count > 1 ? "alert_repeated"
                                            : "alert_raised";
  const std::string message =
      absl::StrCat("alert ", r.spacecraft_id, " #", r.sequence, " ", r.severity, " ", r.reason, " ",
                   r.subsystem, ", x", r.repeat_count, ", ", FormatUtc(r.first_time), "..",
                   FormatUtc(r.measurement_time), state, ": ", r.message);
  const std::initializer_list<LogField> fields = {
      {"spacecraftId", r.spacecraft_id},
      {"alertSequence", r.sequence},
      {"severity", r.severity},
      {"reason", r.reason},
      {"subsystem", r.subsystem},
      {"repeatCount", r.repeat_count},
      {"firstTime", FormatUtc(r.first_time)},
      {"measurementTime", FormatUtc(r.measurement_time)}};
  // Repeats are throttled per alert (server/log_throttle.h): a client sending conflicting frames
  // repeats INGEST_CONFLICT with every apply job (778 lines in 60 s were measured). Subscribers
  // still receive every state; the first line, acknowledgement and clearing are always logged.
  if (r.repeat_count > 1 && !r.cleared && !r.acknowledged) {
    static LogThrottle* const repeats = new LogThrottle("alert_repeated");
    repeats->Log(absl::StrCat("alert ", r.spacecraft_id, " #", r.sequence), level, message, fields);
    return;
  }
  LogEvent(level, event, message, fields);
}

}  // namespace esg::server
