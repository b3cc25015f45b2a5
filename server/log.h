// The server's thin logger (STYLE §3.3 rule 8): one line per message on stderr with a UTC
// timestamp and a level. estimator/ and storage/ never log; only server/ does.
#ifndef ESG_SERVER_LOG_H_
#define ESG_SERVER_LOG_H_

#include <cstdio>
#include <string>
#include "absl/strings/string_view.h"

#include "absl/time/clock.h"
#include "absl/time/time.h"

namespace esg::server {

inline void Log(absl::string_view level, absl::string_view message) {
  const std::string line =
      absl::FormatTime("%Y-%m-%dT%H:%M:%E3SZ ", absl::Now(), absl::UTCTimeZone()) +
      std::string(level) + " esgd: " + std::string(message) + "\n";
  std::fputs(line.c_str(), stderr);
}

}  // namespace esg::server

#endif  // ESG_SERVER_LOG_H_
