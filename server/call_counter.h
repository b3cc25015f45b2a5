// CallCounter: the calls of the service not finished yet, for a shutdown that waits for them.
#ifndef ESG_SERVER_CALL_COUNTER_H_
#define ESG_SERVER_CALL_COUNTER_H_

#include <cstdint>

#include "absl/base/thread_annotations.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"

namespace esg::server {

// The calls of the service that have not finished (their reactor's OnDone not yet run), so
// that a shutdown knows when only idle connections and gRPC's own streams (health watches,
// reflection) are left (EsgServer::Shutdown). Thread-safe.
class CallCounter {
 public:
  // Held by each call's reactor for its whole life.
  class Token {
   public:
    explicit Token(CallCounter* counter) : counter_(counter) { counter_->Enter(); }
    ~Token() { counter_->Leave(); }
    Token(const Token&) = delete;
    Token& operator=(const Token&) = delete;

   private:
    CallCounter* counter_;
  };
  int64_t running();
  // Blocks until no call runs (true) or until `deadline` (false).
  bool WaitIdle(absl::Time deadline);

 private:
  void Enter();
  void Leave();
  absl::Mutex mu_;
  int64_t running_ ABSL_GUARDED_BY(mu_) = 0;
};

}  // namespace esg::server

#endif  // ESG_SERVER_CALL_COUNTER_H_
