// Log lines of one event, rate-limited per key (a station's stream, a peer address), with one
// summary line counting what was held back (docs/service.md "Logs"): a conflicting replay wrote
// 690 `frame_conflict` lines, a client streaming conflicting frames for 200 s 933,000 lines
// (267 MB), a client retrying a wrong token 2.9 MB in 10 s. With a throttle each key writes at
// most `lines_per_interval` lines and one summary per interval:
//
//   WARN esgd: 690 more frame_conflict lines for station GS-2 of spacecraft RDK-1 in the last 10 s
//
// Intervals are fixed windows that open at a key's first line. The summary of a window is written
// by the key's first line after it, or by FlushThrottledLogs (a ThrottledLogFlusher calls it once
// a second, so a flood that stops is still counted). Keys are client-supplied: at most `max_keys`
// are tracked; the lines of further keys share one key, "other keys".
#ifndef ESG_SERVER_LOG_THROTTLE_H_
#define ESG_SERVER_LOG_THROTTLE_H_

#include <cstdint>
#include <initializer_list>
#include <string>
#include <thread>

#include "absl/base/thread_annotations.h"
#include "absl/container/flat_hash_map.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"
#include "absl/synchronization/notification.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "server/log.h"

namespace esg::server {

class LogThrottle {
 public:
  struct Options {
    int lines_per_interval = 10;
    absl::Duration interval = absl::Seconds(10);
    size_t max_keys = 1024;
  };
  inline static constexpr absl::string_view kOtherKeys = "other keys";

  // `event`: the stable name of the throttled lines (frame_conflict). Registers the throttle
  // with FlushThrottledLogs until it is destroyed.
  explicit LogThrottle(std::string event);
  LogThrottle(std::string event, Options options);
  ~LogThrottle();
  LogThrottle(const LogThrottle&) = delete;
  LogThrottle& operator=(const LogThrottle&) = delete;

  // Writes the line (LogEvent with this throttle's event) unless `key` wrote lines_per_interval
  // lines in its current interval; then counts it as suppressed. `key` names the source in the
  // summary ("station GS-2 of spacecraft RDK-1", "peer ipv4:10.0.0.5"). Returns whether the
  // line was written. Thread-safe.
  bool Log(absl::string_view key, absl::string_view level, absl::string_view message,
           std::initializer_list<LogField> fields, absl::Time now = absl::Now());

  // Counts a line of `key` that the caller held back by a budget of its own (a throttled
  // authorization refusal): it appears in the summary only.
  void CountSuppressed(absl::string_view key, absl::Time now = absl::Now());

  // Writes the summary of every key whose interval ended by `now` with lines suppressed, and
  // forgets those keys. absl::InfiniteFuture(): every pending summary (at shutdown). Returns the
  // summaries written.
  int Flush(absl::Time now);

  // The summary's text (exposed for the tests): "N more EVENT lines for KEY in the last S s".
  static std::string SummaryText(absl::string_view event, absl::string_view key, int64_t suppressed,
                                 absl::Duration span);

 private:
  struct Window {
    absl::Time start;
    int written = 0;
    int64_t suppressed = 0;
  };
  struct Summary {
    std::string key;
    int64_t suppressed = 0;
    absl::Duration span;
  };
  // The window of `key` at `now` (a new one when its interval ended, the ended one's summary in
  // `*ended`); the shared "other keys" window when max_keys are tracked.
  Window& WindowAt(absl::string_view key, absl::Time now, Summary* ended)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  void WriteSummary(const Summary& summary) const;

  const std::string event_;
  const Options options_;
  absl::Mutex mu_;
  absl::flat_hash_map<std::string, Window> windows_ ABSL_GUARDED_BY(mu_);
};

// The address part of a gRPC peer string, the key of per-peer throttles: "ipv4:10.0.0.5",
// "ipv6:[::1]", "unix:/path" (the port dropped, so that one client's connections share a key).
std::string PeerAddress(absl::string_view peer);

// Flush(now) on every LogThrottle of the process. Returns the summaries written.
int FlushThrottledLogs(absl::Time now);

// A thread that calls FlushThrottledLogs once a second; Stop (or the destructor) writes every
// pending summary and joins it. EsgServer owns one.
class ThrottledLogFlusher {
 public:
  ThrottledLogFlusher();
  ~ThrottledLogFlusher();
  void Stop();

 private:
  absl::Notification stop_;
  std::thread thread_;
};

}  // namespace esg::server

#endif  // ESG_SERVER_LOG_THROTTLE_H_
