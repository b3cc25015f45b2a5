// Mapping between the service's stored records and estimator values on one side and the esg.v1
// messages on the other (docs/service.md "Alerts", "GetSession"): alert severities and reasons,
// session states and summaries, attitude samples, coefficient snapshots, ingest rejections.
#ifndef ESG_SERVER_PROTO_MAPPING_H_
#define ESG_SERVER_PROTO_MAPPING_H_

#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "esg/v1/estimation_service.pb.h"
#include "estimator/session.h"
#include "estimator/time_interval.h"
#include "estimator/utc_time.h"
#include "server/session_summary.h"
#include "storage/records.h"

namespace esg::server {

// Severity and reason of the alert an estimator event raises (server/alert_catalog.h).
esg::v1::AlertSeverity SeverityOf(estimator::Event::Kind kind);
esg::v1::AlertReason ReasonOf(estimator::Event::Kind kind);
// "INFO", "WARNING", "DISTRESS", "CRITICAL" as stored; "UNSPECIFIED" otherwise.
const char* SeverityName(esg::v1::AlertSeverity severity);

esg::v1::Alert AlertToProto(const storage::AlertRecord& record);
esg::v1::CoefficientSnapshot SnapshotToProto(const storage::CoefficientRecord& record);
esg::v1::SessionState StateToProto(estimator::SessionState state);
// A stored per-step estimate as the message (docs/service.md "Per-step estimates"): q_in_b
// canonical (q0 >= 0), 1-sigma and innovations in arcsec; the attitude's time is the
// measurement time and its spin_axes are not kept (empty).
esg::v1::EstimateRecord EstimateToProto(const storage::EstimateRecord& record);

// One attitude sample: q_in_b canonical (q0 >= 0), 1-sigma about body axes [arcsec], and the
// gyros' inertial spin axes h_in.
void FillSample(absl::Time time, const estimator::AttitudeEstimate& attitude,
                const std::vector<std::pair<int, Eigen::Vector3d>>& h_in,
                esg::v1::AttitudeSample* out);

// GetSession's message (docs/service.md "GetSession"): the counters and sequences as read; the
// state QUARANTINED while a quarantine reason is set, else the session's; the latest attitude
// (canonical q_in_b, 1-sigma [arcsec], inertial spin axes) once the session is initialised and
// valid; the star tracker's latency estimate; the model-consistency result shown (an
// inconsistent channel before a consistent one) and the drift the filter's noise was widened by
// [deg/h].
esg::v1::SessionInfo SessionInfoToProto(const SessionSummary& summary);

// A stored diagnosis as the message (docs/service.md "Diagnose"; DiagnosisRecord of storage/records.h): the report JSON verbatim.
esg::v1::DiagnosisResult DiagnosisToProto(const storage::DiagnosisRecord& record);

// An ingest refusal from a status whose message is "field: reason" (the error contract of
// proto/convert.h), with the status's code and, when the status carries a retry delay
// (grpc_status.h WithRetryDelay: another server holds the lease), retry_after_ms, at least 1.
esg::v1::Rejection RejectionFromStatus(const absl::Status& status);

// The one text form of an instant (estimator/utc_time.h), for messages.
using estimator::FormatUtc;

// The measurement-time interval of a request's optional `from` and `to`, [from, to] with both
// ends inclusive (estimator/time_interval.h); an absent end is open. InvalidArgument starting
// with the field: "from: ..." or "to: ..." for a time out of the Timestamp range, "to: T is before
// from F". Every RPC with from/to reads them here.
absl::StatusOr<estimator::TimeInterval> IntervalFromProto(
    const google::protobuf::Timestamp* from, const google::protobuf::Timestamp* to);
template <typename Request>
absl::StatusOr<estimator::TimeInterval> RequestInterval(const Request& request) {
  return IntervalFromProto(request.has_from() ? &request.from() : nullptr,
                           request.has_to() ? &request.to() : nullptr);
}

}  // namespace esg::server

#endif  // ESG_SERVER_PROTO_MAPPING_H_
