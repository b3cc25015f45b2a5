// The alert catalog: one table that maps every alert reason (esg.v1.AlertReason) to its
// severity, the form of its subsystem text, the rule by which the service clears it, what it
// means and what an operator should do. It is the single source of these facts: the apply worker
// and the alert collapser take severities, subsystem forms and clearing rules from it, the proto
// comments of AlertReason and the table of docs/service.md "Alerts" repeat it, and
// tests/server/alert_lifecycle_test.cc checks that every enum value has a row and that the proto
// and the docs say the same.
#ifndef ESG_SERVER_ALERT_CATALOG_H_
#define ESG_SERVER_ALERT_CATALOG_H_

#include <optional>
#include <string>

#include "absl/strings/string_view.h"
#include "absl/types/span.h"
#include "esg/v1/attitude.pb.h"
#include "estimator/session.h"

namespace esg::server {

// When the service clears an alert (sets Alert.cleared and Alert.cleared_time).
enum class ClearRule {
  // No occurrence of the same (reason, subsystem) for the collapse window (measurement time);
  // cleared_time = the latest occurrence + the window, set at the first frame past it.
  kQuiet,
  // A later measurement step used the star tracker's measurements again; cleared_time = that
  // step's measurement time.
  kStarTrackerAccepted,
  // The quarantine ended (the rebuild caught up with the archive); cleared_time = the
  // measurement time of the last frame applied then.
  kQuarantineEnds,
  // Never cleared by the service: the condition lasts for the session's life.
  kNever,
};

struct AlertKind {
  esg::v1::AlertReason reason;
  // The stored reason: the enum value's name without "ALERT_REASON_".
  const char* name;
  esg::v1::AlertSeverity severity;
  // The estimator event that raises it; nullopt for conditions the service detects itself.
  std::optional<estimator::Event::Kind> event;
  // The form of Alert.subsystem, as the proto comment states it (e.g. "gyro_N").
  const char* subsystem;
  ClearRule clear_rule;
  // What happened, in one sentence.
  const char* meaning;
  // What the operator should do.
  const char* guidance;
};

// Every reason except ALERT_REASON_UNSPECIFIED, in enum order.
absl::Span<const AlertKind> AlertCatalog();

// The row of a reason, or of a stored reason name; nullptr if there is none.
const AlertKind* FindAlertKind(esg::v1::AlertReason reason);
const AlertKind* FindAlertKind(absl::string_view name);
// The row of an estimator event (every Event::Kind has one).
const AlertKind& AlertKindOf(estimator::Event::Kind kind);

// The rule in words, as docs/service.md states it.
const char* ClearRuleText(ClearRule rule);

// A subsystem text of the estimator or the service in the catalog's form: "gyro 2" -> "gyro_2",
// "gyros 1,2" -> "gyro_pair[1,2]", "gyros and star tracker" -> "gyros_and_star_tracker",
// "station S" -> "station:S"; a text already in a catalog form ("star_tracker",
// "working_pair[1,2]", "filter", ...) is returned unchanged.
std::string SubsystemForm(absl::string_view subsystem);

}  // namespace esg::server

#endif  // ESG_SERVER_ALERT_CATALOG_H_
