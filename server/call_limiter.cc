// Concurrent-call bounds (see call_limiter.h).
#include "server/call_limiter.h"

#include <algorithm>
#include <utility>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_replace.h"

namespace esg::server {

std::string CallerFromPeer(absl::string_view peer) {
  if (absl::StartsWith(peer, "ipv4:")) {
    absl::string_view address = peer.substr(5);
    const size_t colon = address.rfind(':');
    return std::string(colon == absl::string_view::npos ? address : address.substr(0, colon));
  }
  if (absl::StartsWith(peer, "ipv6:")) {
    const std::string address = absl::StrReplaceAll(
        peer.substr(5), {{"%5B", "["}, {"%5b", "["}, {"%5D", "]"}, {"%5d", "]"}});
    if (!address.empty() && address.front() == '[') {
      const size_t close = address.find(']');
      if (close != std::string::npos) return address.substr(1, close - 1);
    }
    return address;
  }
  return std::string(peer);
}

CallLimiter::CallLimiter(std::string call, std::string singular, std::string plural,
                         int per_caller, int total, std::string verb)
    : call_(std::move(call)),
      singular_(std::move(singular)),
      plural_(std::move(plural)),
      verb_(std::move(verb)),
      per_caller_(std::max(1, per_caller)),
      total_(std::max(1, total)) {}

absl::StatusOr<CallLimiter::Permit> CallLimiter::Acquire(const std::string& caller,
                                                          absl::string_view call) {
  if (call.empty()) call = call_;
  absl::MutexLock lock(&mu_);
  auto it = running_.find(caller);
  const int mine = it == running_.end() ? 0 : it->second;
  if (mine >= per_caller_) {
    return absl::ResourceExhaustedError(
        absl::StrCat(call, ": caller '", caller, "' already ", verb_, " ", mine, " ", Noun(mine),
                     " (limit ", per_caller_, " per caller); retry when one finishes"));
  }
  if (total_running_ >= total_) {
    return absl::ResourceExhaustedError(
        absl::StrCat(call, ": the server already ", verb_, " ", total_running_, " ",
                     Noun(total_running_), " (limit ", total_, " in total); retry when one finishes"));
  }
  ++running_[caller];
  ++total_running_;
  return Permit(this, caller);
}

void CallLimiter::Give(const std::string& caller) {
  absl::MutexLock lock(&mu_);
  auto it = running_.find(caller);
  if (it == running_.end()) return;  // cannot happen: a permit is given back once
  if (--it->second == 0) running_.erase(it);
  --total_running_;
}

int CallLimiter::Running(const std::string& caller) const {
  absl::MutexLock lock(&mu_);
  auto it = running_.find(caller);
  return it == running_.end() ? 0 : it->second;
}

int CallLimiter::Running() const {
  absl::MutexLock lock(&mu_);
  return total_running_;
}

CallLimiter::Permit::Permit(Permit&& other) noexcept
    : limiter_(std::exchange(other.limiter_, nullptr)), caller_(std::move(other.caller_)) {}

CallLimiter::Permit& CallLimiter::Permit::operator=(Permit&& other) noexcept {
  if (this != &other) {
    Release();
    limiter_ = std::exchange(other.limiter_, nullptr);
    caller_ = std::move(other.caller_);
  }
  return *this;
}

void CallLimiter::Permit::Release() {
  if (limiter_ == nullptr) return;
  std::exchange(limiter_, nullptr)->Give(caller_);
}

}  // namespace esg::server
