// The reorder window's re-run (docs/service.md "Several ground stations", docs/decisions.md
// D60-D62): where a re-run over a late frame starts (the latest window checkpoint before it, or
// the configuration), and what it revises. The apply worker (apply_worker.cc) runs the replay
// and commits it.
#include <algorithm>
#include <utility>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "server/core_internal.h"
#include "server/estimation_core.h"
#include "server/log.h"

namespace esg::server {
namespace {

// Alerts the ingest or the service raises, not the filter: a re-run does not raise them again,
// so it neither revises them nor sets them back.
bool RaisedOutsideTheFilter(const std::string& reason) {
  return reason == "INGEST_CONFLICT" || reason == kQuarantineAlertReason;
}

}  // namespace

std::string EncodeWindowCheckpoint(const ServerCheckpoint& apply,
                                   const estimator::EstimationSession& session) {
  ServerCheckpoint c = apply;
  c.session = session.ExportCheckpoint();
  return EncodeCheckpoint(c);
}

absl::StatusOr<std::vector<int64_t>> EstimationCore::FilterAlertsAfter(
    const std::string& spacecraft_id, absl::Time after) {
  ASSIGN_OR_RETURN(std::vector<int64_t> current,
                   storage_->reorder().CurrentAlertsAfter(spacecraft_id, after));
  std::vector<int64_t> out;
  for (int64_t sequence : current) {
    absl::StatusOr<storage::AlertRecord> r = storage_->alerts().Get(spacecraft_id, sequence);
    if (r.ok() && !RaisedOutsideTheFilter(r->reason)) out.push_back(sequence);
  }
  return out;
}

absl::StatusOr<EstimationCore::Rerun> EstimationCore::StartRerun(
    const std::string& spacecraft_id, const Setup& setup, absl::Time late_time,
    std::optional<estimator::EstimationSession>* session, ServerCheckpoint* apply) {
  const estimator::SessionOptions session_options{setup.model};
  ASSIGN_OR_RETURN(std::optional<storage::WindowCheckpoint> kept,
                   storage_->reorder().CheckpointBefore(spacecraft_id, late_time));
  Rerun rerun;
  ServerCheckpoint restored;
  std::optional<estimator::EstimationSession> restored_session;
  if (kept.has_value()) {
    absl::StatusOr<ServerCheckpoint> decoded = DecodeCheckpoint(kept->state_blob);
    if (decoded.ok() && decoded->model == setup.model_name && decoded->session.has_value()) {
      absl::StatusOr<estimator::EstimationSession> s = estimator::EstimationSession::FromCheckpoint(
          setup.config, session_options, *decoded->session);
      if (s.ok()) {
        restored = std::move(*decoded);
        restored.session.reset();
        restored_session = std::move(*s);
        rerun.after = kept->applied_time;
      }
    }
    if (!restored_session.has_value()) {
      LogEvent(
          "WARN", "window_checkpoint_unusable",
          absl::StrCat(spacecraft_id, ": the window checkpoint of ", FormatUtc(kept->applied_time),
                       " cannot be restored; the re-run starts from the configuration"),
          {{"spacecraftId", spacecraft_id}});
    }
  }
  if (!restored_session.has_value()) {
    ASSIGN_OR_RETURN(estimator::EstimationSession fresh,
                     estimator::EstimationSession::Create(setup.config, session_options));
    restored_session = std::move(fresh);
    restored = ServerCheckpoint();
    restored.model = setup.model_name;
    rerun.after = absl::InfinitePast();
  }
  // The quarantine state is the service's, not the filter's: it carries over. What is stored up
  // to the checkpoint stays; everything after it is revised and written again.
  restored.quarantine_reason = apply->quarantine_reason;
  restored.rebuilding = apply->rebuilding;
  restored.effects_written_until = std::min(restored.effects_written_until, rerun.after);
  std::vector<AlertTrack> tracks;
  for (const AlertTrack& t : restored.alert_tracks) {
    if (RaisedOutsideTheFilter(t.reason)) {
      // Keep the service's own live alert as it is now.
      continue;
    }
    rerun.restores.push_back({t.sequence, t.repeat_count, t.last_time});
    tracks.push_back(t);
  }
  for (const AlertTrack& t : apply->alert_tracks) {
    if (RaisedOutsideTheFilter(t.reason)) tracks.push_back(t);
  }
  restored.alert_tracks = std::move(tracks);
  ASSIGN_OR_RETURN(rerun.revised_alerts, FilterAlertsAfter(spacecraft_id, rerun.after));
  *session = std::move(restored_session);
  *apply = std::move(restored);
  return rerun;
}

}  // namespace esg::server
