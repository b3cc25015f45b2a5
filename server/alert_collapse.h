// Alert collapsing as a pure function of the occurrences (docs/service.md "Alerts"): an occurrence
// of a (reason, subsystem) less than the window after the previous one is a repeat of that alert;
// a track without an occurrence for a whole window is over and its alert is cleared. The apply
// worker feeds one job's occurrences in measurement-time order and stores the effects in the same
// transaction as the checkpoint that carries the tracks.
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
  std::string severity;  // stored severity name, e.g. "WARNING"
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

  // Ends the tracks whose latest occurrence is more than the window before `time`.
  void Advance(absl::Time time);
  // A repeat of a live track, or a new alert.
  void Add(const AlertOccurrence& occurrence);
  // Ends the track of (reason, subsystem) now, if live: the condition is over.
  void End(const std::string& reason, const std::string& subsystem);

  // What to store: new alerts (sequences to be assigned by the store, in this order), repeats of
  // stored alerts (by sequence), stored alerts to clear.
  const std::vector<storage::AlertRecord>& new_alerts() const { return new_alerts_; }
  const std::map<int64_t, storage::AlertRepeat>& repeats() const { return repeats_; }
  const std::vector<int64_t>& clears() const { return clears_; }

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
  std::vector<int64_t> clears_;

  // Ends the track at `it` and returns the next.
  std::vector<AlertTrack>::iterator EndTrack(std::vector<AlertTrack>::iterator it);
};

}  // namespace esg::server

#endif  // ESG_SERVER_ALERT_COLLAPSE_H_
