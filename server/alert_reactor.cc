// The SubscribeAlerts reactor; what it guarantees is stated in alert_reactor.h, the replay and
// live skeleton it shares with SubscribeEstimates in subscription_reactor.h.
#include "server/alert_reactor.h"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <limits>
#include <map>
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
#include "storage/records.h"

namespace esg::server {
namespace {

constexpr size_t kMaxQueuedAlerts = 100000;

// What a SubscribeAlerts stream has sent of each alert (subscription_reactor.h "Feed").
class AlertFeed {
 public:
  using Record = storage::AlertRecord;
  using Message = esg::v1::Alert;
  static constexpr size_t kMaxQueued = kMaxQueuedAlerts;
  // The replay is one read of at most kMaxQueuedAlerts alerts; the live alerts buffered during it
  // are not counted (the queue's limit applies as they are released).
  static constexpr size_t kMaxBuffered = std::numeric_limits<size_t>::max();
  static std::string TooSlowMessage() { return "alert subscriber too slow: queue limit reached"; }
  static std::string DroppedMessage(absl::string_view why) {
    return absl::StrCat("alert subscriber too slow, dropped: ", why,
                        "; subscribe again with since = the latest measurement_time received");
  }
  static Message ToProto(const Record& r) { return AlertToProto(r); }

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
  // The live rule above needs every alert's last state sent: nothing is forgotten.
  void ReplayComplete() {}

 private:
  // repeat_count, acknowledged, cleared, revised (a re-run over a late frame superseded it)
  using Version = std::tuple<int64_t, bool, bool, bool>;
  std::map<std::pair<std::string, int64_t>, Version> sent_;
};

// The replay is one read of the alert store, merged at once with what was buffered meanwhile.
class AlertReactor : public SubscriptionReactor<AlertFeed> {
 public:
  AlertReactor(CallCounter* calls, EstimationCore* core, const esg::v1::AlertSubscription& request,
               absl::StatusOr<SubscriptionHold> hold)
      : SubscriptionReactor(calls, core, &core->alert_hub(), std::move(hold)) {
    absl::Time since;
    if (!Accept(request, &since)) return;
    Subscribe(request.spacecraft_id());
    std::vector<storage::AlertRecord> replay;
    if (since != absl::InfiniteFuture()) {
      absl::StatusOr<std::vector<storage::AlertRecord>> stored = core->storage().alerts().Since(
          request.spacecraft_id(), since, kMaxQueuedAlerts, request.include_revised());
      if (!stored.ok()) {
        absl::MutexLock lock(&shared().mu);
        FinishOnce(shared(), stored.status());
        return;
      }
      replay = std::move(*stored);
    }
    Shared& s = shared();
    absl::MutexLock lock(&s.mu);
    for (const storage::AlertRecord& r : replay) Offer(s, r);
    CompleteReplay(s);
  }
};

}  // namespace

grpc::ServerWriteReactor<esg::v1::Alert>* NewAlertReactor(CallCounter* calls, EstimationCore* core,
                                                          const esg::v1::AlertSubscription& request,
                                                          absl::StatusOr<SubscriptionHold> hold) {
  return new AlertReactor(calls, core, request, std::move(hold));
}

}  // namespace esg::server
