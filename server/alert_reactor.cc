// The SubscribeAlerts reactor; what it guarantees is stated in alert_reactor.h, the replay and
// live skeleton it shares with SubscribeEstimates in subscription_reactor.h.
#include "server/alert_reactor.h"

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/alert_feed.h"
#include "server/subscription_reactor.h"
#include "storage/alert_store.h"
#include "storage/records.h"

namespace esg::server {
namespace {

// Stored alerts read at a time by the replay: about 1.5 MB at 1.3 KB an alert.
constexpr int64_t kAlertReplayPage = 1000;

// The replay is read kAlertReplayPage alerts at a time, each page once the previous one is
// written and charged to the caller's bound while it is held (SubscriptionReactor::OfferPage).
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
        if (!ReadyForPage(s, s.feed.read || s.feed.since == absl::InfiniteFuture())) return;
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
      if (!OfferPage(s, page.status(), page.ok() ? &*page : nullptr)) return;
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
