// Per-step estimate fan-out (see estimate_hub.h).
#include "server/estimate_hub.h"

#include <utility>

namespace esg::server {

int64_t EstimateHub::Subscribe(std::string spacecraft_id, Listener listener, Closer close) {
  Closer closed_now;
  int64_t id = 0;
  {
    absl::MutexLock lock(&mu_);
    id = next_id_++;
    if (closed_) closed_now = close;
    subscribers_[id] = Subscriber{std::move(spacecraft_id), std::move(listener), std::move(close)};
  }
  if (closed_now) closed_now();
  return id;
}

void EstimateHub::Unsubscribe(int64_t id) {
  absl::MutexLock lock(&mu_);
  subscribers_.erase(id);
}

void EstimateHub::Publish(const std::vector<storage::EstimateRecord>& records) {
  if (records.empty()) return;
  absl::MutexLock lock(&mu_);
  for (auto& [id, s] : subscribers_) {
    for (const storage::EstimateRecord& r : records) {
      if (s.spacecraft_id.empty() || s.spacecraft_id == r.spacecraft_id) s.listener(r);
    }
  }
}

void EstimateHub::CloseAll() {
  std::vector<Closer> closers;
  {
    absl::MutexLock lock(&mu_);
    closed_ = true;
    for (auto& [id, s] : subscribers_) closers.push_back(s.close);
  }
  for (Closer& c : closers) c();
}

int EstimateHub::size() {
  absl::MutexLock lock(&mu_);
  return static_cast<int>(subscribers_.size());
}

}  // namespace esg::server
