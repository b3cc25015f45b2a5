// `esg replay --recording F [--spacecraft ID] [--rate X] [--from-sequence N]`: streams a recording
// CSV (docs/formats.md) to esgd through StreamTelemetry, frame sequence number = 1-based row index.
//
// Flow: at most --window frames are unacknowledged at any time; with --rate X the frames leave at
// X times real time (frame epochs scaled), otherwise as fast as the window allows. Acks arrive in
// frame order (estimation_service.proto); each is counted as accepted, duplicate (a frame the
// server had already accepted: not processed again) or rejected (with the offending field).
// An ack that breaks the contract (accepted = false without a rejection) is not counted as a
// rejection: such frames are sent again at the end and counted by the second answer (a stored
// frame comes back as a duplicate), with a warning.
//
// Resume: when the stream fails with a transient code (UNAVAILABLE, CANCELLED, ...: a network
// failure, a server restart or a kill), the client backs off (0.25 s doubling to 4 s), waits
// for the server, asks GetSession for highest_durable_sequence and continues with the frame
// after max(last acknowledged, highest durable). Frames the server had made durable but whose
// acks were lost are therefore not sent twice. After --max-retries consecutive failed attempts
// without progress it gives up with the last status and the sequence to resume from. A frame
// refused with `frame: the server is shutting down` (a graceful stop) is such a failure too, not
// a rejection: it is sent again.
//
// Lease: a frame refused UNAVAILABLE with Rejection.retry_after_ms (another server holds the
// spacecraft's session, docs/service.md "Several servers") is not a rejection either. The
// stream stops writing at the first such refusal (the frames in flight are answered), waits the
// largest delay of those refusals, sends the refused frames again in sequence order, then goes
// on with the frames after them. The waits add up to at most --max-lease-wait; when the next
// one would exceed it, the replay gives up (exit 1) naming the server that holds the session.
//
// Exit codes: 0 success, 2 bad arguments or recording, 1 server failure, or rejected frames
// without --allow-rejects.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdio>
#include <iostream>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "client/commands/commands.h"
#include "client/commands/server_common.h"
#include "client/progress.h"
#include "formats/column_mapping.h"
#include "formats/recording_csv.h"
#include "proto/convert.h"

namespace esg::client {
namespace {

constexpr char kVerb[] = "replay";
constexpr int kRejectionsShown = 5;
constexpr int kRejectionsKept = 20;

struct ReplayOptions {
  std::string recording_path;
  std::string columns_path;
  std::string spacecraft_id;
  double rate = 0.0;
  int64_t from_sequence = 1;
  int window = 1024;
  int max_retries = 8;
  bool allow_rejects = false;
  bool wait = false;
  double wait_timeout_s = 600.0;
  double max_lease_wait_s = 120.0;
  OutputFormat format = OutputFormat::kTable;
};

struct RejectedFrame {
  int64_t sequence;
  std::string field;
  std::string reason;
};

struct Tally {
  int64_t sent = 0;      // frames written to a stream (a frame resent after a failure counts again)
  int64_t acked = 0;     // acknowledgements received
  int64_t accepted = 0;  // acks: accepted, new
  int64_t duplicates = 0;           // acks: accepted before, not processed again
  int64_t rejected = 0;             // acks: rejected
  int64_t durable_without_ack = 0;  // skipped on resume: durable on the server, ack lost
  int64_t ambiguous = 0;            // acks without a verdict (accepted = false, no rejection)
  int64_t ambiguous_stored = 0;     // of those, found stored when sent again (counted in accepted)
  int64_t deferred = 0;  // acks refusing a frame while another server held the session (not
                         // in acked: the frame is sent again)
  absl::Duration lease_wait;  // waited for those, in total
  int reconnects = 0;
  int64_t last_acked = 0;       // highest sequence acknowledged
  int64_t last_accepted = 0;    // highest sequence acknowledged as accepted (incl. duplicate)
  int64_t highest_durable = 0;  // from the latest ack or GetSession
  std::vector<RejectedFrame> rejections;  // the first kRejectionsKept
};

// Codes after which the stream is worth re-opening.
bool Transient(absl::StatusCode code) {
  switch (code) {
    case absl::StatusCode::kUnavailable:
    case absl::StatusCode::kCancelled:
    case absl::StatusCode::kDeadlineExceeded:
    case absl::StatusCode::kAborted:
    case absl::StatusCode::kInternal:
    case absl::StatusCode::kUnknown:
    case absl::StatusCode::kResourceExhausted:
      return true;
    default:
      return false;
  }
}

class Replayer {
 public:
  Replayer(const ReplayOptions& o, const estimator::Recording& recording, std::string spacecraft_id,
           EsgClient* client)
      : o_(o),
        frames_(recording.frames),
        id_(std::move(spacecraft_id)),
        client_(client),
        progress_("replay") {
    tally_.last_acked = o.from_sequence - 1;
  }

  Tally& tally() { return tally_; }
  int64_t frame_count() const { return static_cast<int64_t>(frames_.size()); }

  // Streams frames [first, n] once. OK when every frame written is acknowledged: all of them,
  // or, when paused(), those up to last_written().
  absl::Status StreamFrom(int64_t first) { return Stream(first, nullptr); }

  // The last stream stopped writing at a refusal with a retry delay (the frames after
  // last_written() were not sent).
  bool paused() const { return pausing_; }
  int64_t last_written() const { return last_written_; }

  // Frames refused while another server held the session, to send again.
  bool has_deferred() const { return !deferred_.empty(); }
  int64_t deferred_count() const { return static_cast<int64_t>(deferred_.size()); }
  int64_t first_deferred() const { return *deferred_.begin(); }
  // The longest retry delay of the refusals since the last call (at least 1 ms), and the
  // latest refusal as "field: reason".
  absl::Duration TakeRetryDelay() {
    const absl::Duration delay = absl::Milliseconds(std::max<int64_t>(retry_after_ms_, 1));
    retry_after_ms_ = 0;
    return delay;
  }
  const std::string& deferred_reason() const { return deferred_reason_; }

  // Sends the deferred frames again, in sequence order, without pacing: each is then answered
  // as any frame (or deferred again).
  absl::Status ResendDeferred() {
    const std::vector<int64_t> sequences(deferred_.begin(), deferred_.end());
    return Stream(0, &sequences);
  }

  bool has_ambiguous() const { return !ambiguous_.empty(); }

  // Sends again the frames whose ack carried no verdict (accepted = false without a rejection,
  // against the TelemetryAck contract): a stored frame now comes back as a duplicate, a refused
  // one is rejected with its reason. Safe because the server never processes a frame twice.
  absl::Status VerifyAmbiguous() {
    std::vector<int64_t> sequences;
    sequences.swap(ambiguous_);
    if (sequences.empty()) return absl::OkStatus();
    verifying_ = true;
    absl::Status status = Stream(0, &sequences);
    verifying_ = false;
    return status;
  }

 private:
  // Streams frames [first, n], or only `sequences` (without pacing) when given.
  absl::Status Stream(int64_t first, const std::vector<int64_t>* sequences) {
    server_stopping_ = false;
    pausing_ = false;
    const int64_t count =
        sequences != nullptr ? static_cast<int64_t>(sequences->size()) : frame_count() - first + 1;
    auto sequence_at = [&](int64_t i) {
      return sequences != nullptr ? (*sequences)[i] : first + i;
    };
    int64_t acks = 0;
    // One stream per spacecraft, routed by it (docs/service.md "Routing by spacecraft").
    std::unique_ptr<TelemetryStream> stream = client_->StreamTelemetry(id_);
    std::mutex mu;
    std::condition_variable cv;
    int64_t in_flight = 0;
    int64_t written = 0;
    bool stop = false;
    std::thread writer([&] {
      const auto wall_start = std::chrono::steady_clock::now();
      const absl::Time time_start = frames_[sequence_at(0) - 1].time;
      bool complete = true;
      for (int64_t i = 0; i < count; ++i) {
        const int64_t seq = sequence_at(i);
        std::unique_lock<std::mutex> lock(mu);
        cv.wait(lock, [&] { return stop || pausing_ || in_flight < o_.window; });
        if (stop) {
          complete = false;
          break;
        }
        // Paused: the stream is closed normally, so the frames in flight are answered.
        if (pausing_) break;
        if (o_.rate > 0.0 && sequences == nullptr) {
          const double offset_s =
              absl::ToDoubleSeconds(frames_[seq - 1].time - time_start) / o_.rate;
          const auto due =
              wall_start + std::chrono::duration_cast<std::chrono::steady_clock::duration>(
                               std::chrono::duration<double>(offset_s));
          if (cv.wait_until(lock, due, [&] { return stop || pausing_; })) {
            if (stop) complete = false;
            break;
          }
        }
        ++in_flight;
        lock.unlock();
        if (!stream->Write(proto_convert::FrameToProto(frames_[seq - 1], id_, seq))) {
          complete = false;
          break;
        }
        std::lock_guard<std::mutex> relock(mu);
        ++tally_.sent;
        ++written;
        last_written_ = seq;
      }
      if (complete) stream->WritesDone();
    });

    esg::v1::TelemetryAck ack;
    while (stream->Read(&ack)) {
      {
        std::lock_guard<std::mutex> lock(mu);
        --in_flight;
        ++acks;
        Count(ack);
      }
      cv.notify_all();
      const int64_t total = frame_count() - o_.from_sequence + 1;
      progress_(static_cast<double>(tally_.last_acked - o_.from_sequence + 1) / total);
    }
    {
      std::lock_guard<std::mutex> lock(mu);
      stop = true;
    }
    cv.notify_all();
    writer.join();
    absl::Status status = stream->Finish();
    if (status.ok() && server_stopping_) {
      status = absl::UnavailableError("the server is shutting down");
    } else if (status.ok() && acks < (pausing_ ? written : count)) {
      status = absl::UnavailableError(absl::StrCat("the stream ended after ", acks, " acks for ",
                                                   pausing_ ? written : count, " frames"));
    }
    return status;
  }

  void Count(const esg::v1::TelemetryAck& ack) {
    // A frame refused because the server is stopping was not judged: it and everything after it
    // in this stream are sent again after the reconnect.
    if (!ack.accepted() && ack.rejection().field() == "frame" &&
        absl::StrContains(ack.rejection().reason(), "shutting down")) {
      server_stopping_ = true;
    }
    if (server_stopping_) return;
    // Another server holds the session: not a verdict on the frame, which is sent again after
    // the delay (and the stream stops writing).
    if (!ack.accepted() &&
        ack.rejection().code() == static_cast<int>(absl::StatusCode::kUnavailable) &&
        ack.rejection().retry_after_ms() > 0) {
      ++tally_.deferred;
      deferred_.insert(ack.sequence());
      retry_after_ms_ = std::max(retry_after_ms_, ack.rejection().retry_after_ms());
      deferred_reason_ = absl::StrCat(ack.rejection().field(), ": ", ack.rejection().reason());
      pausing_ = true;
      if (!verifying_) tally_.last_acked = std::max(tally_.last_acked, ack.sequence());
      return;
    }
    deferred_.erase(ack.sequence());
    const bool no_verdict =
        !ack.accepted() && ack.rejection().field().empty() && ack.rejection().reason().empty();
    if (verifying_) {
      // The second answer for a frame whose first ack had no verdict.
      if (ack.accepted()) {
        ++tally_.accepted;
        ++tally_.ambiguous_stored;
        return;
      }
      ++tally_.rejected;
      if (static_cast<int>(tally_.rejections.size()) < kRejectionsKept) {
        tally_.rejections.push_back(
            {ack.sequence(), ack.rejection().field(), ack.rejection().reason()});
      }
      return;
    }
    ++tally_.acked;
    tally_.last_acked = std::max(tally_.last_acked, ack.sequence());
    tally_.highest_durable = std::max(tally_.highest_durable, ack.highest_durable_sequence());
    if (ack.accepted()) {
      tally_.last_accepted = std::max(tally_.last_accepted, ack.sequence());
      if (ack.duplicate()) {
        ++tally_.duplicates;
      } else {
        ++tally_.accepted;
      }
      return;
    }
    if (no_verdict) {
      ++tally_.ambiguous;
      ambiguous_.push_back(ack.sequence());
      return;
    }
    ++tally_.rejected;
    if (static_cast<int>(tally_.rejections.size()) < kRejectionsKept) {
      tally_.rejections.push_back(
          {ack.sequence(), ack.rejection().field(), ack.rejection().reason()});
    }
  }

  const ReplayOptions& o_;
  const std::vector<estimator::TelemetryFrame>& frames_;
  const std::string id_;
  EsgClient* const client_;
  Progress progress_;
  Tally tally_;
  bool server_stopping_ = false;    // this stream got a "server is shutting down" refusal
  bool verifying_ = false;          // VerifyAmbiguous is running
  std::vector<int64_t> ambiguous_;  // sequences whose ack had no verdict, to verify
  // Refusals with a retry delay (another server holds the session). The flags and the writer's
  // position are shared by a stream's writer and reader under its mutex.
  bool pausing_ = false;         // this stream got one: stop writing
  int64_t last_written_ = 0;     // the last sequence this stream wrote
  std::set<int64_t> deferred_;   // sequences refused so, not answered otherwise since
  int64_t retry_after_ms_ = 0;   // the longest delay since the last TakeRetryDelay()
  std::string deferred_reason_;  // the latest such refusal, "field: reason"
};

// Polls GetSession until every durable frame is applied to the session, or the timeout.
absl::StatusOr<esg::v1::SessionInfo> WaitApplied(EsgClient& client, const std::string& id,
                                                 absl::Duration timeout) {
  const absl::Time deadline = absl::Now() + timeout;
  for (;;) {
    absl::StatusOr<esg::v1::SessionInfo> s = client.GetSession(id);
    if (!s.ok()) return s.status();
    if (s->highest_applied_sequence() >= s->highest_durable_sequence()) return s;
    // A stopped filter applies nothing more until the configuration is replaced: say so now
    // rather than at the timeout.
    if (s->state() == esg::v1::SESSION_STATE_QUARANTINED && !s->rebuilding()) {
      return absl::FailedPreconditionError(absl::StrCat(
          "--wait: '", id, "' is quarantined (applied up to sequence ",
          s->highest_applied_sequence(), " of ", s->highest_durable_sequence(),
          " durable): ", s->quarantine_reason()));
    }
    if (absl::Now() > deadline) {
      return absl::DeadlineExceededError(absl::StrCat(
          "--wait: applied up to sequence ", s->highest_applied_sequence(), " of ",
          s->highest_durable_sequence(), " durable after ", absl::FormatDuration(timeout)));
    }
    absl::SleepFor(absl::Milliseconds(100));
  }
}

int RunReplay(const ReplayOptions& o, const GlobalOptions& global) {
  if (o.rate < 0.0 || !std::isfinite(o.rate)) {
    return ReportBadArgument(
        kVerb, absl::StrCat("--rate ", o.rate, ": must be >= 0 (0: as fast as possible)"));
  }
  if (o.window < 1)
    return ReportBadArgument(kVerb, absl::StrCat("--window ", o.window, ": must be >= 1"));
  if (o.max_lease_wait_s < 0.0 || !std::isfinite(o.max_lease_wait_s)) {
    return ReportBadArgument(
        kVerb, absl::StrCat("--max-lease-wait ", o.max_lease_wait_s, ": must be >= 0 [s]"));
  }
  if (o.max_retries < 0) {
    return ReportBadArgument(kVerb,
                             absl::StrCat("--max-retries ", o.max_retries, ": must be >= 0"));
  }
  absl::StatusOr<estimator::Recording> recording =
      storage::ReadRecording(o.recording_path, o.columns_path);
  if (!recording.ok()) {
    return ReportBadArgument(
        kVerb, absl::StrCat("--recording ", o.recording_path, ": ", recording.status().message()));
  }
  const int64_t n = static_cast<int64_t>(recording->frames.size());
  if (n == 0) return ReportBadArgument(kVerb, "--recording " + o.recording_path + ": no frames");
  std::string id = o.spacecraft_id;
  if (id.empty()) {
    auto it = recording->metadata.find("spacecraft_id");
    if (it == recording->metadata.end() || it->second.empty()) {
      return ReportBadArgument(
          kVerb, o.columns_path.empty()
                     ? "--spacecraft: required, the recording has no '# spacecraft_id:' line"
                     : "--spacecraft: required, neither the recording ('# spacecraft_id:') nor "
                       "the --columns mapping (spacecraftId) names the spacecraft");
    }
    id = it->second;
  }
  if (o.from_sequence < 1 || o.from_sequence > n) {
    return ReportBadArgument(
        kVerb, absl::StrCat("--from-sequence ", o.from_sequence, ": must be in 1..", n,
                            " (rows of the recording)"));
  }
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  // Reachability and configuration first: a server that is down or does not know the spacecraft
  // is an immediate, clear failure rather than a retry loop.
  // A station's token may hold the write role only (docs/service.md "Security"): the frames go
  // in, the acks say what is durable, and a reconnect resumes after the last acknowledged frame
  // (the server keeps one copy of a frame sent twice). Only --wait needs the read role.
  absl::StatusOr<esg::v1::SessionInfo> initial = client->GetSession(id);
  const bool can_read = initial.status().code() != absl::StatusCode::kPermissionDenied;
  if (!can_read && o.wait) {
    return ReportRpcError(
        kVerb,
        absl::PermissionDeniedError(absl::StrCat(
            "--wait: polls the session, which needs a token with the read role (",
            initial.status().message(), "); without --wait a write-only token replays")),
        global);
  }
  if (!can_read) {
    std::fprintf(stderr,
                 "esg %s: note: the token has no read role; the replay resumes from the "
                 "acknowledgements alone after a reconnect\n",
                 kVerb);
  } else if (!initial.ok()) {
    return ReportRpcError(kVerb, initial.status(), global);
  }

  const absl::Time started = absl::Now();
  Replayer replayer(o, *recording, id, client.get());
  Tally& tally = replayer.tally();
  const absl::Duration max_lease_wait = absl::Seconds(o.max_lease_wait_s);
  int64_t next = o.from_sequence;
  int failures = 0;  // consecutive attempts without progress
  absl::Status last_error;
  for (;;) {
    const int64_t acked_before = tally.last_acked;
    const int64_t verdicts_before = tally.acked;
    absl::Status status;
    if (replayer.has_deferred()) {
      // Another server holds the session: wait as told, then send those frames again.
      const absl::Duration delay = replayer.TakeRetryDelay();
      if (tally.lease_wait + delay > max_lease_wait) {
        std::fprintf(
            stderr,
            "\nesg %s: %lld frames refused because another server holds the session (%s); "
            "gave up: waiting %s more would exceed --max-lease-wait %s (waited %s); "
            "sequence %lld of %lld was not accepted (continue with --from-sequence %lld)\n",
            kVerb, static_cast<long long>(replayer.deferred_count()),
            replayer.deferred_reason().c_str(), absl::FormatDuration(delay).c_str(),
            absl::FormatDuration(max_lease_wait).c_str(),
            absl::FormatDuration(tally.lease_wait).c_str(),
            static_cast<long long>(replayer.first_deferred()), static_cast<long long>(n),
            static_cast<long long>(replayer.first_deferred()));
        return kExitFailure;
      }
      std::fprintf(stderr,
                   "\nesg %s: %lld frames refused because another server holds the session "
                   "(%s); sending them again in %s\n",
                   kVerb, static_cast<long long>(replayer.deferred_count()),
                   replayer.deferred_reason().c_str(), absl::FormatDuration(delay).c_str());
      absl::SleepFor(delay);
      tally.lease_wait += delay;
      status = replayer.ResendDeferred();
    } else if (next <= n) {
      status = replayer.StreamFrom(next);
      if (status.ok()) next = replayer.paused() ? replayer.last_written() + 1 : n + 1;
    } else if (replayer.has_ambiguous()) {
      status = replayer.VerifyAmbiguous();
      if (!status.ok()) return ReportRpcError(kVerb, status, global);
    } else {
      break;
    }
    if (status.ok()) continue;
    if (!Transient(status.code())) return ReportRpcError(kVerb, status, global);
    if (tally.last_acked > acked_before || tally.acked > verdicts_before) failures = 0;
    // Reconnect: back off, then learn where the server's durable archive ends.
    for (;;) {
      ++failures;
      last_error = status;
      if (failures > o.max_retries) {
        // Frames deferred for the lease below the last acknowledged one are not stored.
        const int64_t resume = replayer.has_deferred()
                                   ? std::min(tally.last_acked + 1, replayer.first_deferred())
                                   : tally.last_acked + 1;
        std::fprintf(
            stderr,
            "esg %s: gave up after %d reconnect attempts; acknowledged up to sequence %lld "
            "of %lld (continue with --from-sequence %lld)\n",
            kVerb, o.max_retries, static_cast<long long>(resume - 1),
            static_cast<long long>(n), static_cast<long long>(resume));
        return ReportRpcError(kVerb, last_error, global);
      }
      const absl::Duration backoff =
          std::min(absl::Milliseconds(250) * (1 << std::min(failures - 1, 4)), absl::Seconds(4));
      std::fprintf(stderr,
                   "\nesg %s: stream failed (%s: %s); reconnecting in %s (attempt %d of %d)\n",
                   kVerb, absl::StatusCodeToString(status.code()).c_str(),
                   std::string(status.message()).c_str(), absl::FormatDuration(backoff).c_str(),
                   failures, o.max_retries);
      absl::SleepFor(backoff);
      if (!can_read) {
        // The stream itself tells whether the server is back.
        next = std::max(tally.last_acked + 1, o.from_sequence);
        ++tally.reconnects;
        break;
      }
      CallOptions call;
      call.timeout = absl::Seconds(5);
      call.wait_for_ready = true;  // wait for a restarting server instead of failing at once
      absl::StatusOr<esg::v1::SessionInfo> session = client->GetSession(id, call);
      if (session.ok()) {
        const int64_t durable = session->highest_durable_sequence();
        if (durable < tally.last_accepted) {
          std::fprintf(stderr,
                       "esg %s: warning: the server's durable sequence %lld is below the "
                       "acknowledged %lld (was its database replaced?)\n",
                       kVerb, static_cast<long long>(durable),
                       static_cast<long long>(tally.last_accepted));
        }
        tally.highest_durable = durable;
        const int64_t resume = std::max({tally.last_acked + 1, durable + 1, o.from_sequence});
        tally.durable_without_ack +=
            std::max<int64_t>(0, std::min(resume, n + 1) - (tally.last_acked + 1));
        tally.last_acked = std::max(tally.last_acked, std::min(resume - 1, n));
        next = resume;
        ++tally.reconnects;
        break;
      }
      if (!Transient(session.status().code()))
        return ReportRpcError(kVerb, session.status(), global);
      status = session.status();
    }
  }
  if (tally.ambiguous > 0) {
    std::fprintf(stderr,
                 "esg %s: warning: %lld acks carried no verdict (accepted = false without a "
                 "rejection, a server bug); sent again: %lld found stored\n",
                 kVerb, static_cast<long long>(tally.ambiguous),
                 static_cast<long long>(tally.ambiguous_stored));
  }
  const double elapsed_s = absl::ToDoubleSeconds(absl::Now() - started);

  std::optional<esg::v1::SessionInfo> applied;
  if (o.wait) {
    absl::StatusOr<esg::v1::SessionInfo> s =
        WaitApplied(*client, id, absl::Seconds(o.wait_timeout_s));
    if (!s.ok()) return ReportRpcError(kVerb, s.status(), global);
    applied = *s;
    tally.highest_durable = std::max(tally.highest_durable, s->highest_durable_sequence());
  }

  if (o.format != OutputFormat::kTable) {
    Json rejections = Json::array();
    for (const RejectedFrame& r : tally.rejections) {
      rejections.push_back(
          Json{{"sequence", r.sequence}, {"field", r.field}, {"reason", r.reason}});
    }
    Json doc{{"spacecraftId", id},
             {"recording", o.recording_path},
             {"frames", n},
             {"fromSequence", o.from_sequence},
             {"sent", tally.sent},
             {"acked", tally.acked},
             {"accepted", tally.accepted},
             {"duplicates", tally.duplicates},
             {"rejected", tally.rejected},
             {"durableWithoutAck", tally.durable_without_ack},
             {"acksWithoutVerdict", tally.ambiguous},
             {"acksWithoutVerdictStored", tally.ambiguous_stored},
             {"deferred", tally.deferred},
             {"leaseWaitS", absl::ToDoubleSeconds(tally.lease_wait)},
             {"reconnects", tally.reconnects},
             {"highestDurableSequence", tally.highest_durable},
             {"elapsedS", elapsed_s},
             {"rejections", rejections}};
    if (applied) {
      doc["highestAppliedSequence"] = applied->highest_applied_sequence();
      doc["session"] = SessionJson(*applied);
    }
    if (o.format == OutputFormat::kJson) {
      PrintJson(doc);
    } else {  // one row: the tally (rejections and the session are in the JSON form)
      doc.erase("rejections");
      doc.erase("session");
      PrintCsv({doc});
    }
  } else {
    std::printf(
        "%s: %lld frames (sequences %lld..%lld) in %.1f s: sent %lld, acked %lld "
        "(accepted %lld, duplicates %lld, rejected %lld)",
        id.c_str(), static_cast<long long>(n - o.from_sequence + 1),
        static_cast<long long>(o.from_sequence), static_cast<long long>(n), elapsed_s,
        static_cast<long long>(tally.sent), static_cast<long long>(tally.acked),
        static_cast<long long>(tally.accepted), static_cast<long long>(tally.duplicates),
        static_cast<long long>(tally.rejected));
    if (tally.durable_without_ack > 0) {
      std::printf(", durable without ack %lld", static_cast<long long>(tally.durable_without_ack));
    }
    if (tally.deferred > 0) {
      std::printf(", deferred %lld (sent again after %.1f s waiting for the session lease)",
                  static_cast<long long>(tally.deferred),
                  absl::ToDoubleSeconds(tally.lease_wait));
    }
    std::printf("; %d reconnects; server durable up to %lld\n", tally.reconnects,
                static_cast<long long>(tally.highest_durable));
    if (applied) {
      std::printf("applied up to %lld (state %s, %lld frames applied, %lld failed)\n",
                  static_cast<long long>(applied->highest_applied_sequence()),
                  StateName(applied->state()).c_str(),
                  static_cast<long long>(applied->frames_applied()),
                  static_cast<long long>(applied->frames_apply_failed()));
    }
  }
  if (tally.rejected > 0) {
    std::fprintf(stderr, "esg %s: %lld frames rejected%s\n", kVerb,
                 static_cast<long long>(tally.rejected),
                 o.allow_rejects ? "" : " (exit 1; --allow-rejects to accept)");
    for (int i = 0; i < static_cast<int>(tally.rejections.size()) && i < kRejectionsShown; ++i) {
      const RejectedFrame& r = tally.rejections[i];
      if (r.field.empty() && r.reason.empty()) {
        // Against the contract (TelemetryAck.rejection is present when accepted = false).
        std::fprintf(stderr, "  sequence %lld: not accepted, and the server gave no reason\n",
                     static_cast<long long>(r.sequence));
      } else {
        std::fprintf(stderr, "  sequence %lld: %s: %s\n", static_cast<long long>(r.sequence),
                     r.field.c_str(), r.reason.c_str());
      }
    }
    if (tally.rejected > kRejectionsShown) {
      std::fprintf(stderr, "  ... and %lld more\n",
                   static_cast<long long>(tally.rejected - kRejectionsShown));
    }
    if (!o.allow_rejects) return kExitFailure;
  }
  return kExitOk;
}

}  // namespace

void RegisterReplay(CLI::App& app, GlobalOptions& global, int* exit_code) {
  auto options = std::make_shared<ReplayOptions>();
  CLI::App* cmd = app.add_subcommand(
      kVerb, "stream a recording CSV to esgd (StreamTelemetry), resuming after failures");
  cmd->add_option("--recording", options->recording_path, "recording CSV (docs/formats.md)")
      ->required();
  cmd->add_option("--columns", options->columns_path,
                  "column mapping JSON: read --recording as a CSV export with other column "
                  "names, units, quaternion order or time format (docs/formats.md)");
  cmd->add_option("--spacecraft", options->spacecraft_id,
                  "spacecraft id (default: the recording's '# spacecraft_id:')");
  cmd->add_option("--rate", options->rate, "X times real time (0: as fast as the window allows)")
      ->capture_default_str();
  cmd->add_option("--from-sequence", options->from_sequence, "first row to send (1-based)")
      ->capture_default_str();
  cmd->add_option("--window", options->window, "frames in flight without an ack, at most")
      ->capture_default_str();
  cmd->add_option("--max-retries", options->max_retries,
                  "consecutive reconnect attempts without progress before giving up")
      ->capture_default_str();
  cmd->add_flag("--allow-rejects", options->allow_rejects, "rejected frames do not make exit 1");
  cmd->add_flag("--wait", options->wait,
                "afterwards, wait until the server has applied every durable frame");
  cmd->add_option("--wait-timeout", options->wait_timeout_s, "longest --wait [s]")
      ->capture_default_str();
  cmd->add_option("--max-lease-wait", options->max_lease_wait_s,
                  "longest total wait for frames refused because another server holds the "
                  "spacecraft's session, before giving up [s]")
      ->capture_default_str();
  AddFormatOption(cmd, &options->format);
  cmd->callback([options, &global, exit_code] { *exit_code = RunReplay(*options, global); });
}

}  // namespace esg::client
