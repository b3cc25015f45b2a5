// Bytes of unread subscription messages (see queue_budget.h).
#include "server/queue_budget.h"

#include <algorithm>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"

namespace esg::server {

std::string ByteText(int64_t bytes) {
  constexpr int64_t kMiB = int64_t{1} << 20;
  if (bytes > 0 && bytes % kMiB == 0) return absl::StrCat(bytes / kMiB, " MiB");
  return absl::StrCat(bytes, " bytes");
}

QueueBudget::QueueBudget(int64_t per_caller_bytes, int64_t total_bytes)
    : per_caller_(std::max<int64_t>(1, per_caller_bytes)),
      total_(std::max<int64_t>(1, total_bytes)) {}

absl::Status QueueBudget::Charge(const std::string& caller, int64_t mine, int64_t bytes) {
  absl::MutexLock lock(&mu_);
  Scope& own = callers_[caller];
  // A stream holds at least its share when mine >= scope.bytes / scope.holders.
  if (own.bytes + bytes > per_caller_ && mine * own.holders >= own.bytes) {
    const int64_t held = own.bytes;
    if (own.bytes == 0) callers_.erase(caller);
    return absl::ResourceExhaustedError(
        absl::StrCat("caller '", caller, "' holds ", held,
                     " bytes of unread subscription messages (limit ", ByteText(per_caller_),
                     " per caller, --max-queued-mb-per-caller)"));
  }
  if (all_.bytes + bytes > total_ && mine * all_.holders >= all_.bytes) {
    if (own.bytes == 0) callers_.erase(caller);
    return absl::ResourceExhaustedError(
        absl::StrCat("the subscribers together hold ", all_.bytes,
                     " bytes of unread subscription messages (limit ", ByteText(total_),
                     " over all subscribers, --max-queued-mb)"));
  }
  if (mine == 0 && bytes > 0) {
    ++own.holders;
    ++all_.holders;
  }
  own.bytes += bytes;
  all_.bytes += bytes;
  return absl::OkStatus();
}

void QueueBudget::Refund(const std::string& caller, int64_t mine_before, int64_t bytes) {
  absl::MutexLock lock(&mu_);
  auto it = callers_.find(caller);
  if (it == callers_.end()) return;  // cannot happen: only charged bytes are refunded
  Scope& own = it->second;
  own.bytes -= bytes;
  all_.bytes -= bytes;
  if (mine_before > 0 && mine_before == bytes) {
    --own.holders;
    --all_.holders;
  }
  if (own.holders == 0) callers_.erase(it);
}

int64_t QueueBudget::held(const std::string& caller) const {
  absl::MutexLock lock(&mu_);
  auto it = callers_.find(caller);
  return it == callers_.end() ? 0 : it->second.bytes;
}

int64_t QueueBudget::held() const {
  absl::MutexLock lock(&mu_);
  return all_.bytes;
}

QueueBudget::Account::Account(Account&& other) noexcept
    : budget_(std::exchange(other.budget_, nullptr)),
      caller_(std::move(other.caller_)),
      held_(std::exchange(other.held_, 0)) {}

QueueBudget::Account& QueueBudget::Account::operator=(Account&& other) noexcept {
  if (this != &other) {
    Close();
    budget_ = std::exchange(other.budget_, nullptr);
    caller_ = std::move(other.caller_);
    held_ = std::exchange(other.held_, 0);
  }
  return *this;
}

absl::Status QueueBudget::Account::Charge(int64_t bytes) {
  if (budget_ == nullptr) return absl::OkStatus();
  if (absl::Status s = budget_->Charge(caller_, held_, bytes); !s.ok()) return s;
  held_ += bytes;
  return absl::OkStatus();
}

void QueueBudget::Account::Refund(int64_t bytes) {
  if (budget_ == nullptr) return;
  bytes = std::min(bytes, held_);
  if (bytes <= 0) return;
  budget_->Refund(caller_, held_, bytes);
  held_ -= bytes;
}

void QueueBudget::Account::Close() {
  Refund(held_);
  budget_ = nullptr;
}

}  // namespace esg::server
