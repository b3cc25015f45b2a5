// The alert catalog (see alert_catalog.h). Changing a row means changing the AlertReason comment
// in proto/esg/v1/attitude.proto and the table in docs/service.md "Alerts" with it; the lifecycle
// test compares them.
#include "server/alert_catalog.h"

#include <array>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/strip.h"
#include "absl/strings/str_cat.h"

namespace esg::server {
namespace {

using esg::v1::AlertReason;
using estimator::Event;
constexpr esg::v1::AlertSeverity kInfo = esg::v1::ALERT_SEVERITY_INFO;
constexpr esg::v1::AlertSeverity kWarning = esg::v1::ALERT_SEVERITY_WARNING;
constexpr esg::v1::AlertSeverity kDistress = esg::v1::ALERT_SEVERITY_DISTRESS;
constexpr esg::v1::AlertSeverity kCritical = esg::v1::ALERT_SEVERITY_CRITICAL;

const std::array<AlertKind, 18> kCatalog = {{
    {esg::v1::ALERT_REASON_STAR_TRACKER_INNOVATION, "STAR_TRACKER_INNOVATION", kWarning,
     Event::Kind::kStarTrackerInnovation, "star_tracker", ClearRule::kQuiet,
     "eq. (14) rejected a star-tracker measurement (its innovation exceeded k_d sigma_z); the "
     "output ran on the gyros for that step",
     "None for an isolated outlier. A growing repeat_count means the star tracker or the drift "
     "model is wrong: check the star tracker's health and look for MODEL_INCONSISTENT or "
     "FILTER_WIDENED alerts"},
    {esg::v1::ALERT_REASON_STAR_TRACKER_FAULT, "STAR_TRACKER_FAULT", kDistress,
     Event::Kind::kStarTrackerFault, "star_tracker", ClearRule::kStarTrackerAccepted,
     "eq. (12) declared the star tracker faulty (both mismatches involving it exceed the allowed "
     "angle), or a filter reset was withheld because of it; its measurements are rejected and the "
     "output runs on the gyros alone",
     "Check the star tracker (blinding, lost lock, frozen output, time tag). The attitude drifts "
     "with the gyros' uncertainty until the star tracker is accepted again"},
    {esg::v1::ALERT_REASON_WORKING_PAIR_FAULT, "WORKING_PAIR_FAULT", kDistress,
     Event::Kind::kWorkingPairFault, "working_pair[A,B] or gyro_N", ClearRule::kNever,
     "an abrupt fault of a working gyro's readings (a jump, frozen or erratic readings, a drift "
     "change beyond the limit) was isolated by eq. (12) or the three pairs: the gyro is "
     "excluded and the output moved to a clean pair, valid; the session runs degraded",
     "The attitude output stays usable (from the clean pair). Check the named gyro's telemetry "
     "and power; switch on the cold spare to restore fault isolation, or reconfigure after "
     "repair (ConfigureSpacecraft replace = true)"},
    {esg::v1::ALERT_REASON_RESERVE_PAIR_FAULT, "RESERVE_PAIR_FAULT", kDistress,
     Event::Kind::kReservePairFault, "reserve_pair[A,B] or gyro_N", ClearRule::kNever,
     "an abrupt fault of the readings of a gyro outside the working pair was isolated by eq. "
     "(12) or the three pairs: the gyro is excluded; the output is unaffected, the redundancy is "
     "lost and the session runs degraded",
     "Check the named gyro; plan to restore redundancy (switch on the cold spare). The output "
     "may still be used"},
    {esg::v1::ALERT_REASON_GYRO_DATA_REJECTED, "GYRO_DATA_REJECTED", kWarning,
     Event::Kind::kGyroDataRejected, "gyro_pair[A,B]", ClearRule::kQuiet,
     "eq. (14) rejected the autonomous measurement z_avt of a gyro pair (the angle between its "
     "spin axes against the measured one); it was not applied",
     "None if isolated. Repeats point to a gyro of the pair leaving its drift model: watch for "
     "pair faults and run `esg diagnose` over the span"},
    {esg::v1::ALERT_REASON_STAR_TRACKER_INVALID, "STAR_TRACKER_INVALID", kInfo,
     Event::Kind::kStarTrackerInvalid, "star_tracker", ClearRule::kQuiet,
     "the star tracker flagged its own sample invalid; not raised today (the estimator skips "
     "such samples without an event)",
     "None"},
    {esg::v1::ALERT_REASON_FILTER_RESET, "FILTER_RESET", kDistress, Event::Kind::kFilterReset,
     "filter", ClearRule::kQuiet,
     "star-tracker data were rejected for 10 measurement steps in a row: the filter was taken to "
     "be wrong and its spin axes re-initialised from the star tracker",
     "Check the star tracker and the drift model (MODEL_INCONSISTENT, FILTER_WIDENED); the "
     "coefficients around the reset are less certain"},
    {esg::v1::ALERT_REASON_SESSION_QUARANTINED, "SESSION_QUARANTINED", kDistress, std::nullopt,
     "session", ClearRule::kQuarantineEnds,
     "the service cannot use the session's stored state or frames, or its filter failed; the "
     "message says why and whether it is being rebuilt from the archive",
     "If rebuilding, wait: it ends by itself. Otherwise read the message, fix the configuration "
     "or the cause and reconfigure with replace = true"},
    {esg::v1::ALERT_REASON_INGEST_CONFLICT, "INGEST_CONFLICT", kWarning, std::nullopt,
     "station:<station id>", ClearRule::kQuiet,
     "a frame reused the identity (station and sequence) or the measurement time of a stored "
     "frame with other content; it was refused with ALREADY_EXISTS",
     "Check the named ground station's sequence numbering and clock; the stored frame was kept"},
    {esg::v1::ALERT_REASON_ARCHIVED_FRAME_UNREADABLE, "ARCHIVED_FRAME_UNREADABLE", kWarning,
     std::nullopt, "station:<station id>", ClearRule::kQuiet,
     "an archived frame could not be decoded; the filter skipped it (value: its sequence)",
     "Check the disk and that one program version wrote the archive; resend the frame's data if "
     "the station still has it"},
    {esg::v1::ALERT_REASON_MODEL_INCONSISTENT, "MODEL_INCONSISTENT", kWarning,
     Event::Kind::kModelInconsistent,
     "model:gyro_N, model:gyros_N_M, model:star_tracker, model:all_gyros, model:common or model",
     ClearRule::kQuiet,
     "the running chi-square test of the filter's innovations failed: the configured drift model "
     "does not explain the data",
     "Run `esg diagnose` over the span to find the missing effect; reconfigure with a fuller "
     "model"},
    {esg::v1::ALERT_REASON_FAULT_AMBIGUOUS, "FAULT_AMBIGUOUS", kWarning,
     Event::Kind::kFaultAmbiguous, "gyro_N, star_tracker or gyros_and_star_tracker",
     ClearRule::kQuiet,
     "mismatches exceeded their allowed angles but no single gyro or the star tracker explains "
     "them, or one was named while the model is known not to fit; nothing was excluded",
     "Read the evidence in the message and check the named subsystems; nothing was switched "
     "automatically"},
    {esg::v1::ALERT_REASON_FILTER_WIDENED, "FILTER_WIDENED", kWarning,
     Event::Kind::kFilterWidened, "filter", ClearRule::kQuiet,
     "the star-tracker innovations stayed larger than the configured model allows: the filter "
     "widened (or keeps widened) its process noise; raised every window while widened",
     "The model does not fit: run `esg diagnose` and reconfigure with a fuller model; the "
     "coefficients carry the widened uncertainty meanwhile"},
    {esg::v1::ALERT_REASON_GYRO_READING_MISSING, "GYRO_READING_MISSING", kWarning,
     Event::Kind::kGyroReadingMissing, "gyro_N", ClearRule::kQuiet,
     "a running gyro had no reading in a frame: no measurement of it, the output moved to a pair "
     "with fresh readings or was marked not valid",
     "Check the gyro's telemetry path (packet loss, a gyro switched off); persistent: the gyro "
     "may have failed"},
    {esg::v1::ALERT_REASON_GYRO_STARTED, "GYRO_STARTED", kInfo, Event::Kind::kGyroStarted,
     "gyro_N", ClearRule::kQuiet,
     "a configured gyro that was not running reports (the cold spare switched on) and joined the "
     "filter",
     "None if the spare was commanded on; otherwise find out why it started"},
    {esg::v1::ALERT_REASON_STAR_TRACKER_REALIGNED, "STAR_TRACKER_REALIGNED", kWarning,
     Event::Kind::kStarTrackerRealigned, "star_tracker", ClearRule::kQuiet,
     "the gyro pairs voted the star tracker faulty for 10 steps in a row with a constant rotation "
     "between them (a mount shift): the star tracker is corrected by that rotation and used "
     "again, with the gyros as the reference",
     "Check the star tracker's mounting and thermal state; the correction stands until the star "
     "tracker's output or the configuration changes again"},
    {esg::v1::ALERT_REASON_DRIFT_CHANGED, "DRIFT_CHANGED", kWarning, Event::Kind::kDriftChanged,
     "gyro_N", ClearRule::kQuiet,
     "a gyro's drift changed by less than filter.driftChangeLimitDegH (its own star-tracker "
     "differences grew alone): not a fault; its drift coefficients were re-opened and are being "
     "recalibrated, nothing was excluded",
     "None at once: the gyro keeps producing. Watch its coefficient history; if the change "
     "repeats or grows, run `esg diagnose` over the span"},
    {esg::v1::ALERT_REASON_MODEL_DIAGNOSED, "MODEL_DIAGNOSED", kWarning, std::nullopt, "model",
     ClearRule::kQuiet,
     "the service's own diagnosis of a MODEL_INCONSISTENT alert is stored (value: its id, "
     "threshold: the alert's sequence); the message gives its verdict",
     "Read the diagnosis (`esg diagnoses show --id ID`); for a verdict naming an effect apply it "
     "with `esg model apply --diagnosis ID`; for none or unexplained there is nothing to apply: "
     "look at the span with `esg diagnose --out DIR` and the plots (docs/discovery.md)"},
}};

}  // namespace

absl::Span<const AlertKind> AlertCatalog() { return kCatalog; }

const AlertKind* FindAlertKind(esg::v1::AlertReason reason) {
  for (const AlertKind& k : kCatalog) {
    if (k.reason == reason) return &k;
  }
  return nullptr;
}

const AlertKind* FindAlertKind(absl::string_view name) {
  for (const AlertKind& k : kCatalog) {
    if (name == k.name) return &k;
  }
  return nullptr;
}

const AlertKind& AlertKindOf(estimator::Event::Kind kind) {
  for (const AlertKind& k : kCatalog) {
    if (k.event == kind) return k;
  }
  // Unreachable while the lifecycle test passes (every Event::Kind has a row); a new event kind
  // without a row must not crash the service: it is reported as a filter warning.
  static const AlertKind kUnknown = {esg::v1::ALERT_REASON_UNSPECIFIED,
                                     "UNSPECIFIED",
                                     kWarning,
                                     std::nullopt,
                                     "filter",
                                     ClearRule::kQuiet,
                                     "an estimator event the catalog does not know",
                                     "Report it: the service's alert catalog needs a row"};
  return kUnknown;
}

const char* ClearRuleText(ClearRule rule) {
  switch (rule) {
    case ClearRule::kQuiet:
      return "when quiet for the collapse window";
    case ClearRule::kStarTrackerAccepted:
      return "when a measurement step uses the star tracker again";
    case ClearRule::kQuarantineEnds:
      return "when the quarantine ends";
    case ClearRule::kNever:
      return "never by the service";
  }
  return "?";
}

std::string SubsystemForm(absl::string_view s) {
  if (s == "gyros and star tracker") return "gyros_and_star_tracker";
  if (absl::ConsumePrefix(&s, "station ")) return absl::StrCat("station:", s);
  if (absl::ConsumePrefix(&s, "gyros ")) {
    return absl::StrCat("gyro_pair[", absl::StripAsciiWhitespace(s), "]");
  }
  if (absl::ConsumePrefix(&s, "gyro ")) return absl::StrCat("gyro_", s);
  return std::string(s);
}

}  // namespace esg::server
