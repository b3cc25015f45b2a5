// QueueBudget: the bytes the subscription streams (SubscribeAlerts, SubscribeEstimates) hold in
// messages queued for clients that read slower than records are published (docs/service.md
// "Limits"). Each stream's queue has its own count bound (subscription_reactor.h); this bounds
// the bytes of one caller's streams together and of all streams together, so that no caller, and
// no set of callers, can make esgd hold their unread records without bound.
//
// A stream opens an Account under its caller (a token's name, or the peer's address: see
// call_limiter.h) and charges each message it queues, refunding it once written. A charge that
// would take the caller or the total beyond its bound is refused for a stream that holds at
// least its share (the average of the streams holding bytes in that scope): that is a slow
// stream, and it is finished with the refusal (RESOURCE_EXHAUSTED naming the bound and its
// value). A stream below its share (one that keeps up, or only starts) is charged anyway, so a
// few slow streams never cost the others theirs; the bound is then exceeded by at most what
// such streams queue before the slow ones are offered their next record and dropped.
#ifndef ESG_SERVER_QUEUE_BUDGET_H_
#define ESG_SERVER_QUEUE_BUDGET_H_

#include <cstdint>
#include <map>
#include <string>
#include <utility>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/synchronization/mutex.h"
#include "server/call_limiter.h"

namespace esg::server {

class QueueBudget {
 public:
  // Bounds in bytes (below 1: 1; the server checks its options first).
  QueueBudget(int64_t per_caller_bytes, int64_t total_bytes);
  QueueBudget(const QueueBudget&) = delete;
  QueueBudget& operator=(const QueueBudget&) = delete;

  // The queued messages of one stream. Move-only; gives back what it holds when destroyed (or
  // on Close). Must not outlive its QueueBudget. Not thread-safe: the stream calls it under its
  // own lock.
  class Account {
   public:
    Account() = default;
    Account(Account&& other) noexcept;
    Account& operator=(Account&& other) noexcept;
    Account(const Account&) = delete;
    Account& operator=(const Account&) = delete;
    ~Account() { Close(); }

    // Charges `bytes` for one more queued message, or refuses it (the charge is not made) with
    // RESOURCE_EXHAUSTED, e.g.
    //   "caller 'ops' holds 67108864 bytes of unread subscription messages (limit 64 MiB per
    //   caller, --max-queued-mb-per-caller)"
    //   "the subscribers together hold 268435456 bytes of unread subscription messages (limit
    //   256 MiB over all subscribers, --max-queued-mb)"
    // An account without a budget (default-constructed) accepts everything.
    absl::Status Charge(int64_t bytes);
    // Gives back `bytes` charged before (a message written or dropped).
    void Refund(int64_t bytes);
    // Gives back everything; the account accepts everything afterwards.
    void Close();
    int64_t held() const { return held_; }

   private:
    friend class QueueBudget;
    Account(QueueBudget* budget, std::string caller)
        : budget_(budget), caller_(std::move(caller)) {}

    QueueBudget* budget_ = nullptr;
    std::string caller_;
    int64_t held_ = 0;
  };

  Account Open(std::string caller) { return Account(this, std::move(caller)); }

  // Bytes held now by `caller`'s streams, and by all.
  int64_t held(const std::string& caller) const;
  int64_t held() const;

  int64_t per_caller_bytes() const { return per_caller_; }
  int64_t total_bytes() const { return total_; }

 private:
  // Bytes held and streams holding some, of one caller or of all.
  struct Scope {
    int64_t bytes = 0;
    int64_t holders = 0;
  };
  absl::Status Charge(const std::string& caller, int64_t mine, int64_t bytes);
  void Refund(const std::string& caller, int64_t mine_before, int64_t bytes);

  const int64_t per_caller_;
  const int64_t total_;
  mutable absl::Mutex mu_;
  std::map<std::string, Scope> callers_ ABSL_GUARDED_BY(mu_);  // callers holding bytes
  Scope all_ ABSL_GUARDED_BY(mu_);
};

// What a subscription stream holds while it runs: its caller's subscription slot (the
// service's subscription limiter) and its account of unread messages.
struct SubscriptionHold {
  CallLimiter::Permit permit;
  QueueBudget::Account queue;
};

// "64 MiB" for whole MiB, else "N bytes".
std::string ByteText(int64_t bytes);

}  // namespace esg::server

#endif  // ESG_SERVER_QUEUE_BUDGET_H_
