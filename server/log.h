// The server's thin logger (STYLE §3.3 rule 8): one line per message on stderr with a UTC
// timestamp and a level. estimator/ and storage/ never log; only server/ does.
#ifndef ESG_SERVER_LOG_H_
#define ESG_SERVER_LOG_H_

#include <cstdio>
#include <string>
#include "absl/strings/str_format.h"
#include "absl/strings/string_view.h"

#include "absl/time/clock.h"
#include "absl/time/time.h"

namespace esg::server {

// One line per message: control characters (C0 and DEL) in `message` (an id
// or a reason quoting client input) are written as escapes, so no client can forge a log line
// or send escape sequences to an operator's terminal.
inline void Log(absl::string_view level, absl::string_view message) {
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
  const std::string line =
      absl::FormatTime("%Y-%m-%dT%H:%M:%E3SZ ", absl::Now(), absl::UTCTimeZone()) +
      std::string(level) + " esgd: " + text + "\n";
  std::fputs(line.c_str(), stderr);
}

}  // namespace esg::server

#endif  // ESG_SERVER_LOG_H_
