// Failed authorizations, throttled per peer address (docs/service.md "Security"). A client
// retrying a wrong token in a loop made 2,584 refusals per second, each a WARN line (2.9 MB of log
// in 10 s). Each address has a budget of refusals that refills over time; within it every
// refusal is answered and logged as before; beyond it the refusal is answered RESOURCE_EXHAUSTED
// without a log line, and one summary line per address and interval counts what was held back.
//
// A valid token is never refused for its address's failures: operators behind one console
// gateway share its address, and one of them mistyping a token must not lock out the others.
// Guessing is made hopeless by the token length (TokenAuthorizer::kMinTokenLength), not by the
// budget; the budget bounds the log and the work a misbehaving client causes.
#ifndef ESG_SERVER_AUTH_THROTTLE_H_
#define ESG_SERVER_AUTH_THROTTLE_H_

#include <cstdint>
#include <string>

#include "absl/container/flat_hash_map.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"

namespace esg::server {

class FailedAuthThrottle {
 public:
  // Refusals an address may have at once, and how many it regains per second.
  static constexpr double kBurst = 20.0;
  static constexpr double kRefillPerSecond = 2.0;
  // At most one summary line per address per interval.
  static constexpr absl::Duration kSummaryInterval = absl::Seconds(10);
  // Addresses tracked at once; beyond it the idle ones (full budget) are forgotten first.
  static constexpr size_t kMaxPeers = 4096;

  enum class Verdict {
    kWithinBudget,  // answer the refusal as usual and log it
    kThrottled,     // answer RESOURCE_EXHAUSTED, no log line of its own
  };
  struct Outcome {
    Verdict verdict = Verdict::kWithinBudget;
    // When not empty: a summary line to log now (refusals held back since the last one).
    std::string summary;
  };

  // Records one refused authorization of `peer` (gRPC's peer string, "ipv4:10.0.0.5:41234";
  // its port is dropped so that one client's connections share a budget) at `now`.
  Outcome Refused(absl::string_view peer, absl::Time now);

  // The address part of a gRPC peer string: "ipv4:10.0.0.5", "ipv6:[::1]", "unix:/path".
  static std::string Address(absl::string_view peer);

 private:
  struct Peer {
    double budget = kBurst;
    absl::Time updated;
    int64_t held_back = 0;  // throttled refusals not yet summarised
    absl::Time last_summary = absl::InfinitePast();
  };

  absl::Mutex mu_;
  absl::flat_hash_map<std::string, Peer> peers_ ABSL_GUARDED_BY(mu_);
};

}  // namespace esg::server

#endif  // ESG_SERVER_AUTH_THROTTLE_H_
