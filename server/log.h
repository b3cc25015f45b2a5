// The server's logger: one line per event on stderr, as text
// (`2019-03-01T00:00:00.000Z INFO esgd: message`) or as one JSON object a line (`--log-format
// json`: ts, level, event, message and the event's fields, e.g. spacecraftId). docs/service.md
// "Logs" lists the events. estimator/ and storage/ never log; only server/ does.
#ifndef ESG_SERVER_LOG_H_
#define ESG_SERVER_LOG_H_

#include <cstddef>
#include <cstdint>
#include <initializer_list>
#include <string>
#include <variant>

#include "absl/strings/string_view.h"

namespace esg::server {

enum class LogFormat { kText, kJson };

// Process-wide; set once at start (main.cc) before other threads log. Text by default.
void SetLogFormat(LogFormat format);
LogFormat GetLogFormat();

// One field of a structured line: a string, an integer, a number or a flag.
struct LogField {
  LogField(absl::string_view k, absl::string_view v) : key(k), value(std::string(v)) {}
  LogField(absl::string_view k, const std::string& v) : key(k), value(v) {}
  LogField(absl::string_view k, const char* v) : key(k), value(std::string(v)) {}
  LogField(absl::string_view k, int v) : key(k), value(int64_t{v}) {}
  LogField(absl::string_view k, long v) : key(k), value(int64_t{v}) {}            // NOLINT
  LogField(absl::string_view k, long long v) : key(k), value(int64_t{v}) {}       // NOLINT
  LogField(absl::string_view k, double v) : key(k), value(v) {}
  LogField(absl::string_view k, bool v) : key(k), value(v) {}
  std::string key;
  std::variant<std::string, int64_t, double, bool> value;
};

// Writes one line. `level`: INFO, WARN or ERROR. `event`: a stable snake_case name an operator
// can filter on (docs/service.md "Logs"). `message`: the human text (the whole line in the text
// format). Text: control characters (C0 and DEL) in the message are written as \xNN escapes, so
// no client-supplied id can forge a line or send escape sequences to a terminal. JSON: every
// string is JSON-escaped (invalid UTF-8 replaced by U+FFFD), one object per line. Thread-safe.
void LogEvent(absl::string_view level, absl::string_view event, absl::string_view message,
              std::initializer_list<LogField> fields = {});

// The longest message a log line carries [bytes]; a longer one (a client's value quoted whole by
// an error) is cut by BoundedText.
inline constexpr size_t kMaxLogMessageBytes = 4096;

// `text` when it has at most `max_bytes` bytes; else its head, cut at a UTF-8 character boundary,
// and " ... (N bytes cut)", the whole at most `max_bytes` (max_bytes >= 64).
std::string BoundedText(absl::string_view text, size_t max_bytes);

// The text of one line without writing it (tests); the message bounded by kMaxLogMessageBytes.
std::string FormatLogLine(LogFormat format, absl::string_view level, absl::string_view event,
                          absl::string_view message, std::initializer_list<LogField> fields);

}  // namespace esg::server

#endif  // ESG_SERVER_LOG_H_
