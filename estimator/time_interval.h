// A span of measurement times, [from, to] with both ends inclusive: the one convention of every
// from/to of the service and the CLI (docs/service.md "Time intervals", docs/cli.md). An absent
// end is open (InfinitePast, InfiniteFuture). Stored times have nanosecond resolution, so the
// half-open span [from, End()) of a storage query holds exactly the same instants.
#ifndef ESG_ESTIMATOR_TIME_INTERVAL_H_
#define ESG_ESTIMATOR_TIME_INTERVAL_H_

#include "absl/time/time.h"

namespace esg::estimator {

struct TimeInterval {
  absl::Time from = absl::InfinitePast();
  absl::Time to = absl::InfiniteFuture();

  bool Contains(absl::Time t) const { return from <= t && t <= to; }
  // The first instant after the interval: to + 1 ns (InfiniteFuture when `to` is open).
  absl::Time End() const { return to == absl::InfiniteFuture() ? to : to + absl::Nanoseconds(1); }
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_TIME_INTERVAL_H_
