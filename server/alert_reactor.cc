// The SubscribeAlerts reactor; what it guarantees is stated in alert_reactor.h, the replay and
// live skeleton it shares with SubscribeEstimates in subscription_reactor.h.
#include "server/alert_reactor.h"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/proto_mapping.h"
#include "server/subscription_reactor.h"
#include "storage/alert_store.h"
#include "storage/records.h"

namespace esg::server {
namespace {

constexpr size_t kMaxQueuedAlerts = 100000;
// Stored alerts read at a time by the replay: about 1.5 MB at 1.3 KB an alert.
constexpr int64_t kAlertReplayPage = 1000;

// What a SubscribeAlerts stream has sent of each alert (subscription_reactor.h "Feed").
class AlertFeed {
 public:
  using Record = storage::AlertRecord;
  using Message = esg::v1::Alert;
  static constexpr size_t kMaxQueued = kMaxQueuedAlerts;
  // The replay is read as the client keeps up, so the live alerts buffered meanwhile are bounded
  // like the queue (and charged to the QueueBudget).
  static constexpr size_t kMaxBuffered = kMaxQueuedAlerts;
  static std::string TooSlowMessage() { return "alert subscriber too slow: queue limit reached"; }
  static std::string DroppedMessage(absl::string_view why) {
    return absl::StrCat("alert subscriber too slow, dropped: ", why,
                        "; subscribe again with since = the latest measurement_time received");
  }
  static Message ToProto(const Record& r) { return AlertToProto(r); }
  static int64_t RecordBytes(const Record& r) {
    return static_cast<int64_t>(sizeof(Record) + r.spacecraft_id.capacity() +
                                r.severity.capacity() + r.reason.capacity() +
                                r.subsystem.capacity() + r.unit.capacity() +
                                r.message.capacity() + r.acknowledged_by.capacity());
  }

  // Whether to queue `r`: not if that state of the alert was already queued. While the replay is
  // merged with the changes buffered during it, their order is unknown, so only a newer state is
  // queued (a count that grew, an acknowledgement, a clear, a revision). Live changes come in
  // commit order (AlertHub), so any state other than the last one sent is queued: a re-run over a
  // late frame may set a repeat count back or undo a clear (docs/service.md "Several ground
  // stations"), and the subscriber must end with the stored state.
  bool Admit(const Record& r, bool replaying) {
    const Version v{r.repeat_count, r.acknowledged, r.cleared,
                    r.revised_time != absl::InfinitePast()};
    auto [it, inserted] = sent_.try_emplace({r.spacecraft_id, r.sequence}, v);
    if (!inserted && !replaying) {
      if (v == it->second) return false;  // the replay already sent this state
      // An acknowledgement is never undone: an unacknowledged state after an acknowledged one
      // was read before the acknowledgement committed (a new alert acknowledged between its
      // commit and its publication); the stored alert is acknowledged.
      if (std::get<1>(it->second) && !std::get<1>(v)) return false;
      it->second = v;
    } else if (!inserted) {
      const Version& old = it->second;
      // A revision is news even where a re-run set the repeat count back.
      const bool revision = std::get<3>(v) && !std::get<3>(old);
      if (!revision && std::get<0>(v) <= std::get<0>(old) && std::get<1>(v) <= std::get<1>(old) &&
          std::get<2>(v) <= std::get<2>(old) && std::get<3>(v) <= std::get<3>(old)) {
        return false;  // not newer
      }
      it->second =
          Version{std::max(std::get<0>(v), std::get<0>(old)), std::get<1>(v) || std::get<1>(old),
                  std::get<2>(v) || std::get<2>(old), std::get<3>(v) || std::get<3>(old)};
    }
    return true;
  }
  // The live rule above needs every alert's last state sent: nothing is forgotten while the
  // stream runs (one map node per alert sent, about 100 bytes).
  void ReplayComplete() {}
  int64_t Forget() {
    const int64_t bytes = static_cast<int64_t>(sent_.size() * kSentNodeBytes);
    std::map<std::pair<std::string, int64_t>, Version>().swap(sent_);
    return bytes;
  }

  // The replay: the request's spacecraft ("" for all), since (InfiniteFuture: no replay),
  // include_revised, and where the read stands (the last alert read; nullopt before the first
  // page); `read` once the last page was read.
  std::string spacecraft_id;
  absl::Time since = absl::InfiniteFuture();
  bool include_revised = false;
  std::optional<storage::AlertPosition> after;
  bool read = false;

 private:
  // repeat_count, acknowledged, cleared, revised (a re-run over a late frame superseded it)
  using Version = std::tuple<int64_t, bool, bool, bool>;
  // A map node: the key and value, and the tree's three pointers and colour.
  static constexpr size_t kSentNodeBytes =
      sizeof(std::pair<std::string, int64_t>) + sizeof(Version) + 4 * sizeof(void*);
  std::map<std::pair<std::string, int64_t>, Version> sent_;
};

// The replay is read kAlertReplayPage alerts at a time, each page once the previous one is
// written, so a client that does not read holds one page at most. A page is charged to the
// caller's QueueBudget account from the read until its alerts are queued (each then charged as
// a message): a page that would take the caller, or all subscribers, beyond the bound finishes
// the stream with RESOURCE_EXHAUSTED naming it, as a slow live subscriber's queue does.
class AlertReactor : public SubscriptionReactor<AlertFeed> {
 public:
  AlertReactor(CallCounter* calls, EstimationCore* core, const esg::v1::AlertSubscription& request,
               absl::StatusOr<SubscriptionHold> hold)
      : SubscriptionReactor(calls, core, &core->alert_hub(), std::move(hold)) {
    absl::Time since;
    if (!Accept(request, &since)) return;
    {
      absl::MutexLock lock(&shared().mu);
      AlertFeed& feed = shared().feed;
      feed.spacecraft_id = request.spacecraft_id();
      feed.since = since;
      feed.include_revised = request.include_revised();
    }
    Subscribe(request.spacecraft_id());
    Pump();
  }

 private:
  // Writes what is queued; while replaying and nothing is queued, reads the next page of the
  // replay (outside the lock: publishers are not held up by the store) or, at its end, releases
  // the buffered live alerts and queues the marker. Runs on the reactor's own calls (the
  // constructor, OnWriteDone), never two at a time.
  void Pump() override {
    Shared& s = shared();
    for (;;) {
      std::string id;
      absl::Time since;
      bool include_revised = false;
      std::optional<storage::AlertPosition> after;
      {
        absl::MutexLock lock(&s.mu);
        if (s.finished) return;
        if (!s.replaying || !s.queue.empty()) {
          TryWrite(s);
          return;
        }
        if (s.feed.read || s.feed.since == absl::InfiniteFuture()) {
          CompleteReplay(s);
          return;
        }
        id = s.feed.spacecraft_id;
        since = s.feed.since;
        include_revised = s.feed.include_revised;
        after = s.feed.after;
      }
      storage::AlertStore& store = core()->storage().alerts();
      absl::StatusOr<std::vector<storage::AlertRecord>> page =
          after.has_value() ? store.Since(id, since, *after, kAlertReplayPage, include_revised)
                            : store.Since(id, since, kAlertReplayPage, include_revised);
      absl::MutexLock lock(&s.mu);
      if (s.finished) return;
      if (!page.ok()) {
        FinishOnce(s, page.status());
        return;
      }
      int64_t page_bytes = 0;
      for (const storage::AlertRecord& r : *page) page_bytes += AlertFeed::RecordBytes(r);
      if (absl::Status charged = s.hold.queue.Charge(page_bytes); !charged.ok()) {
        FinishOnce(s, absl::ResourceExhaustedError(absl::StrCat(
                          "alert replay stopped: the page of ", page->size(),
                          " stored alerts read for it (", page_bytes,
                          " bytes) would pass the bound: ", charged.message(),
                          "; subscribe again with since = the latest measurement_time received")));
        NoteFreedMemory(page_bytes);
        return;
      }
      for (const storage::AlertRecord& r : *page) Offer(s, r);
      s.hold.queue.Refund(page_bytes);
      if (static_cast<int64_t>(page->size()) < kAlertReplayPage) {
        s.feed.read = true;
      } else {
        const storage::AlertRecord& last = page->back();
        s.feed.after = storage::AlertPosition{last.measurement_time, last.spacecraft_id,
                                              last.sequence};
      }
    }
  }
};

}  // namespace

grpc::ServerWriteReactor<esg::v1::Alert>* NewAlertReactor(CallCounter* calls, EstimationCore* core,
                                                          const esg::v1::AlertSubscription& request,
                                                          absl::StatusOr<SubscriptionHold> hold) {
  return new AlertReactor(calls, core, request, std::move(hold));
}

}  // namespace esg::server
