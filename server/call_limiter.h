// Bounds on concurrent calls of one kind (docs/service.md "Limits"): at most `per_caller` calls
// of a caller at once and at most `total` over all callers. A call takes a Permit before it
// starts its work and gives it back when the work is done (the Permit's destructor or Release);
// beyond either bound it is refused at once with RESOURCE_EXHAUSTED, never queued, so a caller
// cannot hold server threads or CPU beyond its share.
//
// Who is a caller is the service's decision (estimation_service.cc): the bearer token's name
// when tokens are configured, else the peer's address without the port (CallerFromPeer).
#ifndef ESG_SERVER_CALL_LIMITER_H_
#define ESG_SERVER_CALL_LIMITER_H_

#include <map>
#include <string>
#include <utility>

#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"

namespace esg::server {

// The caller of a call without a token: the address of gRPC's peer string without the scheme
// and the port. "ipv4:127.0.0.1:54321" -> "127.0.0.1"; "ipv6:[::1]:5432" and its URI-encoded
// form "ipv6:%5B::1%5D:5432" -> "::1". Any other peer string (a Unix socket, an empty one) is
// returned whole.
std::string CallerFromPeer(absl::string_view peer);

class CallLimiter {
 public:
  // `call` names the rpc in messages ("PredictAttitude"); `singular`/`plural` the running thing
  // ("prediction"/"predictions"), `verb` what a caller does with it ("runs"; "holds" for
  // streams). Limits below 1 are treated as 1 (the server validates its options before it
  // builds limiters).
  CallLimiter(std::string call, std::string singular, std::string plural, int per_caller,
              int total, std::string verb = "runs");
  CallLimiter(const CallLimiter&) = delete;
  CallLimiter& operator=(const CallLimiter&) = delete;

  // One running call. Move-only; gives its slot back when destroyed or on Release (idempotent).
  // It must not outlive its CallLimiter.
  class Permit {
   public:
    Permit() = default;
    Permit(Permit&& other) noexcept;
    Permit& operator=(Permit&& other) noexcept;
    Permit(const Permit&) = delete;
    Permit& operator=(const Permit&) = delete;
    ~Permit() { Release(); }

    void Release();
    bool held() const { return limiter_ != nullptr; }

   private:
    friend class CallLimiter;
    Permit(CallLimiter* limiter, std::string caller)
        : limiter_(limiter), caller_(std::move(caller)) {}

    CallLimiter* limiter_ = nullptr;
    std::string caller_;
  };

  // A permit for one more call of `caller`, or RESOURCE_EXHAUSTED
  //   "PredictAttitude: caller 'ops' already runs 4 predictions (limit 4 per caller); retry when
  //   one finishes"
  //   "PredictAttitude: the server already runs 8 predictions (limit 8 in total); retry when one
  //   finishes"
  // The per-caller bound is checked first. `call`, when given, names the rpc instead of the
  // constructor's (one limiter bounding several rpcs together, as SubscribeAlerts and
  // SubscribeEstimates).
  absl::StatusOr<Permit> Acquire(const std::string& caller, absl::string_view call = {});

  // Calls running now, of `caller` and over all callers.
  int Running(const std::string& caller) const;
  int Running() const;

  int per_caller() const { return per_caller_; }
  int total() const { return total_; }

 private:
  void Give(const std::string& caller);
  const std::string& Noun(int n) const { return n == 1 ? singular_ : plural_; }

  const std::string call_;
  const std::string singular_;
  const std::string plural_;
  const std::string verb_;
  const int per_caller_;
  const int total_;
  mutable absl::Mutex mu_;
  std::map<std::string, int> running_ ABSL_GUARDED_BY(mu_);  // callers with >= 1 running call
  int total_running_ ABSL_GUARDED_BY(mu_) = 0;
};

}  // namespace esg::server

#endif  // ESG_SERVER_CALL_LIMITER_H_
