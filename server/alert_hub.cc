// The log line of an alert state (see alert_hub.h).
#include "server/alert_hub.h"

#include <string>

#include "absl/strings/str_cat.h"
#include "server/log.h"
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
  LogEvent(level, event,
           absl::StrCat("alert ", r.spacecraft_id, " #", r.sequence, " ", r.severity, " ",
                        r.reason, " ", r.subsystem, ", x", r.repeat_count, ", ",
                        FormatUtc(r.first_time), "..", FormatUtc(r.measurement_time), state, ": ",
                        r.message),
           {{"spacecraftId", r.spacecraft_id},
            {"alertSequence", r.sequence},
            {"severity", r.severity},
            {"reason", r.reason},
            {"subsystem", r.subsystem},
            {"repeatCount", r.repeat_count},
            {"firstTime", FormatUtc(r.first_time)},
            {"measurementTime", FormatUtc(r.measurement_time)}});
}

}  // namespace esg::server
