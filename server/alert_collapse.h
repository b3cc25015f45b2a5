// Alert collapsing as a pure function of the occurrences (docs/service.md "Alerts"): an occurrence
// of a (reason, subsystem) while that alert is live is a repeat of it; the alert is cleared by the
// rule of its reason (server/alert_catalog.h ClearRule): a track without an occurrence for a whole
// window (kQuiet), a measurement step that uses the star tracker (kStarTrackerAccepted), the end of
// the quarantine (End), or never (kNever). Severity and subsystem form come from the catalog. The
// apply worker feeds one job's occurrences in measurement-time order and stores the effects in the
// same transaction as the checkpoint that carries the tracks.
#ifndef ESG_SERVER_ALERT_COLLAPSE_H_
#define ESG_SERVER_ALERT_COLLAPSE_H_

#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "absl/time/time.h"
#include "server/checkpoint_codec.h"
#include "storage/records.h"

namespace esg::server {

// One occurrence of an alert condition at a measurement epoch.
struct AlertOccurrence {
  std::string reason;    // stored reason name, e.g. "STAR_TRACKER_INNOVATION"
  // Stored severity name. Only used for a reason the catalog does not know: the catalog's
  // severity of the reason is stored otherwise.
  std::string severity;
  // Any subsystem text; stored in the catalog's form (SubsystemForm, alert_catalog.h).
  std::string subsystem;
  absl::Time time;       // measurement epoch
  double value = 0.0;
  double threshold = 0.0;
  std::string unit;
  std::string message;
};

class AlertCollapser {
 public:
  // `tracks`: the live tracks from the checkpoint (their alerts are stored).
  AlertCollapser(std::string spacecraft_id, std::vector<AlertTrack> tracks, absl::Duration window,
                 absl::Time compute_time);

  // Ends the kQuiet tracks whose latest occurrence is more than the window before `time`
  // (cleared_time: that occurrence + the window). Tracks of other rules are left alone.
  void Advance(absl::Time time);
  // A repeat of a live track, or a new alert.
  void Add(const AlertOccurrence& occurrence);
  // Ends the track of (reason, subsystem in any form), if live: the condition is over at the
  // measurement epoch `time`.
  void End(const std::string& reason, const std::string& subsystem, absl::Time time);
  // A measurement step at `time` used the star tracker's measurements: ends the
  // kStarTrackerAccepted tracks.
  void StarTrackerAccepted(absl::Time time);

  // A stored alert to clear and the measurement epoch at which its condition ended.
  struct Clear {
    int64_t sequence = 0;
    absl::Time time;
  };
  // What to store: new alerts (sequences to be assigned by the store, in this order; an alert
  // created and ended in this job is stored cleared with its cleared_time), repeats of stored
  // alerts (by sequence), stored alerts to clear.
  const std::vector<storage::AlertRecord>& new_alerts() const { return new_alerts_; }
  const std::map<int64_t, storage::AlertRepeat>& repeats() const { return repeats_; }
  const std::vector<Clear>& clears() const { return clears_; }

  // The live tracks after the job, given the sequences the store assigned to new_alerts().
  std::vector<AlertTrack> Tracks(const std::vector<int64_t>& new_sequences) const;

 private:
  using Key = std::pair<std::string, std::string>;  // (reason, subsystem)
  const std::string spacecraft_id_;
  const absl::Duration window_;
  const absl::Time compute_time_;
  std::vector<AlertTrack> tracks_;
  std::vector<storage::AlertRecord> new_alerts_;
  std::map<Key, size_t> pending_;  // alerts created in this job -> index into new_alerts_
  std::map<int64_t, storage::AlertRepeat> repeats_;
  std::vector<Clear> clears_;

  // Ends the track at `it`, cleared at `time`, and returns the next.
  std::vector<AlertTrack>::iterator EndTrack(std::vector<AlertTrack>::iterator it, absl::Time time);
};

}  // namespace esg::server

#endif  // ESG_SERVER_ALERT_COLLAPSE_H_
