// Exponential backoff with jitter for the loops that retry storage (docs/service.md "Reconnects
// and retries"): the alert relay's reconnect, the lease renewal, the storage probe and the filter
// workers' retries. Each failure in a row doubles the wait up to a cap, and the wait is drawn at
// random in its upper half, so a loop makes at most two attempts per cap once the cap is reached
// and servers that lost the same database do not retry in step.
#ifndef ESG_SERVER_BACKOFF_H_
#define ESG_SERVER_BACKOFF_H_

#include <cstdint>
#include <random>

#include "absl/time/time.h"

namespace esg::server {

// The longest wait of every reconnect loop of the service: a database that is back is used again
// within this time (plus one connection attempt).
inline constexpr absl::Duration kMaxReconnectWait = absl::Seconds(1);

// The wait after the `failures`-th failure in a row (failures >= 1): a uniform random duration
// in [d / 2, d], d = min(cap, initial * 2^(failures - 1)). Thread-safe.
absl::Duration BackoffDelay(int64_t failures, absl::Duration initial, absl::Duration cap);

// One loop's failures in a row and the wait before its next attempt. Not thread-safe: one loop.
class Backoff {
 public:
  Backoff(absl::Duration initial, absl::Duration cap) : initial_(initial), cap_(cap) {}

  // Counts a failed attempt (the first of a run records its time) and returns how long to wait
  // before the next one.
  absl::Duration Failed();
  // Ends the run of failures (after a success).
  void Reset() { failures_ = 0; }

  // Failed attempts since the last success; 0 while the loop succeeds.
  int64_t failures() const { return failures_; }
  // When the current run of failures began (meaningful while failures() > 0).
  absl::Time since() const { return since_; }

 private:
  const absl::Duration initial_;
  const absl::Duration cap_;
  int64_t failures_ = 0;
  absl::Time since_;
};

}  // namespace esg::server

#endif  // ESG_SERVER_BACKOFF_H_
