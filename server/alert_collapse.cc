// Alert collapsing (see alert_collapse.h).
#include "server/alert_collapse.h"

#include <algorithm>

#include "server/alert_catalog.h"
#include "server/proto_mapping.h"

namespace esg::server {
namespace {

// The clearing rule of a stored reason name; kQuiet for a name the catalog does not know.
ClearRule RuleOf(const std::string& reason) {
  const AlertKind* kind = FindAlertKind(reason);
  return kind != nullptr ? kind->clear_rule : ClearRule::kQuiet;
}

}  // namespace

AlertCollapser::AlertCollapser(std::string spacecraft_id, std::vector<AlertTrack> tracks,
                               absl::Duration window, absl::Time compute_time)
    : spacecraft_id_(std::move(spacecraft_id)),
      window_(window),
      compute_time_(compute_time),
      tracks_(std::move(tracks)) {}

std::vector<AlertTrack>::iterator AlertCollapser::EndTrack(std::vector<AlertTrack>::iterator it,
                                                           absl::Time time) {
  // The condition is over: a stored alert is cleared, one created in this job is stored cleared.
  auto p = pending_.find({it->reason, it->subsystem});
  if (p != pending_.end()) {
    new_alerts_[p->second].cleared = true;
    new_alerts_[p->second].cleared_time = time;
    pending_.erase(p);
  } else if (it->sequence > 0) {
    clears_.push_back({it->sequence, time});
  }
  return tracks_.erase(it);
}

void AlertCollapser::Advance(absl::Time time) {
  for (auto it = tracks_.begin(); it != tracks_.end();) {
    const bool over = RuleOf(it->reason) == ClearRule::kQuiet && time - it->last_time > window_;
    it = over ? EndTrack(it, it->last_time + window_) : it + 1;
  }
}

void AlertCollapser::End(const std::string& reason, const std::string& subsystem,
                         absl::Time time) {
  const std::string form = SubsystemForm(subsystem);
  for (auto it = tracks_.begin(); it != tracks_.end();) {
    const bool match =
        it->reason == reason && (it->subsystem == form || it->subsystem == subsystem);
    it = match ? EndTrack(it, time) : it + 1;
  }
}

void AlertCollapser::StarTrackerAccepted(absl::Time time) {
  for (auto it = tracks_.begin(); it != tracks_.end();) {
    it = RuleOf(it->reason) == ClearRule::kStarTrackerAccepted ? EndTrack(it, time) : it + 1;
  }
}

void AlertCollapser::Add(const AlertOccurrence& occurrence) {
  AlertOccurrence o = occurrence;
  o.subsystem = SubsystemForm(occurrence.subsystem);
  if (const AlertKind* kind = FindAlertKind(o.reason)) o.severity = SeverityName(kind->severity);
  auto it = std::find_if(tracks_.begin(), tracks_.end(), [&](const AlertTrack& t) {
    return t.reason == o.reason && t.subsystem == o.subsystem;
  });
  if (it != tracks_.end()) {
    ++it->repeat_count;
    it->last_time = o.time;
    auto p = pending_.find({o.reason, o.subsystem});
    if (p != pending_.end()) {
      storage::AlertRecord& a = new_alerts_[p->second];
      a.repeat_count = it->repeat_count;
      a.measurement_time = o.time;
      a.value = o.value;
      a.threshold = o.threshold;
      a.message = o.message;
    } else {
      storage::AlertRepeat& rep = repeats_[it->sequence];
      rep.spacecraft_id = spacecraft_id_;
      rep.sequence = it->sequence;
      rep.repeat_count = it->repeat_count;
      rep.last_time = o.time;
    }
    return;
  }
  storage::AlertRecord a;
  a.spacecraft_id = spacecraft_id_;
  a.severity = o.severity;
  a.reason = o.reason;
  a.subsystem = o.subsystem;
  a.value = o.value;
  a.threshold = o.threshold;
  a.unit = o.unit;
  a.repeat_count = 1;
  a.first_time = o.time;
  a.measurement_time = o.time;
  a.compute_time = compute_time_;
  a.message = o.message;
  pending_[{o.reason, o.subsystem}] = new_alerts_.size();
  new_alerts_.push_back(std::move(a));
  tracks_.push_back(AlertTrack{o.reason, o.subsystem, 0, 1, o.time});
}

std::vector<AlertTrack> AlertCollapser::Tracks(const std::vector<int64_t>& new_sequences) const {
  std::vector<AlertTrack> tracks = tracks_;
  for (AlertTrack& t : tracks) {
    auto p = pending_.find({t.reason, t.subsystem});
    if (p != pending_.end() && p->second < new_sequences.size()) {
      t.sequence = new_sequences[p->second];
    }
  }
  return tracks;
}

}  // namespace esg::server
