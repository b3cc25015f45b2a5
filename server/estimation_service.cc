// Reactors of the esg.v1.EstimationService (see estimation_service.h, docs/service.md).
#include "server/estimation_service.h"

#include <atomic>
#include <chrono>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <thread>
#include <tuple>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "proto/convert.h"
#include "server/grpc_status.h"
#include "server/log.h"
#include "server/proto_mapping.h"
#include "server/service_metrics.h"
#include "server/spacecraft_scope.h"

namespace esg::server {
namespace {

// The reactor of a unary call: counted until gRPC is done with the call (its response sent).
class UnaryReactor : public grpc::ServerUnaryReactor {
 public:
  explicit UnaryReactor(CallCounter* calls) : token_(calls) {}
  void OnDone() override { delete this; }

 private:
  CallCounter::Token token_;
};

// Unary rpcs: run `work` (returning absl::StatusOr<Response>) and finish.
template <typename Response, typename Work>
grpc::ServerUnaryReactor* Unary(CallCounter* calls, absl::Status auth, Response* response,
                                Work work) {
  grpc::ServerUnaryReactor* reactor = new UnaryReactor(calls);
  if (!auth.ok()) {
    reactor->Finish(ToGrpcStatus(auth));
    return reactor;
  }
  absl::StatusOr<Response> result = work();
  if (result.ok()) *response = std::move(*result);
  reactor->Finish(ToGrpcStatus(result.status()));
  return reactor;
}

// ---- StreamTelemetry ------------------------------------------------------------------------
// Acks leave in frame order; an ack waiting for durability holds back the ones behind it. At
// most kMaxInFlight frames are waiting for their ack before the stream stops reading (flow
// control back to the client).
constexpr size_t kMaxInFlight = 4096;

class TelemetryReactor
    : public grpc::ServerBidiReactor<esg::v1::TelemetryFrame, esg::v1::TelemetryAck> {
 public:
  // `scope`: the spacecraft the stream is routed by (server/spacecraft_scope.h), or empty.
  TelemetryReactor(CallCounter* calls, EstimationCore* core, const absl::Status& auth,
                   std::string peer, std::string scope)
      : token_(calls),
        core_(core),
        shared_(std::make_shared<Shared>()),
        peer_(std::move(peer)),
        scope_(std::move(scope)) {
    shared_->reactor = this;
    shared_->metrics = &core->metrics();
    if (!auth.ok()) {
      shared_->finished = true;
      Finish(ToGrpcStatus(auth));
      return;
    }
    StartRead(&frame_);
  }

  void OnReadDone(bool ok) override {
    if (!ok) {
      absl::MutexLock lock(&shared_->mu);
      shared_->reads_done = true;
      TryWrite(*shared_);
      return;
    }
    auto slot = std::make_shared<Slot>();
    slot->received = std::chrono::steady_clock::now();
    shared_->metrics->frames_received.With({StationLabel(frame_.station_id())}).Increment();
    {
      absl::MutexLock lock(&shared_->mu);
      ++shared_->frames_received;
      shared_->slots.push_back(slot);
    }
    std::weak_ptr<Shared> weak = shared_;
    const absl::StatusOr<bool> wait =
        core_->Ingest(frame_, &slot->ack, [weak, slot](absl::Status stored) {
          std::shared_ptr<Shared> shared = weak.lock();
          if (shared == nullptr) return;
          absl::MutexLock lock(&shared->mu);
          if (stored.ok()) {
            slot->ready = true;
          } else {
            // Not stored: the stream fails once the acks before this frame are out; the client
            // resumes from its highest durable sequence.
            slot->failure = std::move(stored);
          }
          TryWrite(*shared);
        },
        scope_);
    absl::MutexLock lock(&shared_->mu);
    if (!wait.ok()) {
      slot->failure = wait.status();
    } else if (!*wait) {
      slot->ready = true;
    }
    TryWrite(*shared_);
    if (shared_->finished) return;
    if (!wait.ok()) return;  // no more reads: the stream ends with this frame's failure
    if (shared_->slots.size() < kMaxInFlight) {
      StartRead(&frame_);
    } else {
      shared_->read_paused = true;
    }
  }

  void OnWriteDone(bool ok) override {
    absl::MutexLock lock(&shared_->mu);
    shared_->writing = false;
    if (!ok) {  // the client is gone
      if (!shared_->finished) {
        shared_->finished = true;
        CountUnacknowledged(*shared_, absl::StatusCode::kCancelled);
        Finish(ToGrpcStatus(absl::CancelledError("the client went away")));
      }
      return;
    }
    shared_->slots.pop_front();
    if (shared_->read_paused && shared_->slots.size() < kMaxInFlight / 2 && !shared_->finished) {
      shared_->read_paused = false;
      StartRead(&frame_);
    }
    TryWrite(*shared_);
  }

  void OnCancel() override {
    absl::MutexLock lock(&shared_->mu);
    if (!shared_->finished) {
      shared_->finished = true;
      CountUnacknowledged(*shared_, absl::StatusCode::kCancelled);
      Finish(ToGrpcStatus(absl::CancelledError("the client went away")));
    }
  }

  void OnDone() override {
    std::string summary;
    int64_t received = 0;
    int64_t acknowledged = 0;
    int64_t refused = 0;
    int64_t unacknowledged = 0;
    {
      absl::MutexLock lock(&shared_->mu);
      shared_->reactor = nullptr;
      received = shared_->frames_received;
      acknowledged = shared_->frames_acknowledged;
      refused = shared_->frames_refused;
      unacknowledged = shared_->frames_unacknowledged;
      for (const auto& [reason, n] : shared_->refusals) {
        absl::StrAppend(&summary, summary.empty() ? "" : ", ", n, " ", reason);
      }
    }
    // A stream that refused frames or ended before acknowledging all of them is summarised once,
    // when it ends (each refusal itself is in the client's ack).
    if (refused > 0 || unacknowledged > 0) {
      LogEvent("WARN", "stream_refusals",
               absl::StrCat("telemetry stream from ", peer_.empty() ? "unknown" : peer_, " ended: ",
                            received, " frames received, ", acknowledged, " acknowledged, ",
                            refused, " refused", summary.empty() ? "" : " (", summary,
                            summary.empty() ? "" : ")", ", ", unacknowledged,
                            " not acknowledged (stream failed)"),
               {{"peer", peer_},
                {"framesReceived", received},
                {"framesAcknowledged", acknowledged},
                {"framesRefused", refused},
                {"framesUnacknowledged", unacknowledged}});
    }
    delete this;
  }

 private:
  struct Slot {
    std::chrono::steady_clock::time_point received;
    esg::v1::TelemetryAck ack;
    bool ready = false;    // guarded by Shared::mu
    absl::Status failure;  // guarded by Shared::mu; not OK: fail the stream here, no ack
  };
  // State shared with the committer's callbacks, which may outlive the reactor.
  struct Shared {
    absl::Mutex mu;
    TelemetryReactor* reactor ABSL_GUARDED_BY(mu) = nullptr;
    std::deque<std::shared_ptr<Slot>> slots ABSL_GUARDED_BY(mu);
    bool writing ABSL_GUARDED_BY(mu) = false;
    bool reads_done ABSL_GUARDED_BY(mu) = false;
    bool read_paused ABSL_GUARDED_BY(mu) = false;
    bool finished ABSL_GUARDED_BY(mu) = false;
    ServiceMetrics* metrics = nullptr;
    // This stream's counts, for the summary logged when it ends.
    int64_t frames_received ABSL_GUARDED_BY(mu) = 0;
    int64_t frames_acknowledged ABSL_GUARDED_BY(mu) = 0;
    int64_t frames_refused ABSL_GUARDED_BY(mu) = 0;
    int64_t frames_unacknowledged ABSL_GUARDED_BY(mu) = 0;
    std::map<std::string, int64_t> refusals ABSL_GUARDED_BY(mu);  // "REASON field" -> count
  };

  // The frames read and not acknowledged when the stream ends with `code`.
  static void CountUnacknowledged(Shared& s, absl::StatusCode code)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    if (s.slots.empty()) return;
    s.frames_unacknowledged += static_cast<int64_t>(s.slots.size());
    s.metrics->frames_unacknowledged.With({absl::StatusCodeToString(code)})
        .Increment(static_cast<double>(s.slots.size()));
  }

  // Counts the ack about to be written (metrics and the stream's summary).
  static void CountAck(Shared& s, const Slot& slot) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    const esg::v1::TelemetryAck& ack = slot.ack;
    const std::string station = StationLabel(ack.station_id());
    s.metrics->ack_latency.Observe(std::chrono::duration<double>(
                                        std::chrono::steady_clock::now() - slot.received)
                                        .count());
    if (ack.accepted()) {
      ++s.frames_acknowledged;
      s.metrics->frames_acknowledged.With({station, ack.duplicate() ? "duplicate" : "new"})
          .Increment();
      return;
    }
    ++s.frames_refused;
    const std::string reason =
        absl::StatusCodeToString(static_cast<absl::StatusCode>(ack.rejection().code()));
    const std::string field = FieldLabel(ack.rejection().field());
    ++s.refusals[absl::StrCat(reason, " ", field)];
    s.metrics->frames_refused.With({station, reason, field}).Increment();
  }

  // Sends the next ack if it is ready, or finishes when everything is acknowledged.
  static void TryWrite(Shared& s) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    if (s.finished || s.writing || s.reactor == nullptr) return;
    if (!s.slots.empty()) {
      Slot& front = *s.slots.front();
      if (!front.failure.ok()) {
        s.finished = true;
        CountUnacknowledged(s, front.failure.code());
        s.reactor->Finish(ToGrpcStatus(front.failure));
        return;
      }
      if (!front.ready) return;
      s.reactor->core_->FillDurable(&front.ack);
      CountAck(s, front);
      s.writing = true;
      s.reactor->StartWrite(&front.ack);
      return;
    }
    if (s.reads_done) {
      s.finished = true;
      s.reactor->Finish(ToGrpcStatus(absl::OkStatus()));
    }
  }

  CallCounter::Token token_;
  EstimationCore* core_;
  std::shared_ptr<Shared> shared_;
  const std::string peer_;
  const std::string scope_;
  esg::v1::TelemetryFrame frame_;
};

// ---- SubscribeAlerts ------------------------------------------------------------------------
// Subscribes to the live feed first, then replays the store, then releases the live alerts that
// arrived meanwhile, then (replay_marker) queues the end-of-replay marker; every alert state
// (sequence, repeat_count, acknowledged, cleared) is sent at most once and never after a newer
// state of the same alert. Live alerts published after the marker was queued follow it.
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
      absl::StatusOr<std::vector<storage::AlertRecord>> stored =
          core->storage().alerts().Since(request.spacecraft_id(), since, kMaxQueuedAlerts,
                                         request.include_revised());
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
      it->second = Version{std::max(std::get<0>(v), std::get<0>(old)),
                           std::get<1>(v) || std::get<1>(old), std::get<2>(v) || std::get<2>(old),
                           std::get<3>(v) || std::get<3>(old)};
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

// ---- SubscribeEstimates ---------------------------------------------------------------------
// Subscribes to the live feed first, then replays the stored estimates at or after `since` (per
// spacecraft in id order, each in measurement-time order) one page at a time, reading the next
// page only once the previous one is written (a slow client holds at most a page of the replay),
// then releases the live estimates that arrived meanwhile, then (replay_marker) queues the
// end-of-replay marker. Replay and live are merged without gap (everything committed before the
// subscription is stored, everything committed after is published to it) or duplicate: until
// the live estimates buffered during the replay are released, a record is queued only if no
// record of the same (spacecraft, measurement time) with the same or a later compute time was
// (a re-run's recomputed step has a later compute time, so it still goes out). Afterwards live
// estimates are queued as published. A subscriber with kMaxQueuedEstimates live estimates
// waiting is finished with RESOURCE_EXHAUSTED, as slow alert subscribers are.
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
      auto [it, inserted] = s.sent.try_emplace({r.spacecraft_id, r.measurement_time},
                                               r.compute_time);
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

// Export streams: `next` produces the next chunk (nullopt: the export is complete) on the callback
// thread, since a chunk is one bounded SQLite read (EstimationCore::kExportChunkSize records),
// like a unary list call. One write in flight: the next chunk is read only once the client took
// the previous one (gRPC flow control), so a slow client holds no more than one chunk. An error
// finishes the call with its status after the chunks already sent; a client that goes away
// ends it with CANCELLED.
namespace {
template <typename Response>
class ExportReactor : public grpc::ServerWriteReactor<Response> {
 public:
  using Next = std::function<absl::StatusOr<std::optional<Response>>()>;
  ExportReactor(CallCounter* calls, const absl::Status& auth, Next next)
      : token_(calls), next_(std::move(next)) {
    if (!auth.ok()) {
      this->Finish(ToGrpcStatus(auth));
      return;
    }
    WriteNext();
  }

  void OnWriteDone(bool ok) override {
    if (!ok) {
      this->Finish(ToGrpcStatus(absl::CancelledError("the client went away")));
      return;
    }
    WriteNext();
  }

  void OnDone() override { delete this; }

 private:
  CallCounter::Token token_;
  void WriteNext() {
    absl::StatusOr<std::optional<Response>> chunk = next_();
    if (!chunk.ok()) {
      this->Finish(ToGrpcStatus(chunk.status()));
      return;
    }
    if (!chunk->has_value()) {
      this->Finish(ToGrpcStatus(absl::OkStatus()));
      return;
    }
    current_ = std::move(**chunk);
    this->StartWrite(&current_);
  }

  Next next_;
  Response current_;  // the chunk being written
};
}  // namespace

// Diagnose: the diagnosis runs on its own thread (it takes seconds; gRPC threads must not
// block). Progress updates are coalesced: at most one write in flight, the newest update waiting.
// The final update carries the result; an error finishes the call with its status. When the
// call is cancelled (the client went away, its deadline passed, the server shuts down) or a
// write fails, the diagnosis is told through its cancellation predicate, stops at its next
// check and stores nothing; the call then finishes with CANCELLED. The permit (the caller's
// diagnosis slot) is given back as soon as the worker is done.
class DiagnoseReactor : public grpc::ServerWriteReactor<esg::v1::DiagnoseUpdate> {
 public:
  // `permit` holds the caller's slot, or why the call is refused (role, limit).
  DiagnoseReactor(CallCounter* calls, EstimationCore* core, esg::v1::DiagnoseRequest request,
                  absl::StatusOr<CallLimiter::Permit> permit)
      : token_(calls) {
    if (!permit.ok()) {
      finished_ = true;
      Finish(ToGrpcStatus(permit.status()));
      return;
    }
    worker_ = std::thread(
        [this, core, request = std::move(request), permit = std::move(*permit)]() mutable {
          absl::StatusOr<esg::v1::DiagnosisResult> result = core->Diagnose(
              request, [this](double fraction, const std::string& stage) { Post(fraction, stage); },
              [this] { return cancelled_.load(std::memory_order_relaxed); });
          permit.Release();
          absl::MutexLock lock(&mu_);
          worker_done_ = true;
          if (result.ok()) {
            final_.set_progress(1.0);
            final_.set_stage("done");
            *final_.mutable_result() = std::move(*result);
            have_final_ = true;
          } else {
            status_ = result.status();
          }
          MaybeWriteLocked();
        });
  }

  void OnWriteDone(bool ok) override {
    absl::MutexLock lock(&mu_);
    writing_ = false;
    if (!ok) {  // the client went away: stop the diagnosis; finish once the worker is done
      broken_ = true;
      cancelled_ = true;
    }
    MaybeWriteLocked();
  }

  void OnCancel() override {
    absl::MutexLock lock(&mu_);
    broken_ = true;
    cancelled_ = true;
    MaybeWriteLocked();
  }

  void OnDone() override {
    if (worker_.joinable()) worker_.join();
    delete this;
  }

 private:
  CallCounter::Token token_;
  void Post(double fraction, const std::string& stage) {
    absl::MutexLock lock(&mu_);
    pending_.set_progress(fraction);
    pending_.set_stage(stage);
    have_pending_ = true;
    MaybeWriteLocked();
  }

  void MaybeWriteLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
    if (writing_ || finished_) return;
    if (!broken_ && have_pending_) {
      current_ = pending_;
      have_pending_ = false;
      writing_ = true;
      StartWrite(&current_);
      return;
    }
    if (!worker_done_) return;
    if (!broken_ && have_final_) {
      current_ = final_;
      have_final_ = false;
      writing_ = true;
      StartWrite(&current_);
      return;
    }
    finished_ = true;
    Finish(ToGrpcStatus(broken_ ? absl::CancelledError("the client went away") : status_));
  }

  absl::Mutex mu_;
  esg::v1::DiagnoseUpdate pending_ ABSL_GUARDED_BY(mu_);
  esg::v1::DiagnoseUpdate final_ ABSL_GUARDED_BY(mu_);
  esg::v1::DiagnoseUpdate current_;  // the update being written
  bool have_pending_ ABSL_GUARDED_BY(mu_) = false;
  bool have_final_ ABSL_GUARDED_BY(mu_) = false;
  bool writing_ ABSL_GUARDED_BY(mu_) = false;
  bool worker_done_ ABSL_GUARDED_BY(mu_) = false;
  bool broken_ ABSL_GUARDED_BY(mu_) = false;
  bool finished_ ABSL_GUARDED_BY(mu_) = false;
  absl::Status status_ ABSL_GUARDED_BY(mu_);
  // Read by the diagnosis (its cancellation predicate) without the lock.
  std::atomic<bool> cancelled_{false};
  std::thread worker_;
};

void CallCounter::Enter() {
  absl::MutexLock lock(&mu_);
  ++running_;
}

void CallCounter::Leave() {
  absl::MutexLock lock(&mu_);
  --running_;
}

int64_t CallCounter::running() {
  absl::MutexLock lock(&mu_);
  return running_;
}

bool CallCounter::WaitIdle(absl::Time deadline) {
  absl::MutexLock lock(&mu_);
  return mu_.AwaitWithDeadline(absl::Condition(
                                   +[](int64_t* running) { return *running == 0; }, &running_),
                               deadline);
}

EstimationServiceImpl::EstimationServiceImpl(EstimationCore* core, const TokenAuthorizer* auth,
                                             const CallLimits& limits)
    : core_(core),
      auth_(auth),
      predictions_("PredictAttitude", "prediction", "predictions",
                   limits.max_predictions_per_caller, limits.max_predictions),
      diagnoses_("Diagnose", "diagnosis", "diagnoses", limits.max_diagnoses_per_caller,
                 limits.max_diagnoses) {
  for (int i = 0; i < predictions_.total(); ++i) pool_.emplace_back([this] { PredictionLoop(); });
}

EstimationServiceImpl::~EstimationServiceImpl() {
  {
    absl::MutexLock lock(&pool_mu_);
    pool_stop_ = true;
  }
  for (std::thread& t : pool_) t.join();
}

void EstimationServiceImpl::RunPrediction(absl::AnyInvocable<void() &&> task) {
  absl::MutexLock lock(&pool_mu_);
  pool_tasks_.push_back(std::move(task));
}

void EstimationServiceImpl::PredictionLoop() {
  while (true) {
    absl::AnyInvocable<void() &&> task;
    {
      absl::MutexLock lock(&pool_mu_);
      auto ready = [this]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(pool_mu_) {
        return pool_stop_ || !pool_tasks_.empty();
      };
      pool_mu_.Await(absl::Condition(&ready));
      if (pool_tasks_.empty()) return;  // stopping, nothing left
      task = std::move(pool_tasks_.front());
      pool_tasks_.pop_front();
    }
    std::move(task)();
  }
}

absl::Status EstimationServiceImpl::Authorize(grpc::CallbackServerContext* context,
                                              Role role) const {
  if (auth_ == nullptr) return absl::OkStatus();
  return auth_->Check(*context, role);
}

absl::Status EstimationServiceImpl::Authorize(grpc::CallbackServerContext* context, Role role,
                                              absl::string_view spacecraft_id) const {
  // The role first: a caller without one learns nothing about the routing.
  if (absl::Status allowed = Authorize(context, role); !allowed.ok()) return allowed;
  return CheckCallScope(*context, spacecraft_id);
}

absl::StatusOr<std::string> EstimationServiceImpl::Caller(grpc::CallbackServerContext* context,
                                                          Role role) const {
  if (auth_ != nullptr) return auth_->Authenticate(*context, role);
  return CallerFromPeer(context->peer());
}

grpc::ServerBidiReactor<esg::v1::TelemetryFrame, esg::v1::TelemetryAck>*
EstimationServiceImpl::StreamTelemetry(grpc::CallbackServerContext* context) {
  // The stream's scope is checked once, at its start; each frame is checked against it by the
  // ingest contract, so a frame of another spacecraft is refused and the stream goes on.
  absl::Status admitted = Authorize(context, Role::kWrite);
  absl::StatusOr<std::string> scope = SpacecraftScope(context->client_metadata());
  if (admitted.ok() && !scope.ok()) admitted = scope.status();
  return new TelemetryReactor(&calls_, core_, admitted, context->peer(),
                              scope.ok() ? *std::move(scope) : std::string());
}

grpc::ServerUnaryReactor* EstimationServiceImpl::ConfigureSpacecraft(
    grpc::CallbackServerContext* context, const esg::v1::ConfigureRequest* request,
    esg::v1::ConfigureResponse* response) {
  return Unary(&calls_, Authorize(context, Role::kWrite, request->config().spacecraft_id()),
               response, [&] { return core_->Configure(*request); });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::GetSession(
    grpc::CallbackServerContext* context, const esg::v1::GetSessionRequest* request,
    esg::v1::SessionInfo* response) {
  return Unary(&calls_, Authorize(context, Role::kRead, request->spacecraft_id()), response,
               [&] { return core_->GetSession(request->spacecraft_id()); });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::ListSessions(
    grpc::CallbackServerContext* context, const esg::v1::ListSessionsRequest* request,
    esg::v1::ListSessionsResponse* response) {
  // Names no spacecraft, so it has no routing scope: with x-esg-spacecraft it lists this node's
  // sessions like without (docs/service.md "Routing by spacecraft").
  return Unary(&calls_, Authorize(context, Role::kRead), response,
               [&] { return core_->ListSessions(*request); });
}

// The prediction runs on a prediction thread, never on the callback thread: a 48 h prediction
// at the sample limit takes long and would hold a gRPC thread. The estimator's Predict cannot be
// interrupted; its run is bounded by CoreOptions::max_prediction_samples and the horizon, and a
// call cancelled before its turn does not start. The permit is given back before Finish, so a
// client that sends its next prediction on the response is not refused.
grpc::ServerUnaryReactor* EstimationServiceImpl::PredictAttitude(
    grpc::CallbackServerContext* context, const esg::v1::PredictRequest* request,
    esg::v1::PredictResponse* response) {
  grpc::ServerUnaryReactor* reactor = new UnaryReactor(&calls_);
  absl::StatusOr<std::string> caller = Caller(context, Role::kRead);
  if (caller.ok()) {
    // Before a permit is taken: a misrouted call must not hold a prediction slot.
    if (absl::Status in_scope = CheckCallScope(*context, request->spacecraft_id());
        !in_scope.ok()) {
      caller = in_scope;
    }
  }
  if (!caller.ok()) {
    reactor->Finish(ToGrpcStatus(caller.status()));
    return reactor;
  }
  absl::StatusOr<CallLimiter::Permit> permit = predictions_.Acquire(*caller);
  if (!permit.ok()) {
    reactor->Finish(ToGrpcStatus(permit.status()));
    return reactor;
  }
  RunPrediction([this, context, request, response, reactor, permit = std::move(*permit)]() mutable {
    absl::Status status;
    if (context->IsCancelled()) {
      status = absl::CancelledError("PredictAttitude: cancelled before it started");
    } else {
      absl::StatusOr<esg::v1::PredictResponse> result = core_->Predict(*request);
      if (result.ok()) *response = std::move(*result);
      status = result.status();
    }
    permit.Release();
    reactor->Finish(ToGrpcStatus(status));
  });
  return reactor;
}

grpc::ServerWriteReactor<esg::v1::Alert>* EstimationServiceImpl::SubscribeAlerts(
    grpc::CallbackServerContext* context, const esg::v1::AlertSubscription* request) {
  return new AlertReactor(&calls_, core_, *request,
                          Authorize(context, Role::kRead, request->spacecraft_id()));
}

grpc::ServerUnaryReactor* EstimationServiceImpl::AcknowledgeAlert(
    grpc::CallbackServerContext* context, const esg::v1::AcknowledgeRequest* request,
    esg::v1::Alert* response) {
  // With a tokens file an empty operator_name means the caller's own token name, so a console
  // that signs each operator in with their token acknowledges under that operator's name.
  absl::StatusOr<std::string> token_name =
      auth_ != nullptr ? auth_->Authenticate(*context, Role::kWrite) : std::string();
  esg::v1::AcknowledgeRequest named = *request;
  if (token_name.ok() && named.operator_name().empty()) named.set_operator_name(*token_name);
  absl::Status admitted = token_name.status();
  if (admitted.ok()) admitted = CheckCallScope(*context, request->spacecraft_id());
  return Unary(
      &calls_, admitted, response,
      [this, named = std::move(named)]() -> absl::StatusOr<esg::v1::Alert> {
        absl::StatusOr<esg::v1::Alert> alert = core_->Acknowledge(named);
        if (!alert.ok()) return alert.status();
        // The store keeps the first acknowledgement; another operator's is refused so
        // that it is never silently dropped (the same operator again is idempotent).
        if (alert->acknowledged_by() != named.operator_name()) {
          absl::Status refused = absl::FailedPreconditionError(
              absl::StrCat("operator_name: alert ", alert->sequence(), " of spacecraft '",
                           alert->spacecraft_id(), "' was already acknowledged by '",
                           alert->acknowledged_by(), "' at ",
                           FormatUtc(proto_convert::TimeFromProto(alert->acknowledged_time())
                                         .value_or(absl::InfinitePast())),
                           "; the first acknowledgement stands"));
          LogEvent("WARN", "alert_acknowledgement_refused",
                   absl::StrCat("acknowledgement by '", named.operator_name(),
                                "' refused: ", refused.message()),
                   {{"spacecraftId", named.spacecraft_id()},
                    {"alertSequence", named.sequence()},
                    {"operator", named.operator_name()}});
          return refused;
        }
        return alert;
      });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::GetCoefficientHistory(
    grpc::CallbackServerContext* context, const esg::v1::HistoryRequest* request,
    esg::v1::HistoryResponse* response) {
  return Unary(&calls_, Authorize(context, Role::kRead, request->spacecraft_id()), response,
               [&] { return core_->History(*request); });
}

grpc::ServerWriteReactor<esg::v1::ExportCoefficientHistoryResponse>*
EstimationServiceImpl::ExportCoefficientHistory(
    grpc::CallbackServerContext* context, const esg::v1::ExportCoefficientHistoryRequest* request) {
  // The pages of GetCoefficientHistory at the export chunk size, followed by their tokens.
  esg::v1::HistoryRequest pages;
  pages.set_spacecraft_id(request->spacecraft_id());
  pages.set_gyro_id(request->gyro_id());
  if (request->has_from()) *pages.mutable_from() = request->from();
  if (request->has_to()) *pages.mutable_to() = request->to();
  pages.set_include_revised(request->include_revised());
  pages.set_page_size(static_cast<int32_t>(EstimationCore::kExportChunkSize));
  EstimationCore* core = core_;
  bool last_page = false;
  return new ExportReactor<esg::v1::ExportCoefficientHistoryResponse>(
      &calls_, Authorize(context, Role::kRead, request->spacecraft_id()),
      [core, pages, last_page]() mutable
      -> absl::StatusOr<std::optional<esg::v1::ExportCoefficientHistoryResponse>> {
        if (last_page) return std::nullopt;
        absl::StatusOr<esg::v1::HistoryResponse> page = core->History(pages);
        if (!page.ok()) return page.status();
        last_page = page->next_page_token().empty();
        pages.set_page_token(page->next_page_token());
        if (page->snapshots_size() == 0) return std::nullopt;
        esg::v1::ExportCoefficientHistoryResponse chunk;
        chunk.mutable_snapshots()->Swap(page->mutable_snapshots());
        return chunk;
      });
}

grpc::ServerWriteReactor<esg::v1::ExportTelemetryResponse>* EstimationServiceImpl::ExportTelemetry(
    grpc::CallbackServerContext* context, const esg::v1::ExportTelemetryRequest* request) {
  EstimationCore* core = core_;
  absl::Time after = absl::InfinitePast();
  bool done = false;
  return new ExportReactor<esg::v1::ExportTelemetryResponse>(
      &calls_, Authorize(context, Role::kRead, request->spacecraft_id()),
      [core, request = *request, after,
       done]() mutable -> absl::StatusOr<std::optional<esg::v1::ExportTelemetryResponse>> {
        if (done) return std::nullopt;
        absl::StatusOr<esg::v1::ExportTelemetryResponse> chunk =
            core->ExportTelemetryChunk(request, &after, &done);
        if (!chunk.ok()) return chunk.status();
        if (chunk->frames_size() == 0) return std::nullopt;
        return *std::move(chunk);
      });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::GetEstimateHistory(
    grpc::CallbackServerContext* context, const esg::v1::EstimateHistoryRequest* request,
    esg::v1::EstimateHistoryResponse* response) {
  return Unary(&calls_, Authorize(context, Role::kRead), response,
               [&] { return core_->EstimateHistory(*request); });
}

grpc::ServerWriteReactor<esg::v1::EstimateRecord>* EstimationServiceImpl::SubscribeEstimates(
    grpc::CallbackServerContext* context, const esg::v1::EstimateSubscription* request) {
  return new EstimateReactor(&calls_, core_, *request, Authorize(context, Role::kRead));
}

grpc::ServerWriteReactor<esg::v1::DiagnoseUpdate>* EstimationServiceImpl::Diagnose(
    grpc::CallbackServerContext* context, const esg::v1::DiagnoseRequest* request) {
  absl::StatusOr<std::string> caller = Caller(context, Role::kRead);
  if (caller.ok()) {
    // Before a permit is taken: a misrouted call must not hold the caller's diagnosis slot.
    if (absl::Status in_scope = CheckCallScope(*context, request->spacecraft_id());
        !in_scope.ok()) {
      caller = in_scope;
    }
  }
  return new DiagnoseReactor(&calls_, core_, *request,
                             caller.ok() ? diagnoses_.Acquire(*caller)
                                         : absl::StatusOr<CallLimiter::Permit>(caller.status()));
}

grpc::ServerUnaryReactor* EstimationServiceImpl::ListDiagnoses(
    grpc::CallbackServerContext* context, const esg::v1::ListDiagnosesRequest* request,
    esg::v1::ListDiagnosesResponse* response) {
  return Unary(&calls_, Authorize(context, Role::kRead, request->spacecraft_id()), response,
               [&] { return core_->ListDiagnoses(*request); });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::GetDiagnosis(
    grpc::CallbackServerContext* context, const esg::v1::GetDiagnosisRequest* request,
    esg::v1::DiagnosisResult* response) {
  return Unary(&calls_, Authorize(context, Role::kRead, request->spacecraft_id()), response,
               [&] { return core_->GetDiagnosis(*request); });
}

}  // namespace esg::server
