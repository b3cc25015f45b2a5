// Alert fan-out (see alert_hub.h).
#include "server/alert_hub.h"

#include <utility>
#include <vector>

namespace esg::server {

int64_t AlertHub::Subscribe(std::string spacecraft_id, Listener listener, Closer close) {
  absl::MutexLock lock(&mu_);
  const int64_t id = next_id_++;
  subscribers_[id] = Subscriber{std::move(spacecraft_id), std::move(listener), std::move(close)};
  return id;
}

void AlertHub::Unsubscribe(int64_t id) {
  absl::MutexLock lock(&mu_);
  subscribers_.erase(id);
}

void AlertHub::Publish(const storage::AlertRecord& record) {
  absl::MutexLock lock(&mu_);
  for (auto& [id, s] : subscribers_) {
    if (s.spacecraft_id.empty() || s.spacecraft_id == record.spacecraft_id) s.listener(record);
  }
}

int AlertHub::size() {
  absl::MutexLock lock(&mu_);
  return static_cast<int>(subscribers_.size());
}

void AlertHub::CloseAll() {
  std::vector<Closer> closers;
  {
    absl::MutexLock lock(&mu_);
    for (auto& [id, s] : subscribers_) closers.push_back(s.close);
  }
  for (Closer& c : closers) c();
}

}  // namespace esg::server
