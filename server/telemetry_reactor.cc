// The StreamTelemetry reactor; what it guarantees is stated in telemetry_reactor.h.
#include "server/telemetry_reactor.h"

#include <chrono>
#include <cstddef>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <string>
#include <utility>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "server/grpc_status.h"
#include "server/log.h"
#include "server/log_throttle.h"
#include "server/service_metrics.h"

namespace esg::server {
namespace {

constexpr size_t kMaxInFlight = 4096;

class TelemetryReactor
    : public grpc::ServerBidiReactor<esg::v1::TelemetryFrame, esg::v1::TelemetryAck> {
 public:
  // `scope`: the spacecraft the stream is routed by (server/spacecraft_scope.h), or empty.
  TelemetryReactor(grpc::CallbackServerContext* context, CallCounter* calls, EstimationCore* core,
                   const absl::Status& auth, std::string peer, std::string scope)
      : token_(calls),
        context_(context),
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
    // A shutdown stops the stream between frames too, not only at its next frame.
    std::weak_ptr<Shared> weak = shared_;
    stream_id_ = core_->AddIngestStream([weak] {
      std::shared_ptr<Shared> shared = weak.lock();
      if (shared == nullptr) return;
      absl::MutexLock lock(&shared->mu);
      shared->closing = true;
      TryWrite(*shared);
    });
    absl::MutexLock lock(&shared_->mu);
    if (!shared_->finished) StartRead(&frame_);
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
    const absl::StatusOr<bool> wait = core_->Ingest(
        frame_, &slot->ack,
        [weak, slot](absl::Status stored) {
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
    if (shared_->closing) return;  // the server shuts down: no more frames are read
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
    if (shared_->read_paused && shared_->slots.size() < kMaxInFlight / 2 && !shared_->finished &&
        !shared_->closing) {
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
    if (stream_id_ != 0) core_->RemoveIngestStream(stream_id_);
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
    // when it ends (each refusal itself is in the client's ack); these lines are throttled per
    // client address (server/log_throttle.h), so a client that reconnects in a loop writes a few
    // lines and a count, not a line per stream.
    static LogThrottle* const stream_log = new LogThrottle("stream_refusals");
    if (refused > 0 || unacknowledged > 0) {
      stream_log->Log(absl::StrCat("peer ", peer_.empty() ? "unknown" : PeerAddress(peer_)), "WARN",
                      absl::StrCat("telemetry stream from ", peer_.empty() ? "unknown" : peer_,
                                   " ended: ", received, " frames received, ", acknowledged,
                                   " acknowledged, ", refused, " refused",
                                   summary.empty() ? "" : " (", summary, summary.empty() ? "" : ")",
                                   ", ", unacknowledged, " not acknowledged (stream failed)"),
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
    // The server shuts down (EstimationCore::CloseIngest): no more reads; once the acks of the
    // frames read are out, the stream finishes with UNAVAILABLE.
    bool closing ABSL_GUARDED_BY(mu) = false;
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
    s.metrics->ack_latency.Observe(
        std::chrono::duration<double>(std::chrono::steady_clock::now() - slot.received).count());
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
        s.reactor->Finish(ToGrpcStatus(front.failure, *s.reactor->context_));
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
    } else if (s.closing) {
      s.finished = true;
      s.reactor->Finish(ToGrpcStatus(EstimationCore::ShuttingDown(), *s.reactor->context_));
    }
  }

  CallCounter::Token token_;
  grpc::CallbackServerContext* const context_;
  EstimationCore* core_;
  int64_t stream_id_ = 0;  // its registration with core_ (AddIngestStream); 0 before
  std::shared_ptr<Shared> shared_;
  const std::string peer_;
  const std::string scope_;
  esg::v1::TelemetryFrame frame_;
};

}  // namespace

grpc::ServerBidiReactor<esg::v1::TelemetryFrame, esg::v1::TelemetryAck>* NewTelemetryReactor(
    grpc::CallbackServerContext* context, CallCounter* calls, EstimationCore* core,
    const absl::Status& auth, std::string peer, std::string scope) {
  return new TelemetryReactor(context, calls, core, auth, std::move(peer), std::move(scope));
}

}  // namespace esg::server
