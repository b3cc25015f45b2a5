// The server's logger (see log.h).
#include "server/log.h"

#include <atomic>
#include <cstdio>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "estimator/utc_time.h"
#include "nlohmann/json.hpp"

namespace esg::server {
namespace {

std::atomic<LogFormat> log_format{LogFormat::kText};

std::string EscapeControl(absl::string_view message) {
  std::string text;
  text.reserve(message.size());
  for (const char c : message) {
    const unsigned char u = static_cast<unsigned char>(c);
    if (u < 0x20 || u == 0x7f) {
      text += absl::StrFormat("\\x%02x", u);
    } else {
      text += c;
    }
  }
  return text;
}

}  // namespace

std::string BoundedText(absl::string_view text, size_t max_bytes) {
  if (text.size() <= max_bytes) return std::string(text);
  size_t keep = max_bytes - 64;  // room for the marker
  // Back over UTF-8 continuation bytes (10xxxxxx) so that no character is split.
  while (keep > 0 && (static_cast<unsigned char>(text[keep]) & 0xC0) == 0x80) --keep;
  return absl::StrCat(text.substr(0, keep), " ... (", text.size() - keep, " bytes cut)");
}

void SetLogFormat(LogFormat format) { log_format.store(format); }
LogFormat GetLogFormat() { return log_format.load(); }

std::string FormatLogLine(LogFormat format, absl::string_view level, absl::string_view event,
                          absl::string_view full_message,
                          std::initializer_list<LogField> fields) {
  const std::string message = BoundedText(full_message, kMaxLogMessageBytes);
  const std::string ts = estimator::FormatUtc(absl::Now());
  if (format == LogFormat::kText) {
    return absl::StrCat(ts, " ", level, " esgd: ", EscapeControl(message), "\n");
  }
  nlohmann::ordered_json line;
  line["ts"] = ts;
  line["level"] = std::string(level);
  line["event"] = std::string(event);
  for (const LogField& f : fields) {
    std::visit([&](const auto& v) { line[f.key] = v; }, f.value);
  }
  line["message"] = message;
  return line.dump(-1, ' ', false, nlohmann::ordered_json::error_handler_t::replace) + "\n";
}

void LogEvent(absl::string_view level, absl::string_view event, absl::string_view message,
              std::initializer_list<LogField> fields) {
  const std::string line = FormatLogLine(GetLogFormat(), level, event, message, fields);
  std::fputs(line.c_str(), stderr);
}

}  // namespace esg::server
