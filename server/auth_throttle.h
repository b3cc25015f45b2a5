// Failed authorizations, throttled per peer address (docs/service.md "Security"). A client
// retrying a wrong token in a loop made 2,584 refusals per second, each a WARN line (2.9 MB of log
// in 10 s). Each address has a budget of refusals that refills over time; within it every
// refusal is answered as before; beyond it the refusal is answered RESOURCE_EXHAUSTED. Their log
// lines are throttled per address apart from that budget (server/log_throttle.h): a few a
// interval, then one line counting the refusals not logged one by one, budgeted or not.
//
// A valid token is never refused for its address's failures: operators behind one console
// gateway share its address, and one of them mistyping a token must not lock out the others.
// Guessing is made hopeless by the token length (TokenAuthorizer::kMinTokenLength), not by the
// budget; the budget bounds the work, and the log throttle the log, a misbehaving client causes.
#ifndef ESG_SERVER_AUTH_THROTTLE_H_
#define ESG_SERVER_AUTH_THROTTLE_H_

#include <cstdint>
#include <initializer_list>
#include <string>

#include "absl/container/flat_hash_map.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/log.h"
#include "server/log_throttle.h"

namespace esg::server {

class FailedAuthThrottle {
 public:
  // Refusals an address may have at once, and how many it regains per second.
  static constexpr double kBurst = 20.0;
  static constexpr double kRefillPerSecond = 2.0;
  // Addresses tracked at once; beyond it the idle ones (full budget) are forgotten first.
  static constexpr size_t kMaxPeers = 4096;

  enum class Verdict {
    kWithinBudget,  // answer the refusal as usual
    kThrottled,     // answer RESOURCE_EXHAUSTED
  };

  // Records one refused authorization of `peer` (gRPC's peer string, "ipv4:10.0.0.5:41234";
  // its port is dropped so that one client's connections share a budget) at `now`.
  Verdict Refused(absl::string_view peer, absl::Time now);

  // The `authorization_refused` line of a refusal of `peer` with `verdict`: written within the
  // address's log budget (LogThrottle defaults) when kWithinBudget, else only counted in the
  // address's `log_suppressed` summary ("37 more authorization_refused lines for peer
  // ipv4:10.0.0.5 in the last 10 s").
  void Log(absl::string_view peer, Verdict verdict, absl::string_view message,
           std::initializer_list<LogField> fields, absl::Time now);

  // The address part of a gRPC peer string: "ipv4:10.0.0.5", "ipv6:[::1]", "unix:/path".
  static std::string Address(absl::string_view peer);

 private:
  struct Peer {
    double budget = kBurst;
    absl::Time updated;
  };

  absl::Mutex mu_;
  absl::flat_hash_map<std::string, Peer> peers_ ABSL_GUARDED_BY(mu_);
  LogThrottle log_{"authorization_refused"};
};

}  // namespace esg::server

#endif  // ESG_SERVER_AUTH_THROTTLE_H_
