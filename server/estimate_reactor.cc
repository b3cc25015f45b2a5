// The SubscribeEstimates reactor; what it guarantees is stated in estimate_reactor.h.
#include "server/estimate_reactor.h"

#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "proto/convert.h"
#include "server/grpc_status.h"
#include "server/proto_mapping.h"
#include "storage/estimate_store.h"
#include "storage/records.h"

namespace esg::server {
namespace {

constexpr size_t kMaxQueuedEstimates = 50000;
constexpr int64_t kEstimateReplayPage = 500;

class EstimateReactor : public grpc::ServerWriteReactor<esg::v1::EstimateRecord> {
 public:
  EstimateReactor(CallCounter* calls, EstimationCore* core,
                  const esg::v1::EstimateSubscription& request, absl::Status auth)
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
    {
      absl::MutexLock lock(&shared_->mu);
      shared_->since = since;
      shared_->marker = request.replay_marker();
      if (since != absl::InfiniteFuture()) {
        shared_->ids = request.spacecraft_id().empty()
                           ? core->SpacecraftIds()
                           : std::vector<std::string>{request.spacecraft_id()};
      }
    }
    std::weak_ptr<Shared> weak = shared_;
    subscription_ = core->estimate_hub().Subscribe(
        request.spacecraft_id(),
        [weak](const storage::EstimateRecord& r) {
          std::shared_ptr<Shared> s = weak.lock();
          if (s == nullptr) return;
          absl::MutexLock lock(&s->mu);
          if (s->finished) return;
          if (s->replaying) {
            if (s->buffered.size() >= kMaxQueuedEstimates) {
              TooSlow(*s);
              return;
            }
            s->buffered.push_back(r);
          } else {
            Offer(*s, r);
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
    Pump();
  }

  void OnWriteDone(bool ok) override {
    {
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
    }
    Pump();
  }

  void OnCancel() override {
    absl::MutexLock lock(&shared_->mu);
    if (!shared_->finished) {
      shared_->finished = true;
      Finish(ToGrpcStatus(absl::CancelledError("the client went away")));
    }
  }

  void OnDone() override {
    if (subscription_ != 0) core_->estimate_hub().Unsubscribe(subscription_);
    {
      absl::MutexLock lock(&shared_->mu);
      shared_->reactor = nullptr;
    }
    delete this;
  }

 private:
  using Key = std::pair<std::string, absl::Time>;  // (spacecraft, measurement time)
  struct Shared {
    absl::Mutex mu;
    EstimateReactor* reactor ABSL_GUARDED_BY(mu) = nullptr;
    bool replaying ABSL_GUARDED_BY(mu) = true;
    // The replay's position: spacecraft ids[index], after the measurement time `after`.
    std::vector<std::string> ids ABSL_GUARDED_BY(mu);
    size_t index ABSL_GUARDED_BY(mu) = 0;
    std::optional<absl::Time> after ABSL_GUARDED_BY(mu);
    absl::Time since ABSL_GUARDED_BY(mu) = absl::InfiniteFuture();
    bool marker ABSL_GUARDED_BY(mu) = false;
    std::vector<storage::EstimateRecord> buffered ABSL_GUARDED_BY(mu);
    // Compute time of the latest record queued per key, until the buffer is released.
    std::map<Key, absl::Time> sent ABSL_GUARDED_BY(mu);
    std::deque<esg::v1::EstimateRecord> queue ABSL_GUARDED_BY(mu);
    bool writing ABSL_GUARDED_BY(mu) = false;
    bool finished ABSL_GUARDED_BY(mu) = false;
  };

  static void TooSlow(Shared& s) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    if (!s.finished && s.reactor != nullptr) {
      s.finished = true;
      s.reactor->Finish(ToGrpcStatus(absl::ResourceExhaustedError(absl::StrCat(
          "estimate subscriber too slow: ", kMaxQueuedEstimates,
          " estimates waiting; subscribe again with since = the last measurement_time received"))));
    }
  }

  // Queues `r` unless, while replay and live overlap, the same or a later computation of its
  // step was already queued.
  static void Offer(Shared& s, const storage::EstimateRecord& r)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    if (s.replaying) {
      auto [it, inserted] =
          s.sent.try_emplace({r.spacecraft_id, r.measurement_time}, r.compute_time);
      if (!inserted) {
        if (it->second >= r.compute_time) return;
        it->second = r.compute_time;
      }
    }
    if (s.queue.size() >= kMaxQueuedEstimates) {
      TooSlow(s);
      return;
    }
    s.queue.push_back(EstimateToProto(r));
  }

  static void TryWrite(Shared& s) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    if (s.finished || s.writing || s.reactor == nullptr || s.queue.empty()) return;
    s.writing = true;
    s.reactor->StartWrite(&s.queue.front());
  }

  // Writes what is queued; while replaying and nothing is queued, reads the next page of the
  // replay (outside the lock: publishers are not held up by SQLite) or, at its end, releases
  // the buffered live estimates and queues the marker. Runs on the reactor's own calls (the
  // constructor, OnWriteDone), never two at a time.
  void Pump() {
    for (;;) {
      std::string id;
      std::optional<absl::Time> after;
      absl::Time since;
      {
        absl::MutexLock lock(&shared_->mu);
        Shared& s = *shared_;
        if (s.finished) return;
        if (!s.replaying || !s.queue.empty()) {
          TryWrite(s);
          return;
        }
        if (s.index >= s.ids.size()) {
          // The replay is complete: the live estimates that came meanwhile, then the marker.
          for (const storage::EstimateRecord& r : s.buffered) Offer(s, r);
          s.buffered.clear();
          s.replaying = false;
          s.sent.clear();
          if (s.marker && !s.finished) {
            esg::v1::EstimateRecord marker;
            marker.set_replay_complete(true);
            s.queue.push_back(std::move(marker));
          }
          TryWrite(s);
          return;
        }
        id = s.ids[s.index];
        after = s.after;
        since = s.since;
      }
      if (core_->options().before_estimate_replay_page) {
        core_->options().before_estimate_replay_page(id);
      }
      absl::StatusOr<storage::EstimatePage> page = core_->storage().estimates().Page(
          id, since, absl::InfiniteFuture(), after, kEstimateReplayPage);
      absl::MutexLock lock(&shared_->mu);
      Shared& s = *shared_;
      if (!page.ok()) {
        if (!s.finished) {
          s.finished = true;
          Finish(ToGrpcStatus(page.status()));
        }
        return;
      }
      for (const storage::EstimateRecord& r : page->records) Offer(s, r);
      if (page->next.has_value()) {
        s.after = page->next;
      } else {
        ++s.index;
        s.after.reset();
      }
    }
  }

  CallCounter::Token token_;
  EstimationCore* core_;
  std::shared_ptr<Shared> shared_;
  int64_t subscription_ = 0;
};

}  // namespace

grpc::ServerWriteReactor<esg::v1::EstimateRecord>* NewEstimateReactor(
    CallCounter* calls, EstimationCore* core, const esg::v1::EstimateSubscription& request,
    absl::Status auth) {
  return new EstimateReactor(calls, core, request, std::move(auth));
}

}  // namespace esg::server
