// Helpers shared by the server verbs (see server_common.h).
#include "client/commands/server_common.h"

#include <cstdio>
#include <string_view>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "google/protobuf/util/json_util.h"
#include "proto/convert.h"

namespace esg::client {
namespace {

std::string StripPrefix(const std::string& name, absl::string_view prefix) {
  return absl::StartsWith(name, prefix) ? name.substr(prefix.size()) : name;
}

Json Doubles(const google::protobuf::RepeatedField<double>& values) {
  Json out = Json::array();
  for (double v : values) out.push_back(v);
  return out;
}

Json Ints(const google::protobuf::RepeatedField<int32_t>& values) {
  Json out = Json::array();
  for (int32_t v : values) out.push_back(v);
  return out;
}

Json TimeJson(const google::protobuf::Timestamp& t, bool present) {
  if (!present) return nullptr;
  return FormatUtc(t);
}

}  // namespace

std::unique_ptr<EsgClient> Connect(const char* verb, const GlobalOptions& global) {
  ClientOptions options;
  options.server = global.server;
  options.tls_ca = global.tls_ca;
  options.tls_cert = global.tls_cert;
  options.tls_key = global.tls_key;
  options.token = global.token;
  absl::StatusOr<std::unique_ptr<EsgClient>> client = EsgClient::Create(options);
  if (!client.ok()) {
    ReportBadArgument(verb, std::string(client.status().message()));
    return nullptr;
  }
  return *std::move(client);
}

int ReportRpcError(const char* verb, const absl::Status& status, const GlobalOptions& global) {
  std::string message(status.message());
  if (status.code() == absl::StatusCode::kUnavailable) {
    message = absl::StrCat("server not reachable at ", global.server, " (", message, ")");
  }
  std::fprintf(stderr, "esg %s: %s: %s\n", verb, absl::StatusCodeToString(status.code()).c_str(),
               message.c_str());
  return kExitFailure;
}

int ReportBadArgument(const char* verb, const std::string& message) {
  std::fprintf(stderr, "esg %s: %s\n", verb, message.c_str());
  return kExitBadArguments;
}

std::string FormatUtc(absl::Time time) {
  return absl::FormatTime("%Y-%m-%dT%H:%M:%E*SZ", time, absl::UTCTimeZone());
}

std::string FormatUtc(const google::protobuf::Timestamp& timestamp, bool present) {
  if (!present) return "-";
  absl::StatusOr<absl::Time> t = proto_convert::TimeFromProto(timestamp);
  if (!t.ok()) return "(invalid time)";
  return FormatUtc(*t);
}

std::optional<absl::Time> ParseUtc(const std::string& text) {
  absl::Time t;
  std::string error;
  if (!absl::ParseTime(absl::RFC3339_full, text, &t, &error)) return std::nullopt;
  return t;
}

std::string StateName(esg::v1::SessionState state) {
  return StripPrefix(esg::v1::SessionState_Name(state), "SESSION_STATE_");
}

std::string SeverityName(esg::v1::AlertSeverity severity) {
  return StripPrefix(esg::v1::AlertSeverity_Name(severity), "ALERT_SEVERITY_");
}

std::string ReasonName(esg::v1::AlertReason reason) {
  return StripPrefix(esg::v1::AlertReason_Name(reason), "ALERT_REASON_");
}

Json AttitudeJson(const esg::v1::AttitudeSample& sample) {
  Json axes = Json::array();
  for (const esg::v1::GyroAxis& axis : sample.spin_axes()) {
    axes.push_back(Json{{"gyro", axis.gyro_id()}, {"hIn", Doubles(axis.h_in())}});
  }
  return Json{{"time", TimeJson(sample.time(), sample.has_time())},
              {"qInB", Doubles(sample.q_in_b())},
              {"sigmaArcsec", Doubles(sample.sigma_arcsec())},
              {"spinAxes", axes}};
}

Json SessionJson(const esg::v1::SessionInfo& s) {
  Json doc{{"spacecraftId", s.spacecraft_id()},
           {"state", StateName(s.state())},
           {"model", s.model()},
           {"workingPair", Ints(s.working_pair())},
           {"reservePair", Ints(s.reserve_pair())},
           {"lastFrameTime", TimeJson(s.last_frame_time(), s.has_last_frame_time())},
           {"lastSequence", s.last_sequence()},
           {"highestDurableSequence", s.highest_durable_sequence()},
           {"highestAppliedSequence", s.highest_applied_sequence()},
           {"framesAccepted", s.frames_accepted()},
           {"framesRejected", s.frames_rejected()},
           {"framesDuplicate", s.frames_duplicate()},
           {"framesConflicting", s.frames_conflicting()},
           {"framesApplied", s.frames_applied()},
           {"framesApplyFailed", s.frames_apply_failed()},
           {"starTrackerRejections", s.star_tracker_rejections()},
           {"activeAlerts", s.active_alerts()},
           {"unacknowledgedAlerts", s.unacknowledged_alerts()},
           {"latestAttitude", s.has_latest_attitude() ? AttitudeJson(s.latest_attitude()) : Json()},
           {"lastComputeTime", TimeJson(s.last_compute_time(), s.has_last_compute_time())}};
  if (!s.quarantine_reason().empty()) {
    doc["quarantineReason"] = s.quarantine_reason();
    doc["rebuilding"] = s.rebuilding();
  }
  Json stations = Json::array();
  for (const esg::v1::StationSequence& st : s.stations()) {
    stations.push_back(
        Json{{"stationId", st.station_id()}, {"highestDurableSequence", st.highest_durable_sequence()}});
  }
  doc["stations"] = stations;
  if (s.has_model_consistency()) {
    const esg::v1::ModelConsistency& mc = s.model_consistency();
    doc["modelConsistency"] = Json{
        {"consistent", mc.consistent()},
        {"channel", mc.channel()},
        {"value", mc.value()},
        {"threshold", mc.threshold()},
        {"windowSteps", mc.window_steps()},
        {"degreesOfFreedom", mc.degrees_of_freedom()},
        {"testTime", TimeJson(mc.test_time(), mc.has_test_time())},
        {"tests", mc.tests()},
        {"failingTests", mc.failing_tests()},
        {"widenedDriftDegH", mc.widened_drift_deg_h()},
        {"firstInconsistentTime",
         TimeJson(mc.first_inconsistent_time(), mc.has_first_inconsistent_time())}};
  }
  if (s.has_config()) {
    // The configuration in the form of its JSON file (docs/cli.md).
    std::string text;
    google::protobuf::util::JsonPrintOptions print;
    print.always_print_primitive_fields = true;
    if (google::protobuf::util::MessageToJsonString(s.config(), &text, print).ok()) {
      doc["config"] = Json::parse(text, nullptr, /*allow_exceptions=*/false);
    }
  }
  return doc;
}

Json AlertJson(const esg::v1::Alert& a) {
  return Json{{"spacecraftId", a.spacecraft_id()},
              {"sequence", a.sequence()},
              {"severity", SeverityName(a.severity())},
              {"reason", ReasonName(a.reason())},
              {"subsystem", a.subsystem()},
              {"value", a.value()},
              {"threshold", a.threshold()},
              {"unit", a.unit()},
              {"repeatCount", a.repeat_count()},
              {"firstTime", TimeJson(a.first_time(), a.has_first_time())},
              {"measurementTime", TimeJson(a.measurement_time(), a.has_measurement_time())},
              {"computeTime", TimeJson(a.compute_time(), a.has_compute_time())},
              {"acknowledged", a.acknowledged()},
              {"acknowledgedBy", a.acknowledged_by()},
              {"acknowledgedTime", TimeJson(a.acknowledged_time(), a.has_acknowledged_time())},
              {"cleared", a.cleared()},
              {"clearedTime", TimeJson(a.cleared_time(), a.has_cleared_time())},
              {"message", a.message()}};
}

}  // namespace esg::client
