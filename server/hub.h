// Live fan-out of committed records to the streams subscribed to them: one Hub per kind of record
// (alert_hub.h, estimate_hub.h). Publishers call Publish after the change is committed; a
// subscriber's listener runs under the hub's lock and must only queue the record.
#ifndef ESG_SERVER_HUB_H_
#define ESG_SERVER_HUB_H_

#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/synchronization/mutex.h"
#include "absl/types/span.h"

namespace esg::server {

// What Subscribe does once CloseAll has run.
enum class AfterClose {
  kCloseNewSubscribers,  // the new subscriber's closer is called at once
  kKeepNewSubscribers,   // the new subscriber stays open
};

// `Record` has a `spacecraft_id` member (std::string).
template <typename Record>
class Hub {
 public:
  using Listener = std::function<void(const Record&)>;
  using Closer = std::function<void()>;

  explicit Hub(AfterClose after_close = AfterClose::kCloseNewSubscribers)
      : after_close_(after_close) {}
  Hub(const Hub&) = delete;
  Hub& operator=(const Hub&) = delete;

  // spacecraft_id empty: every spacecraft. `close` is called by CloseAll (server shutdown), or
  // with AfterClose::kCloseNewSubscribers at once (after registering) when the hub is already
  // closed, so that no subscription started during shutdown stays open. Returns an id for
  // Unsubscribe.
  int64_t Subscribe(std::string spacecraft_id, Listener listener, Closer close) {
    Closer closed_now;
    int64_t id = 0;
    {
      absl::MutexLock lock(&mu_);
      id = next_id_++;
      if (closed_ && after_close_ == AfterClose::kCloseNewSubscribers) closed_now = close;
      subscribers_[id] =
          Subscriber{std::move(spacecraft_id), std::move(listener), std::move(close)};
    }
    if (closed_now) closed_now();
    return id;
  }

  // After it returns, the listener is never called again.
  void Unsubscribe(int64_t id) {
    absl::MutexLock lock(&mu_);
    subscribers_.erase(id);
  }

  // Hands each record, in order, to the matching subscribers; all of them under one hold of the
  // lock, so that no other publication comes between them.
  void Publish(absl::Span<const Record> records) {
    if (records.empty()) return;
    absl::MutexLock lock(&mu_);
    for (auto& [id, s] : subscribers_) {
      for (const Record& r : records) {
        if (s.spacecraft_id.empty() || s.spacecraft_id == r.spacecraft_id) s.listener(r);
      }
    }
  }
  void Publish(const Record& record) { Publish(absl::Span<const Record>(&record, 1)); }

  // Calls every subscriber's closer (they finish their streams).
  void CloseAll() {
    std::vector<Closer> closers;
    {
      absl::MutexLock lock(&mu_);
      closed_ = true;
      for (auto& [id, s] : subscribers_) closers.push_back(s.close);
    }
    for (Closer& c : closers) c();
  }

  // Number of subscribers.
  int size() {
    absl::MutexLock lock(&mu_);
    return static_cast<int>(subscribers_.size());
  }

 private:
  struct Subscriber {
    std::string spacecraft_id;
    Listener listener;
    Closer close;
  };
  const AfterClose after_close_;
  absl::Mutex mu_;
  int64_t next_id_ ABSL_GUARDED_BY(mu_) = 1;
  bool closed_ ABSL_GUARDED_BY(mu_) = false;
  std::map<int64_t, Subscriber> subscribers_ ABSL_GUARDED_BY(mu_);
};

}  // namespace esg::server

#endif  // ESG_SERVER_HUB_H_
