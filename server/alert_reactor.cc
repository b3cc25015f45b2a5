// The SubscribeAlerts reactor; what it guarantees is stated in alert_reactor.h.
#include "server/alert_reactor.h"

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "proto/convert.h"
#include "server/grpc_status.h"
#include "server/proto_mapping.h"
#include "storage/records.h"

namespace esg::server {
namespace {

constexpr size_t kMaxQueuedAlerts = 100000;

class AlertReactor : public grpc::ServerWriteReactor<esg::v1::Alert> {
 public:
  AlertReactor(CallCounter* calls, EstimationCore* core, const esg::v1::AlertSubscription& request,
               absl::Status auth)
      : token_(calls), core_(core), shared_(std::make_shared<Shared>()) {
    shared_->reactor = this;
    if (auth.ok()) auth = core->CheckSpacecraft(request.spacecraft_id());
    absl::Time since = absl::InfiniteFuture();
    if (auth.ok() && request.has_since()) {
      absl::StatusOr<absl::Time> t = proto_convert::TimeFromProto(request.since());
      if (t.ok()) {
        since = *t;
      } else {
        auth =
            absl::InvalidArgumentError(std::string("since: ") + std::string(t.status().message()));
      }
    }
    if (!auth.ok()) {
      shared_->finished = true;
      Finish(ToGrpcStatus(auth));
      return;
    }
    std::weak_ptr<Shared> weak = shared_;
    subscription_ = core->alert_hub().Subscribe(
        request.spacecraft_id(),
        [weak](const storage::AlertRecord& r) {
          std::shared_ptr<Shared> s = weak.lock();
          if (s == nullptr) return;
          absl::MutexLock lock(&s->mu);
          if (s->replaying) {
            s->buffered.push_back(r);
          } else {
            Offer(*s, r, /*live=*/true);
            TryWrite(*s);
          }
        },
        [weak]() {
          std::shared_ptr<Shared> s = weak.lock();
          if (s == nullptr) return;
          absl::MutexLock lock(&s->mu);
          if (!s->finished && s->reactor != nullptr) {
            s->finished = true;
            s->reactor->Finish(ToGrpcStatus(absl::UnavailableError("the server is shutting down")));
          }
        });
    std::vector<storage::AlertRecord> replay;
    if (since != absl::InfiniteFuture()) {
      absl::StatusOr<std::vector<storage::AlertRecord>> stored = core->storage().alerts().Since(
          request.spacecraft_id(), since, kMaxQueuedAlerts, request.include_revised());
      if (!stored.ok()) {
        absl::MutexLock lock(&shared_->mu);
        shared_->finished = true;
        Finish(ToGrpcStatus(stored.status()));
        return;
      }
      replay = std::move(*stored);
    }
    absl::MutexLock lock(&shared_->mu);
    for (const storage::AlertRecord& r : replay) Offer(*shared_, r, /*live=*/false);
    for (const storage::AlertRecord& r : shared_->buffered) Offer(*shared_, r, /*live=*/false);
    shared_->buffered.clear();
    shared_->replaying = false;
    if (request.replay_marker() && !shared_->finished) {
      esg::v1::Alert marker;
      marker.set_replay_complete(true);
      shared_->queue.push_back(std::move(marker));
    }
    TryWrite(*shared_);
  }

  void OnWriteDone(bool ok) override {
    absl::MutexLock lock(&shared_->mu);
    shared_->writing = false;
    if (!ok) {
      if (!shared_->finished) {
        shared_->finished = true;
        Finish(ToGrpcStatus(absl::CancelledError("the client went away")));
      }
      return;
    }
    shared_->queue.pop_front();
    TryWrite(*shared_);
  }

  void OnCancel() override {
    absl::MutexLock lock(&shared_->mu);
    if (!shared_->finished) {
      shared_->finished = true;
      Finish(ToGrpcStatus(absl::CancelledError("the client went away")));
    }
  }

  void OnDone() override {
    if (subscription_ != 0) core_->alert_hub().Unsubscribe(subscription_);
    {
      absl::MutexLock lock(&shared_->mu);
      shared_->reactor = nullptr;
    }
    delete this;
  }

 private:
  // repeat_count, acknowledged, cleared, revised (a re-run over a late frame superseded it)
  using Version = std::tuple<int64_t, bool, bool, bool>;
  struct Shared {
    absl::Mutex mu;
    AlertReactor* reactor ABSL_GUARDED_BY(mu) = nullptr;
    bool replaying ABSL_GUARDED_BY(mu) = true;
    std::vector<storage::AlertRecord> buffered ABSL_GUARDED_BY(mu);
    std::deque<esg::v1::Alert> queue ABSL_GUARDED_BY(mu);
    std::map<std::pair<std::string, int64_t>, Version> sent ABSL_GUARDED_BY(mu);
    bool writing ABSL_GUARDED_BY(mu) = false;
    bool finished ABSL_GUARDED_BY(mu) = false;
  };

  // Queues `r` unless that state of the alert was already queued. While the replay is merged
  // with the changes buffered during it, their order is unknown, so only a newer state is queued
  // (a count that grew, an acknowledgement, a clear, a revision). Live changes come in commit
  // order (AlertHub), so any state other than the last one sent is queued: a re-run over a late
  // frame may set a repeat count back or undo a clear (docs/service.md "Several ground
  // stations"), and the subscriber must end with the stored state.
  static void Offer(Shared& s, const storage::AlertRecord& r, bool live)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    const Version v{r.repeat_count, r.acknowledged, r.cleared,
                    r.revised_time != absl::InfinitePast()};
    auto [it, inserted] = s.sent.try_emplace({r.spacecraft_id, r.sequence}, v);
    if (!inserted && live) {
      if (v == it->second) return;  // the replay already sent this state
      // An acknowledgement is never undone: an unacknowledged state after an acknowledged one
      // was read before the acknowledgement committed (a new alert acknowledged between its
      // commit and its publication); the stored alert is acknowledged.
      if (std::get<1>(it->second) && !std::get<1>(v)) return;
      it->second = v;
    } else if (!inserted) {
      const Version& old = it->second;
      // A revision is news even where a re-run set the repeat count back.
      const bool revision = std::get<3>(v) && !std::get<3>(old);
      if (!revision && std::get<0>(v) <= std::get<0>(old) && std::get<1>(v) <= std::get<1>(old) &&
          std::get<2>(v) <= std::get<2>(old) && std::get<3>(v) <= std::get<3>(old)) {
        return;  // not newer
      }
      it->second =
          Version{std::max(std::get<0>(v), std::get<0>(old)), std::get<1>(v) || std::get<1>(old),
                  std::get<2>(v) || std::get<2>(old), std::get<3>(v) || std::get<3>(old)};
    }
    if (s.queue.size() >= kMaxQueuedAlerts) {
      if (!s.finished && s.reactor != nullptr) {
        s.finished = true;
        s.reactor->Finish(ToGrpcStatus(
            absl::ResourceExhaustedError("alert subscriber too slow: queue limit reached")));
      }
      return;
    }
    s.queue.push_back(AlertToProto(r));
  }

  static void TryWrite(Shared& s) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    if (s.finished || s.writing || s.reactor == nullptr || s.queue.empty()) return;
    s.writing = true;
    s.reactor->StartWrite(&s.queue.front());
  }

  CallCounter::Token token_;
  EstimationCore* core_;
  std::shared_ptr<Shared> shared_;
  int64_t subscription_ = 0;
};

}  // namespace

grpc::ServerWriteReactor<esg::v1::Alert>* NewAlertReactor(CallCounter* calls, EstimationCore* core,
                                                          const esg::v1::AlertSubscription& request,
                                                          absl::Status auth) {
  return new AlertReactor(calls, core, request, std::move(auth));
}

}  // namespace esg::server
