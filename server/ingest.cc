// The ingest contract (docs/service.md "Ingest contract"): each frame is validated and then
// decided as new, an exact duplicate, a conflict, late within the reorder window (new, applied
// by a re-run) or too late, before anything is queued for the archive. An acknowledgement that
// says "accepted" is sent only after the commit that stores the frame (committer.cc).
#include <algorithm>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "estimator/spacecraft_config.h"
#include "estimator/status_macros.h"
#include "google/protobuf/io/coded_stream.h"
#include "google/protobuf/io/zero_copy_stream_impl_lite.h"
#include "proto/convert.h"
#include "server/core_internal.h"
#include "server/estimation_core.h"
#include "server/grpc_status.h"
#include "server/log.h"
#include "server/log_throttle.h"
#include "server/spacecraft_scope.h"

namespace esg::server {
namespace {

// The largest frame sequence: 2^53 - 1, the largest integer a JSON number holds exactly.
constexpr int64_t kMaxFrameSequence = (int64_t{1} << 53) - 1;

std::string Serialize(const esg::v1::TelemetryFrame& frame) {
  std::string out;
  {
    google::protobuf::io::StringOutputStream stream(&out);
    google::protobuf::io::CodedOutputStream coded(&stream);
    coded.SetSerializationDeterministic(true);
    frame.SerializeToCodedStream(&coded);
  }
  return out;
}

// The measurement a payload carries, without the identity of the frame that carried it (the
// archive keeps the identity in its own columns).
std::string Measurement(const std::string& payload) {
  esg::v1::TelemetryFrame frame;
  if (!frame.ParseFromString(payload)) return "\xff unparsable";
  frame.clear_station_id();
  frame.clear_sequence();
  return Serialize(frame);
}

// How long a station should wait before it sends again to a server that is shutting down: about
// the time a restart or the router's switch to another server takes.
constexpr absl::Duration kShutdownRetryDelay = absl::Seconds(1);

// A refusal of the frame in its ack: `status` is "field: reason" (RejectionFromStatus splits it
// at the first ": "). False: the ack can be sent at once.
bool Refuse(esg::v1::TelemetryAck* ack, const absl::Status& status) {
  ack->set_accepted(false);
  *ack->mutable_rejection() = RejectionFromStatus(status);
  return false;
}

}  // namespace

absl::Status EstimationCore::ShuttingDown() {
  return WithRetryDelay(
      absl::UnavailableError(
          "the server is shutting down: it takes no more frames; resume from "
          "highest_durable_sequence + 1 when it (or another server) serves again"),
      kShutdownRetryDelay);
}

absl::StatusOr<std::optional<storage::ArchivedFrame>> EstimationCore::FindStoredFrame(
    Spacecraft& sc, const std::string& station, int64_t sequence, absl::Time time,
    bool by_identity) {
  // Accepted but not yet durable: still in memory.
  if (by_identity) {
    auto it = sc.pending_ids.find({station, sequence});
    if (it != sc.pending_ids.end()) time = it->second;
  }
  if (auto p = sc.pending.find(time); p != sc.pending.end() &&
                                      (!by_identity || (p->second.station == station &&
                                                        p->second.sequence == sequence))) {
    storage::ArchivedFrame f;
    f.spacecraft_id = sc.id;
    f.station_id = p->second.station;
    f.sequence = p->second.sequence;
    f.measurement_time = p->first;
    f.payload = p->second.payload;
    return std::optional<storage::ArchivedFrame>(std::move(f));
  }
  if (by_identity) return storage_->archive().Find(sc.id, station, sequence);
  return storage_->archive().FindAtTime(sc.id, time);
}

absl::StatusOr<bool> EstimationCore::Ingest(const esg::v1::TelemetryFrame& proto,
                                            esg::v1::TelemetryAck* ack,
                                            std::function<void(absl::Status)> on_durable,
                                            absl::string_view scope) {
  const std::string station =
      proto.station_id().empty() ? std::string(storage::kDefaultStation) : proto.station_id();
  // Echo the identity, shortened when it is not a valid identifier (the ack must stay small).
  ack->set_spacecraft_id(proto.spacecraft_id().size() <= 64 ? proto.spacecraft_id()
                                                              : proto.spacecraft_id().substr(0, 64));
  ack->set_station_id(station.size() <= 64 ? station : station.substr(0, 64));
  ack->set_sequence(proto.sequence());
  {
    absl::MutexLock commit(&commit_mu_);
    if (ingest_closed_) return ShuttingDown();
    if (!storage_fault_.empty() && !storage_trial_) {
      return absl::UnavailableError(absl::StrCat(
          "storage: cannot commit (", storage_fault_,
          "); no frame is acknowledged until it can: resume from highest_durable_sequence + 1"));
    }
  }
  if (absl::Status id = estimator::ValidateIdentifier(proto.spacecraft_id(), "spacecraft_id");
      !id.ok()) {
    return Refuse(ack, id);
  }
  if (absl::Status id = estimator::ValidateIdentifier(station, "station_id"); !id.ok()) {
    return Refuse(ack, id);
  }
  // A stream routed by one spacecraft reached that spacecraft's node: another spacecraft's frame
  // does not belong here (docs/service.md "Routing by spacecraft"). Refused before anything is
  // looked up, so it counts against no session.
  if (absl::Status routed = CheckInScope(scope, proto.spacecraft_id()); !routed.ok()) {
    return Refuse(ack, routed);
  }
  const int64_t frame_bytes = static_cast<int64_t>(proto.ByteSizeLong());
  if (frame_bytes > options_.max_frame_bytes) {
    return Refuse(ack, absl::ResourceExhaustedError(absl::StrCat(
                           "frame: ", frame_bytes, " bytes exceed the limit of ",
                           options_.max_frame_bytes)));
  }
  absl::StatusOr<std::shared_ptr<Spacecraft>> found = Lookup(proto.spacecraft_id());
  if (!found.ok()) return Refuse(ack, found.status());
  std::shared_ptr<Spacecraft> sc = *std::move(found);
  absl::StatusOr<estimator::TelemetryFrame> frame = proto_convert::FrameFromProto(proto);

  absl::MutexLock lock(&sc->ingest_mu);
  if (absl::Status checked = CheckFrame(*sc, proto, frame); !checked.ok()) {
    ++sc->frames_rejected;
    return Refuse(ack, checked);
  }
  const absl::Time time = frame->time;
  // Identity and time against what is stored or queued.
  // Stored as received; the archive's columns hold the identity (station made explicit).
  const std::string payload = proto.SerializeAsString();
  auto highest = sc->highest_accepted.find(station);
  const bool known_identity =
      highest != sc->highest_accepted.end() && proto.sequence() <= highest->second;
  const bool known_time = time <= sc->last_accepted_time;
  if (known_identity || known_time) {
    std::optional<absl::StatusOr<bool>> judged = JudgeKnownFrame(
        sc, station, proto.sequence(), time, payload, known_identity, ack, on_durable);
    if (judged.has_value()) return *std::move(judged);
  } else if (sc->last_accepted_time != absl::InfinitePast() &&
             time - sc->last_accepted_time > options_.max_frame_gap) {
    // The filter integrates across a gap at the configured rate: an absurd gap (a wrong time
    // tag) would occupy a worker for hours.
    ++sc->frames_rejected;
    return Refuse(ack, absl::OutOfRangeError(absl::StrCat(
                           "time: ", FormatUtc(time), " is more than ",
                           absl::FormatDuration(options_.max_frame_gap),
                           " after the previous accepted frame (",
                           FormatUtc(sc->last_accepted_time), ")")));
  }

  // New (or late within the window): queue it for the archive.
  CommitEntry entry;
  entry.sc = sc;
  entry.station = station;
  entry.sequence = proto.sequence();
  entry.time = time;
  entry.payload = payload;
  entry.frame = std::move(*frame);
  entry.late = known_time;
  entry.done = std::move(on_durable);
  // The verdict goes into the ack before the entry is queued: the committer may commit and send
  // this ack before push_back returns here.
  ack->set_accepted(true);
  {
    absl::MutexLock commit(&commit_mu_);
    if (ingest_closed_) return ShuttingDown();
    if (!storage_fault_.empty() && !storage_trial_) {
      return absl::UnavailableError(absl::StrCat("storage: cannot commit (", storage_fault_, ")"));
    }
    if (commit_queue_bytes_ + static_cast<int64_t>(payload.size()) >
        options_.max_commit_backlog_bytes) {
      return absl::ResourceExhaustedError(absl::StrCat(
          "ingest backlog: ", commit_queue_bytes_, " bytes wait for the archive (limit ",
          options_.max_commit_backlog_bytes,
          "); resume from highest_durable_sequence + 1 shortly"));
    }
    commit_queue_bytes_ += static_cast<int64_t>(payload.size());
    commit_queue_.push_back(std::move(entry));
  }
  sc->pending[time] = PendingFrame{station, proto.sequence(), payload};
  sc->pending_ids[{station, proto.sequence()}] = time;
  int64_t& highest_of_station = sc->highest_accepted[station];
  highest_of_station = std::max(highest_of_station, proto.sequence());
  sc->last_accepted_time = std::max(sc->last_accepted_time, time);
  return true;
}

absl::Status EstimationCore::CheckFrame(Spacecraft& sc, const esg::v1::TelemetryFrame& proto,
                                        const absl::StatusOr<estimator::TelemetryFrame>& frame) {
  if (sc.ingest_setup == nullptr) {
    std::string reason;
    {
      absl::MutexLock state(&sc.state_mu);
      reason = sc.apply.quarantine_reason;
    }
    return absl::FailedPreconditionError(
        absl::StrCat("spacecraft_id: '", sc.id, "' is quarantined: ", reason));
  }
  // At most 2^53 - 1, so that a JSON client (the console, a script) reads every sequence exactly;
  // INT64_MAX left no next sequence and `esg replay --wait` waiting for one.
  if (proto.sequence() < 1 || proto.sequence() > kMaxFrameSequence) {
    return absl::InvalidArgumentError(absl::StrCat("sequence: must be in [1, ",
                                                   kMaxFrameSequence, "] (2^53 - 1), got ",
                                                   proto.sequence()));
  }
  if (!frame.ok()) return frame.status();
  for (int i = 0; i < proto.gyros_size(); ++i) {
    const int id = proto.gyros(i).gyro_id();
    if (!sc.ingest_setup->configured[id - 1]) {  // 1..4 checked by FrameFromProto
      return absl::InvalidArgumentError(
          absl::StrCat("gyros[", i, "].gyro_id: gyro ", id,
                       " is not configured for spacecraft '", sc.id, "'"));
    }
  }
  // Each channel declared by the configuration and within its valid range (docs/formats.md
  // "Channels"); FrameFromProto checked the names, the count and that the values are finite.
  if (absl::Status channels = estimator::CheckDeclaredChannels(
          frame->channels, sc.ingest_setup->config.channels);
      !channels.ok()) {
    return channels;
  }
  const absl::Time time = frame->time;
  if (time < options_.earliest_frame_time || time >= options_.latest_frame_time) {
    return absl::OutOfRangeError(absl::StrCat("time: ", FormatUtc(time),
                                              " is outside the accepted window [",
                                              FormatUtc(options_.earliest_frame_time), ", ",
                                              FormatUtc(options_.latest_frame_time), ")"));
  }
  // Nothing is measured in the future: a frame ahead of the present would move the reorder
  // window past the correct frames after it (docs/decisions.md D95). The clock cannot judge
  // past-dated data (a recording replayed); only the gap limit applies to it.
  if (const absl::Time now = absl::Now(); time - now > options_.max_clock_lead) {
    return absl::OutOfRangeError(
        absl::StrCat("time: ", FormatUtc(time), " is ",
                     absl::FormatDuration(absl::Trunc(time - now, absl::Seconds(1))),
                     " ahead of the server's clock (", FormatUtc(now), "; at most ",
                     absl::FormatDuration(options_.max_clock_lead),
                     ", esgd --max-clock-lead): a frame cannot be measured in the future; "
                     "check the time tag and the clocks"));
  }
  return absl::OkStatus();
}

std::optional<absl::StatusOr<bool>> EstimationCore::JudgeKnownFrame(
    const std::shared_ptr<Spacecraft>& sc, const std::string& station, int64_t sequence,
    absl::Time time, const std::string& payload, bool known_identity, esg::v1::TelemetryAck* ack,
    std::function<void(absl::Status)>& on_durable) {
  const bool known_time = time <= sc->last_accepted_time;
  absl::StatusOr<std::optional<storage::ArchivedFrame>> stored =
      FindStoredFrame(*sc, station, sequence, time, known_identity);
  // An identity the station used for a measurement another station had delivered first was
  // acknowledged as a duplicate of that measurement, and is judged against it again.
  bool by_identity = known_identity;
  if (stored.ok() && !stored->has_value() && known_identity && known_time) {
    stored = FindStoredFrame(*sc, station, sequence, time, /*by_identity=*/false);
    by_identity = false;
  }
  if (!stored.ok()) {
    return absl::UnavailableError(
        absl::StrCat("storage: cannot read the archive: ", stored.status().message()));
  }
  if (stored->has_value()) {
    const storage::ArchivedFrame& original = **stored;
    // By identity the station and sequence are equal already: the measurement decides.
    if (Measurement(original.payload) != Measurement(payload)) {
      ++sc->frames_conflicting;
      const std::string what = absl::StrCat(
          "frame (station '", station, "', sequence ", sequence, ", time ", FormatUtc(time),
          ") conflicts with the stored frame (station '", original.station_id, "', sequence ",
          original.sequence, ", time ", FormatUtc(original.measurement_time), "): same ",
          by_identity ? "station and sequence" : "measurement time",
          ", different content; the stored frame is kept");
      // Per station of a spacecraft: a replay of conflicting frames is one line each for the
      // first few, then a count (server/log_throttle.h).
      static LogThrottle* const conflict_log = new LogThrottle("frame_conflict");
      conflict_log->Log(absl::StrCat("station ", station, " of spacecraft ", sc->id), "WARN",
                        absl::StrCat(sc->id, ": ", what),
                        {{"spacecraftId", sc->id}, {"station", station}, {"sequence", sequence}});
      {
        absl::MutexLock state(&sc->state_mu);
        sc->service_alerts.push_back({"INGEST_CONFLICT", "WARNING",
                                      absl::StrCat("station ", station), time,
                                      static_cast<double>(sequence),
                                      static_cast<double>(original.sequence), "sequence", what});
      }
      Schedule(sc);
      return Refuse(ack, absl::AlreadyExistsError(
                             absl::StrCat(by_identity ? "sequence" : "time", ": ", what)));
    }
    // An exact duplicate: stored once, acknowledged as a duplicate once the original is.
    ++sc->frames_duplicate;
    ack->set_accepted(true);
    ack->set_duplicate(true);
    if (sc->pending.count(original.measurement_time) == 0) return false;
    CommitEntry entry;
    entry.sc = sc;
    entry.barrier = true;
    entry.done = std::move(on_durable);
    absl::MutexLock commit(&commit_mu_);
    if (ingest_closed_) return ShuttingDown();
    commit_queue_.push_back(std::move(entry));
    return true;
  }
  // Never stored: a late frame (docs/service.md "Several ground stations"). A station's
  // sequence identifies its frames and the time orders them: a sequence below the station's
  // highest one that it never used is a frame the station sends late (a pass relayed after a
  // later one, a gap filled); only its time decides whether the window still takes it.
  if (known_time && sc->last_accepted_time - time > options_.reorder_window) {
    ++sc->frames_rejected;
    return Refuse(ack, absl::OutOfRangeError(absl::StrCat(
                           "time: ", FormatUtc(time), " is more than the reorder window (",
                           absl::FormatDuration(options_.reorder_window),
                           ", esgd --reorder-window) before the last accepted frame of '",
                           sc->id, "' (", FormatUtc(sc->last_accepted_time),
                           "): too late to be applied in time order")));
  }
  return std::nullopt;
}

void EstimationCore::FillDurable(esg::v1::TelemetryAck* ack) {
  std::shared_ptr<Spacecraft> sc = Find(ack->spacecraft_id());
  if (sc == nullptr) return;
  absl::MutexLock lock(&sc->state_mu);
  auto it = sc->highest_durable.find(ack->station_id());
  ack->set_highest_durable_sequence(it == sc->highest_durable.end() ? 0 : it->second);
}

}  // namespace esg::server
