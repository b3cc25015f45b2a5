// `esg status [--spacecraft ID]`: the state of one session (GetSession) or of all (ListSessions):
// life-cycle state, calibration model, working and reserve pairs, last frame, ingest and apply
// counters, star-tracker rejections (eq. (14), (12)), alert counts and the latest attitude with
// its 1-sigma about the body axes.
// Exit codes: 0 success, 2 bad arguments, 1 server failure (NOT_FOUND for an unknown spacecraft).
#include <cstdio>
#include <iostream>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/str_replace.h"
#include "client/commands/commands.h"
#include "client/commands/server_common.h"

namespace esg::client {
namespace {

constexpr char kVerb[] = "status";

struct StatusOptions {
  std::string spacecraft_id;
  OutputFormat format = OutputFormat::kTable;
};

// CSV record of a session: its JSON form without the configuration (a file of its own,
// docs/formats.md).
Json SessionRecord(const esg::v1::SessionInfo& s) {
  Json record = SessionJson(s);
  record.erase("config");
  return record;
}

std::string Ids(const google::protobuf::RepeatedField<int32_t>& ids) {
  std::string out = "[";
  for (int i = 0; i < ids.size(); ++i) out += (i ? "," : "") + std::to_string(ids[i]);
  return out + "]";
}

void PrintSession(const esg::v1::SessionInfo& s) {
  auto n = [](int64_t v) { return static_cast<long long>(v); };
  std::printf("%s  %s  model %s%s\n", s.spacecraft_id().c_str(), StateName(s.state()).c_str(),
              s.model().c_str(),
              s.served_by().empty() ? "" : ("  served by " + s.served_by()).c_str());
  if (!s.quarantine_reason().empty()) {
    std::printf("  quarantined%s: %s\n", s.rebuilding() ? " (rebuilding from the archive)" : "",
                s.quarantine_reason().c_str());
  }
  std::printf("  working pair %s, reserve pair %s\n", Ids(s.working_pair()).c_str(),
              Ids(s.reserve_pair()).c_str());
  if (s.degraded()) {
    std::printf("  DEGRADED: output from a clean pair, valid; predictions served\n");
  }
  for (const esg::v1::ExcludedGyro& x : s.excluded_gyros()) {
    // The reason in words ("reading jump"), as the console's fleet view shows it.
    std::printf("  gyro %d excluded (%s): %s\n", x.gyro_id(),
                absl::StrReplaceAll(absl::AsciiStrToLower(x.reason()), {{"_", " "}}).c_str(),
                x.message().c_str());
  }
  std::printf("  last frame %s (sequence %lld); durable up to %lld, applied up to %lld\n",
              FormatUtc(s.last_frame_time(), s.has_last_frame_time()).c_str(), n(s.last_sequence()),
              n(s.highest_durable_sequence()), n(s.highest_applied_sequence()));
  if (s.stations_size() > 1 || (s.stations_size() == 1 && s.stations(0).station_id() != "default")) {
    std::printf("  stations:");
    for (const esg::v1::StationSequence& st : s.stations()) {
      std::printf(" %s durable up to %lld;", st.station_id().c_str(),
                  n(st.highest_durable_sequence()));
    }
    std::printf("\n");
  }
  std::printf(
      "  frames: accepted %lld, rejected %lld, duplicates %lld, conflicting %lld, applied %lld, "
      "apply failed %lld\n",
      n(s.frames_accepted()), n(s.frames_rejected()), n(s.frames_duplicate()),
      n(s.frames_conflicting()), n(s.frames_applied()), n(s.frames_apply_failed()));
  std::printf("  star-tracker rejections %lld; alerts active %lld, unacknowledged %lld\n",
              n(s.star_tracker_rejections()), n(s.active_alerts()), n(s.unacknowledged_alerts()));
  if (s.has_latest_attitude()) {
    const esg::v1::AttitudeSample& a = s.latest_attitude();
    std::printf("  attitude at %s: q_in_b", FormatUtc(a.time(), a.has_time()).c_str());
    for (double q : a.q_in_b()) std::printf(" %+.9f", q);
    std::printf(", 1-sigma body x,y,z");
    for (double sigma : a.sigma_arcsec()) std::printf(" %.2f", sigma);
    std::printf(" arcsec\n");
  } else {
    std::printf("  attitude: none yet\n");
  }
  if (s.has_model_consistency()) {
    const esg::v1::ModelConsistency& mc = s.model_consistency();
    const bool widened = mc.widened_drift_deg_h() > 0.0;
    if (widened) {
      std::printf(
          "  FILTER WIDENED: process noise as an unmodelled drift of %.3g deg/h, because the "
          "star-tracker innovations exceeded what the configured model allows; run esg "
          "diagnose\n",
          mc.widened_drift_deg_h());
    }
    if (mc.tests() == 0) {
      // no consistency test yet (the first window is a warm-up)
    } else if (mc.consistent() || (widened && mc.value() <= mc.threshold())) {
      std::printf("  %s with the data: %s %.1f <= %.1f over %d steps (%d tests)\n",
                  widened ? "widened filter consistent" : "model consistent",
                  mc.channel().c_str(), mc.value(), mc.threshold(), mc.window_steps(), mc.tests());
    } else {
      std::printf(
          "  MODEL INCONSISTENT with the data: %s %.1f > %.1f over %d steps at %s (first at %s, "
          "%d of %d tests failed); run esg diagnose to find what the model leaves out\n",
          mc.channel().c_str(), mc.value(), mc.threshold(), mc.window_steps(),
          FormatUtc(mc.test_time(), mc.has_test_time()).c_str(),
          FormatUtc(mc.first_inconsistent_time(), mc.has_first_inconsistent_time()).c_str(),
          mc.failing_tests(), mc.tests());
    }
  }
  if (s.has_star_tracker_latency() && (s.star_tracker_latency().estimated() ||
                                       s.star_tracker_latency().latency_s() != 0.0)) {
    const esg::v1::StarTrackerLatency& l = s.star_tracker_latency();
    if (l.estimated()) {
      std::printf("  star-tracker latency %+.4f +- %.4f s (estimated)\n", l.latency_s(), l.sigma_s());
    } else {
      std::printf("  star-tracker latency %+.4f s (configured, held)\n", l.latency_s());
    }
  }
  std::printf("  last update %s\n",
              FormatUtc(s.last_compute_time(), s.has_last_compute_time()).c_str());
}

int RunStatus(const StatusOptions& o, const GlobalOptions& global) {
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  if (!o.spacecraft_id.empty()) {
    absl::StatusOr<esg::v1::SessionInfo> session = client->GetSession(o.spacecraft_id);
    if (!session.ok()) return ReportRpcError(kVerb, session.status(), global);
    if (o.format == OutputFormat::kJson) {
      PrintJson(SessionJson(*session));
    } else if (o.format == OutputFormat::kCsv) {
      PrintCsv({SessionRecord(*session)}, {"spacecraftId", "state"});
    } else {
      PrintSession(*session);
    }
    return kExitOk;
  }
  absl::StatusOr<esg::v1::ListSessionsResponse> list = client->ListSessions();
  if (!list.ok()) return ReportRpcError(kVerb, list.status(), global);
  if (o.format == OutputFormat::kJson) {
    Json doc = ProtoToJson(*list);
    doc.erase("nextPageToken");  // every page is in the list
    PrintJson(doc);
  } else if (o.format == OutputFormat::kCsv) {
    std::vector<Json> records;
    for (const esg::v1::SessionInfo& s : list->sessions()) records.push_back(SessionRecord(s));
    PrintCsv(records, {"spacecraftId", "state"});
  } else if (list->sessions().empty()) {
    std::printf("no spacecraft configured on %s\n", global.server.c_str());
  } else {
    for (const esg::v1::SessionInfo& s : list->sessions()) PrintSession(s);
  }
  return kExitOk;
}

}  // namespace

void RegisterStatus(CLI::App& app, GlobalOptions& global, int* exit_code) {
  auto options = std::make_shared<StatusOptions>();
  CLI::App* cmd = app.add_subcommand(
      kVerb, "state of one spacecraft's session, or of all (GetSession, ListSessions)");
  cmd->add_option("--spacecraft", options->spacecraft_id, "spacecraft id (default: all)");
  AddFormatOption(cmd, &options->format);
  cmd->callback([options, &global, exit_code] { *exit_code = RunStatus(*options, global); });
}

}  // namespace esg::client
