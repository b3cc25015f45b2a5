#include "server/auth_throttle.h"

#include <algorithm>
#include <vector>

#include "absl/strings/str_cat.h"

namespace esg::server {

std::string FailedAuthThrottle::Address(absl::string_view peer) { return PeerAddress(peer); }

FailedAuthThrottle::Verdict FailedAuthThrottle::Refused(absl::string_view peer, absl::Time now) {
  const std::string address = Address(peer);
  absl::MutexLock lock(&mu_);
  if (peers_.size() >= kMaxPeers && !peers_.contains(address)) {
    // Forget the addresses whose budget has refilled: they hold nothing worth keeping.
    std::vector<std::string> idle;
    for (const auto& [key, p] : peers_) {
      if (p.budget + absl::ToDoubleSeconds(now - p.updated) * kRefillPerSecond >= kBurst) {
        idle.push_back(key);
      }
    }
    for (const std::string& key : idle) peers_.erase(key);
    // Still full (a flood from many addresses): the new address is throttled without state.
    if (peers_.size() >= kMaxPeers) return Verdict::kThrottled;
  }
  auto [it, inserted] = peers_.try_emplace(address);
  Peer& p = it->second;
  if (inserted) p.updated = now;
  p.budget = std::min(
      kBurst, p.budget + std::max(0.0, absl::ToDoubleSeconds(now - p.updated)) * kRefillPerSecond);
  p.updated = now;
  if (p.budget < 1.0) return Verdict::kThrottled;
  p.budget -= 1.0;
  return Verdict::kWithinBudget;
}

void FailedAuthThrottle::Log(absl::string_view peer, Verdict verdict, absl::string_view message,
                             std::initializer_list<LogField> fields, absl::Time now) {
  const std::string key = absl::StrCat("peer ", Address(peer));
  if (verdict == Verdict::kWithinBudget) {
    log_.Log(key, "WARN", message, fields, now);
  } else {
    log_.CountSuppressed(key, now);
  }
}

}  // namespace esg::server
