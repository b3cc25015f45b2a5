// CallCounter (see call_counter.h).
#include "server/call_counter.h"

#include <cstdint>

#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"

namespace esg::server {

void CallCounter::Enter() {
  absl::MutexLock lock(&mu_);
  ++running_;
}

void CallCounter::Leave() {
  absl::MutexLock lock(&mu_);
  --running_;
}

int64_t CallCounter::running() {
  absl::MutexLock lock(&mu_);
  return running_;
}

bool CallCounter::WaitIdle(absl::Time deadline) {
  absl::MutexLock lock(&mu_);
  return mu_.AwaitWithDeadline(absl::Condition(
                                   +[](int64_t* running) { return *running == 0; }, &running_),
                               deadline);
}

}  // namespace esg::server
