// The SubscribeEstimates reactor; what it guarantees is stated in estimate_reactor.h, the replay
// and live skeleton it shares with SubscribeAlerts in subscription_reactor.h.
#include "server/estimate_reactor.h"

#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/proto_mapping.h"
#include "server/subscription_reactor.h"
#include "storage/estimate_store.h"
#include "storage/records.h"

namespace esg::server {
namespace {

constexpr size_t kMaxQueuedEstimates = 50000;
constexpr int64_t kEstimateReplayPage = 500;

// The dedupe state and the replay's position of a SubscribeEstimates stream
// (subscription_reactor.h "Feed").
struct EstimateFeed {
  using Record = storage::EstimateRecord;
  using Message = esg::v1::EstimateRecord;
  static constexpr size_t kMaxQueued = kMaxQueuedEstimates;
  static constexpr size_t kMaxBuffered = kMaxQueuedEstimates;
  static std::string TooSlowMessage() {
    return absl::StrCat(
        "estimate subscriber too slow: ", kMaxQueuedEstimates,
        " estimates waiting; subscribe again with since = the last measurement_time received");
  }
  static std::string DroppedMessage(absl::string_view why) {
    return absl::StrCat(
        "estimate subscriber too slow, dropped: ", why,
        "; subscribe again with since = the last measurement_time received");
  }
  static std::string ReplayStoppedMessage(size_t records, int64_t bytes, absl::string_view why) {
    return absl::StrCat("estimate replay stopped: the page of ", records,
                        " stored estimates read for it (", bytes,
                        " bytes) would pass the bound: ", why,
                        "; subscribe again with since = the last measurement_time received");
  }
  static Message ToProto(const Record& r) { return EstimateToProto(r); }
  static int64_t RecordBytes(const Record& r) {
    return static_cast<int64_t>(
        sizeof(Record) + r.spacecraft_id.capacity() + r.state.capacity() +
        r.attitude_invalid_reason.capacity() +
        r.star_tracker_innovations.capacity() * sizeof(r.star_tracker_innovations[0]));
  }

  // Whether to queue `r`: not if, while replay and live overlap, the same or a later computation
  // of its step was already queued.
  bool Admit(const Record& r, bool replaying) {
    if (!replaying) return true;
    auto [it, inserted] = sent.try_emplace({r.spacecraft_id, r.measurement_time}, r.compute_time);
    if (!inserted) {
      if (it->second >= r.compute_time) return false;
      it->second = r.compute_time;
    }
    return true;
  }
  void ReplayComplete() { sent.clear(); }
  int64_t Forget() {
    // A map node: the key and value, and the tree's three pointers and colour.
    constexpr size_t kNodeBytes = sizeof(Key) + sizeof(absl::Time) + 4 * sizeof(void*);
    const int64_t bytes = static_cast<int64_t>(sent.size() * kNodeBytes +
                                               ids.capacity() * sizeof(std::string));
    std::map<Key, absl::Time>().swap(sent);
    std::vector<std::string>().swap(ids);
    return bytes;
  }

  using Key = std::pair<std::string, absl::Time>;  // (spacecraft, measurement time)
  // Compute time of the latest record queued per key, until the buffer is released.
  std::map<Key, absl::Time> sent;
  // The replay's position: spacecraft ids[index], after the measurement time `after`.
  std::vector<std::string> ids;
  size_t index = 0;
  std::optional<absl::Time> after;
  absl::Time since = absl::InfiniteFuture();
};

// The replay is read a page at a time, each page once the previous one is written and charged to
// the caller's bound while it is held (SubscriptionReactor::OfferPage).
class EstimateReactor : public SubscriptionReactor<EstimateFeed> {
 public:
  EstimateReactor(CallCounter* calls, EstimationCore* core,
                  const esg::v1::EstimateSubscription& request, absl::StatusOr<SubscriptionHold> hold)
      : SubscriptionReactor(calls, core, &core->estimate_hub(), std::move(hold)) {
    absl::Time since;
    if (!Accept(request, &since)) return;
    {
      absl::MutexLock lock(&shared().mu);
      EstimateFeed& feed = shared().feed;
      feed.since = since;
      if (since != absl::InfiniteFuture()) {
        feed.ids = request.spacecraft_id().empty()
                       ? core->SpacecraftIds()
                       : std::vector<std::string>{request.spacecraft_id()};
      }
    }
    Subscribe(request.spacecraft_id());
    Pump();
  }

 private:
  // Writes what is queued; while replaying and nothing is queued, reads the next page of the
  // replay (outside the lock: publishers are not held up by SQLite) or, at its end, releases
  // the buffered live estimates and queues the marker. Runs on the reactor's own calls (the
  // constructor, OnWriteDone), never two at a time.
  void Pump() override {
    Shared& s = shared();
    for (;;) {
      std::string id;
      std::optional<absl::Time> after;
      absl::Time since;
      {
        absl::MutexLock lock(&s.mu);
        if (!ReadyForPage(s, s.feed.index >= s.feed.ids.size())) return;
        id = s.feed.ids[s.feed.index];
        after = s.feed.after;
        since = s.feed.since;
      }
      if (core()->options().before_estimate_replay_page) {
        core()->options().before_estimate_replay_page(id);
      }
      absl::StatusOr<storage::EstimatePage> page = core()->storage().estimates().Page(
          id, since, absl::InfiniteFuture(), after, kEstimateReplayPage);
      absl::MutexLock lock(&s.mu);
      if (!OfferPage(s, page.status(), page.ok() ? &page->records : nullptr)) return;
      if (page->next.has_value()) {
        s.feed.after = page->next;
      } else {
        ++s.feed.index;
        s.feed.after.reset();
      }
    }
  }
};

}  // namespace

grpc::ServerWriteReactor<esg::v1::EstimateRecord>* NewEstimateReactor(
    CallCounter* calls, EstimationCore* core, const esg::v1::EstimateSubscription& request,
    absl::StatusOr<SubscriptionHold> hold) {
  return new EstimateReactor(calls, core, request, std::move(hold));
}

}  // namespace esg::server
