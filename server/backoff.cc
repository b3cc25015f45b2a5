// Exponential backoff with jitter (backoff.h).
#include "server/backoff.h"

#include <algorithm>

#include "absl/time/clock.h"

namespace esg::server {

absl::Duration BackoffDelay(int64_t failures, absl::Duration initial, absl::Duration cap) {
  thread_local std::mt19937_64 rng{std::random_device{}()};
  absl::Duration d = std::max(initial, absl::Nanoseconds(1));
  for (int64_t i = 1; i < failures && d < cap; ++i) d *= 2;
  d = std::min(d, cap);
  std::uniform_real_distribution<double> upper_half(0.5, 1.0);
  return d * upper_half(rng);
}

absl::Duration Backoff::Failed() {
  if (failures_ == 0) since_ = absl::Now();
  ++failures_;
  return BackoffDelay(failures_, initial_, cap_);
}

}  // namespace esg::server
