// Rate-limited log lines with counted suppression (see log_throttle.h).
#include "server/log_throttle.h"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace esg::server {
namespace {

// Every live throttle, for FlushThrottledLogs. Never destroyed: throttles that are function
// statics may unregister after other statics are gone. Lock order: this mutex, then a throttle's.
struct Registry {
  absl::Mutex mu;
  std::vector<LogThrottle*> throttles ABSL_GUARDED_BY(mu);
};
Registry& Throttles() {
  static Registry* const registry = new Registry;
  return *registry;
}

}  // namespace

LogThrottle::LogThrottle(std::string event) : LogThrottle(std::move(event), Options()) {}

LogThrottle::LogThrottle(std::string event, Options options)
    : event_(std::move(event)), options_(options) {
  Registry& r = Throttles();
  absl::MutexLock lock(&r.mu);
  r.throttles.push_back(this);
}

LogThrottle::~LogThrottle() {
  Registry& r = Throttles();
  absl::MutexLock lock(&r.mu);
  r.throttles.erase(std::remove(r.throttles.begin(), r.throttles.end(), this), r.throttles.end());
}

std::string LogThrottle::SummaryText(absl::string_view event, absl::string_view key,
                                     int64_t suppressed, absl::Duration span) {
  return absl::StrFormat("%d more %s lines for %s in the last %.0f s", suppressed, event, key,
                         std::ceil(absl::ToDoubleSeconds(span)));
}

LogThrottle::Window& LogThrottle::WindowAt(absl::string_view key, absl::Time now, Summary* ended) {
  auto it = windows_.find(key);
  if (it == windows_.end()) {
    if (windows_.size() >= options_.max_keys) {
      // Make room from the windows that ended without anything to report.
      for (auto w = windows_.begin(); w != windows_.end();) {
        auto here = w++;
        if (here->second.suppressed == 0 && now - here->second.start >= options_.interval) {
          windows_.erase(here);
        }
      }
    }
    if (windows_.size() >= options_.max_keys) key = kOtherKeys;
    it = windows_.try_emplace(key, Window{now, 0, 0}).first;
  }
  Window& w = it->second;
  if (now - w.start >= options_.interval) {
    if (w.suppressed > 0) *ended = {it->first, w.suppressed, options_.interval};
    w = Window{now, 0, 0};
  }
  return w;
}

void LogThrottle::WriteSummary(const Summary& s) const {
  LogEvent("WARN", "log_suppressed", SummaryText(event_, s.key, s.suppressed, s.span),
           {{"suppressedEvent", event_},
            {"key", s.key},
            {"suppressed", static_cast<int64_t>(s.suppressed)},
            {"intervalSeconds", std::ceil(absl::ToDoubleSeconds(s.span))}});
}

bool LogThrottle::Log(absl::string_view key, absl::string_view level, absl::string_view message,
                      std::initializer_list<LogField> fields, absl::Time now) {
  Summary ended;
  bool write = false;
  {
    absl::MutexLock lock(&mu_);
    Window& w = WindowAt(key, now, &ended);
    if (w.written < options_.lines_per_interval) {
      ++w.written;
      write = true;
    } else {
      ++w.suppressed;
    }
  }
  // The summary of the previous window first: the lines stay in time order.
  if (ended.suppressed > 0) WriteSummary(ended);
  if (write) LogEvent(level, event_, message, fields);
  return write;
}

void LogThrottle::CountSuppressed(absl::string_view key, absl::Time now) {
  Summary ended;
  {
    absl::MutexLock lock(&mu_);
    ++WindowAt(key, now, &ended).suppressed;
  }
  if (ended.suppressed > 0) WriteSummary(ended);
}

int LogThrottle::Flush(absl::Time now) {
  std::vector<Summary> due;
  {
    absl::MutexLock lock(&mu_);
    for (auto it = windows_.begin(); it != windows_.end();) {
      auto here = it++;
      const Window& w = here->second;
      const absl::Duration age = now - w.start;
      if (age < options_.interval && now != absl::InfiniteFuture()) continue;
      if (w.suppressed > 0) {
        // At shutdown a window may be younger than its interval: its own age is reported.
        due.push_back({here->first, w.suppressed,
                       now == absl::InfiniteFuture()
                           ? std::min(absl::Now() - w.start, options_.interval)
                           : options_.interval});
      }
      windows_.erase(here);
    }
  }
  for (const Summary& s : due) WriteSummary(s);
  return static_cast<int>(due.size());
}

std::string PeerAddress(absl::string_view peer) {
  // "ipv4:10.0.0.5:41234", "ipv6:[::1]:41234" (or "ipv6:%5B::1%5D:41234"): the port is after
  // the last ':'.
  if (absl::StartsWith(peer, "ipv4:") || absl::StartsWith(peer, "ipv6:")) {
    const size_t colon = peer.rfind(':');
    if (colon > 5) return std::string(peer.substr(0, colon));
  }
  return std::string(peer);
}

int FlushThrottledLogs(absl::Time now) {
  Registry& r = Throttles();
  absl::MutexLock lock(&r.mu);
  int written = 0;
  for (LogThrottle* t : r.throttles) written += t->Flush(now);
  return written;
}

ThrottledLogFlusher::ThrottledLogFlusher()
    : thread_([this] {
        while (!stop_.WaitForNotificationWithTimeout(absl::Seconds(1))) {
          FlushThrottledLogs(absl::Now());
        }
      }) {}

ThrottledLogFlusher::~ThrottledLogFlusher() { Stop(); }

void ThrottledLogFlusher::Stop() {
  if (!thread_.joinable()) return;
  stop_.Notify();
  thread_.join();
  FlushThrottledLogs(absl::InfiniteFuture());
}

}  // namespace esg::server
