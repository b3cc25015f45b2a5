// The operator's view of the real esgd (docs/service.md "Metrics" and "Logs"): the metrics
// endpoint scraped with curl over HTTP and parsed, its counters matching what a client sent and
// what was refused; and with --log-format json every line of the log parsing as one JSON object,
// including the WORKING_PAIR_FAULT alert (DISTRESS) of a gyro fault.
#include <cstdio>
#include <map>
#include <set>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/time/clock.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/prometheus_text.h"
#include "tests/testing/run_process.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::Daemon;
using ::esg::testing::Exposition;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StreamFrames;
using ::esg::testing::StreamResult;
using ::esg::testing::TempDir;

// Runs `command` through the shell and returns its stdout.
std::string RunShell(const std::string& command) {
  std::string out;
  FILE* pipe = popen(command.c_str(), "r");
  if (pipe == nullptr) return out;
  char buffer[4096];
  size_t n = 0;
  while ((n = fread(buffer, 1, sizeof buffer, pipe)) > 0) out.append(buffer, n);
  pclose(pipe);
  return out;
}

std::string Scrape(int port) {
  return RunShell(absl::StrCat("curl -sS --max-time 10 http://127.0.0.1:", port, "/metrics"));
}

void Configure(esg::v1::EstimationService::Stub& stub, const estimator::SpacecraftConfig& config) {
  grpc::ClientContext context;
  esg::v1::ConfigureResponse response;
  const grpc::Status status =
      stub.ConfigureSpacecraft(&context, ConfigureRequestFor(config), &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
}

// Every histogram: buckets cumulative (non-decreasing in le order) and +Inf equal to _count.
void ExpectHistogramsConsistent(const Exposition& e) {
  for (const auto& [name, type] : e.type) {
    if (type != "histogram") continue;
    std::map<std::map<std::string, std::string>, std::vector<double>> buckets;
    for (const esg::testing::Sample& s : e.samples) {
      if (s.name != name + "_bucket") continue;
      std::map<std::string, std::string> labels = s.labels;
      labels.erase("le");
      buckets[labels].push_back(s.value);
    }
    for (const auto& [labels, counts] : buckets) {
      for (size_t i = 1; i < counts.size(); ++i) EXPECT_LE(counts[i - 1], counts[i]) << name;
      EXPECT_EQ(counts.back(), e.Value(name + "_count", labels)) << name;
    }
  }
}

TEST(Observability, MetricsScrapedWithCurlCountWhatWasSentAndRefused) {
  TempDir dir;
  Daemon daemon(dir.File("esg.db"), dir.File("esgd.log"), {},
                {"--metrics-listen", "127.0.0.1:0"});
  ASSERT_GT(daemon.metrics_port(), 0);
  auto stub = daemon.Stub();
  const SimulatedRun run = SimulateRun("OBS-1", 2.0, 11);
  Configure(*stub, run.config);
  const double n = static_cast<double>(run.frames.size());

  const StreamResult first = StreamFrames(*stub, run.frames);
  ASSERT_TRUE(first.status.ok()) << first.status.error_message();
  ASSERT_EQ(first.acks.size(), run.frames.size());
  // Two duplicates, a frame with sequence 0 and one of a spacecraft nobody configured.
  std::vector<esg::v1::TelemetryFrame> second = {run.frames[0], run.frames[1], run.frames[5],
                                                 run.frames[6]};
  second[2].set_sequence(0);
  second[3].set_spacecraft_id("OBS-NOBODY");
  const StreamResult again = StreamFrames(*stub, second);
  ASSERT_TRUE(again.status.ok()) << again.status.error_message();
  ASSERT_EQ(again.acks.size(), 4u);
  EXPECT_TRUE(again.acks[0].duplicate());
  EXPECT_FALSE(again.acks[2].accepted());
  EXPECT_FALSE(again.acks[3].accepted());

  // The filter applies behind ingest: scrape until every frame went through a filter step.
  Exposition e;
  const absl::Time deadline = absl::Now() + absl::Seconds(60);
  for (;;) {
    const std::string text = Scrape(daemon.metrics_port());
    absl::StatusOr<Exposition> parsed = esg::testing::ParseExposition(text);
    ASSERT_TRUE(parsed.ok()) << parsed.status() << "\n" << text;
    e = *parsed;
    if (e.Sum("esg_filter_step_seconds_count") >= n || absl::Now() > deadline) break;
    absl::SleepFor(absl::Milliseconds(100));
  }
  RecordProperty("frames", static_cast<int>(n));
  const std::map<std::string, std::string> station = {{"station", "default"}};
  EXPECT_EQ(e.Value("esg_frames_received_total", station), n + 4);
  EXPECT_EQ(e.Value("esg_frames_acknowledged_total", {{"station", "default"}, {"outcome", "new"}}),
            n);
  EXPECT_EQ(
      e.Value("esg_frames_acknowledged_total", {{"station", "default"}, {"outcome", "duplicate"}}),
      2);
  EXPECT_EQ(e.Value("esg_frames_refused_total",
                    {{"station", "default"}, {"reason", "INVALID_ARGUMENT"}, {"field", "sequence"}}),
            1);
  EXPECT_EQ(e.Value("esg_frames_refused_total",
                    {{"station", "default"}, {"reason", "NOT_FOUND"}, {"field", "spacecraft_id"}}),
            1);
  EXPECT_EQ(e.Sum("esg_frames_refused_total"), 2);
  EXPECT_EQ(e.Sum("esg_frames_unacknowledged_total"), 0);
  EXPECT_EQ(e.Value("esg_ack_latency_seconds_count"), n + 4);
  EXPECT_GT(e.Value("esg_ack_latency_seconds_sum"), 0);
  // Every new frame stored by a group commit; the configuration by its own transaction.
  EXPECT_EQ(e.Value("esg_commit_batch_frames_sum"), n);
  EXPECT_GE(e.Value("esg_storage_commit_seconds_count", {{"transaction", "telemetry"}}), 1);
  EXPECT_EQ(e.Value("esg_storage_commit_seconds_count", {{"transaction", "configure"}}), 1);
  EXPECT_GE(e.Value("esg_storage_commit_seconds_count", {{"transaction", "filter"}}), 1);
  EXPECT_EQ(e.Sum("esg_filter_step_seconds_count"), n);
  EXPECT_GT(e.Value("esg_filter_step_seconds_count", {{"step", "measurement"}}), 0);
  EXPECT_EQ(e.Value("esg_storage_healthy"), 1);
  EXPECT_EQ(e.Value("esg_revisions_total"), 0);
  EXPECT_EQ(e.Value("esg_diagnoses_total", {{"result", "ok"}}), 0);
  // One spacecraft, in the state GetSession reports.
  EXPECT_EQ(e.Sum("esg_sessions"), 1);
  const esg::v1::SessionInfo info = esg::testing::Session(*stub, "OBS-1");
  const std::string state =
      std::string(absl::StripPrefix(esg::v1::SessionState_Name(info.state()), "SESSION_STATE_"));
  EXPECT_EQ(e.Value("esg_sessions", {{"state", state}}), 1) << state;
  ExpectHistogramsConsistent(e);
  // Every sample belongs to a family with a TYPE line (histograms: _bucket, _sum, _count).
  for (const esg::testing::Sample& s : e.samples) {
    const std::string base = s.name.substr(0, s.name.rfind('_'));
    EXPECT_TRUE(e.type.count(s.name) || e.type.count(base)) << "no TYPE line for " << s.name;
  }
  // Only /metrics is served.
  EXPECT_EQ(RunShell(absl::StrCat("curl -s -o /dev/null -w '%{http_code}' http://127.0.0.1:",
                             daemon.metrics_port(), "/")),
            "404");
}

// Simulates `hours` of the calibration profile of `id` with a 5 arcmin readout jump of gyro 2
// (in the working pair [1,2]) at `fault_hours`.
SimulatedRun SimulateGyroFault(const std::string& id, double hours, double fault_hours) {
  estimator::SimulationSpec spec;
  spec.config = esg::testing::ServerTestConfig(id);
  spec.duration = estimator::HoursToSeconds(hours);
  spec.seed = 8;
  estimator::GyroFault fault;
  fault.time = estimator::HoursToSeconds(fault_hours) + 30.0;
  fault.kind = estimator::GyroFault::Kind::kReadoutJump;
  fault.value = Eigen::Vector3d(estimator::ArcminToRad(5), 0, 0);
  spec.gyros[1].fault = fault;
  return esg::testing::SimulateCalibrationRun(id, spec);
}

TEST(Observability, JsonLogLinesParseAndCarryTheWorkingPairFault) {
  TempDir dir;
  const std::string log = dir.File("esgd.log");
  {
    Daemon daemon(dir.File("esg.db"), log, {}, {"--log-format", "json"});
    auto stub = daemon.Stub();
    const SimulatedRun run = SimulateGyroFault("OBS-2", 3.0, 2.5);
    Configure(*stub, run.config);
    std::vector<esg::v1::TelemetryFrame> frames = run.frames;
    esg::v1::TelemetryFrame refused = frames.back();
    refused.set_sequence(0);
    frames.push_back(refused);
    const StreamResult sent = StreamFrames(*stub, frames);
    ASSERT_TRUE(sent.status.ok()) << sent.status.error_message();
    ASSERT_EQ(sent.acks.size(), frames.size());
    esg::v1::SessionInfo info;
    const absl::Time deadline = absl::Now() + absl::Seconds(60);
    do {
      absl::SleepFor(absl::Milliseconds(100));
      info = esg::testing::Session(*stub, "OBS-2");
    } while (!info.degraded() && absl::Now() < deadline);
    // The jump excludes gyro 2 and the output moves to the clean pair: degraded, not FAULTED
    // (docs/decisions.md D94).
    ASSERT_TRUE(info.degraded()) << info.DebugString();
    EXPECT_NE(info.state(), esg::v1::SESSION_STATE_FAULTED) << info.DebugString();
    ASSERT_EQ(info.excluded_gyros_size(), 1) << info.DebugString();
    EXPECT_EQ(info.excluded_gyros(0).gyro_id(), 2);
    daemon.Stop(SIGTERM);
  }

  const std::string text = esg::testing::ReadFile(log);
  std::multiset<std::string> events;
  int lines = 0;
  bool critical = false;
  for (absl::string_view line : absl::StrSplit(text, '\n', absl::SkipEmpty())) {
    ++lines;
    nlohmann::json j;
    ASSERT_NO_THROW(j = nlohmann::json::parse(line)) << line;
    ASSERT_TRUE(j.is_object()) << line;
    for (const char* key : {"ts", "level", "event", "message"}) {
      ASSERT_TRUE(j.contains(key) && j[key].is_string()) << key << " in " << line;
    }
    EXPECT_TRUE(absl::EndsWith(j["ts"].get<std::string>(), "Z")) << line;
    events.insert(j["event"].get<std::string>());
    if (j["event"] == "alert_raised" && j.value("reason", "") == "WORKING_PAIR_FAULT") {
      EXPECT_EQ(j["severity"], "DISTRESS");
      EXPECT_EQ(j["level"], "ERROR");
      EXPECT_EQ(j["spacecraftId"], "OBS-2");
      EXPECT_TRUE(j["alertSequence"].is_number_integer());
      critical = true;
    }
    if (j["event"] == "session_state" && j["to"] == "FAULTED") {
      EXPECT_EQ(j["spacecraftId"], "OBS-2");
    }
    if (j["event"] == "stream_refusals") {
      EXPECT_EQ(j["framesRefused"], 1);
      EXPECT_THAT(j["message"].get<std::string>(), ::testing::HasSubstr("1 INVALID_ARGUMENT sequence"));
    }
  }
  RecordProperty("log_lines", lines);
  EXPECT_TRUE(critical) << "no DISTRESS WORKING_PAIR_FAULT line in\n" << text;
  for (const char* event : {"started", "spacecraft_configured", "session_state", "alert_raised",
                            "stream_refusals", "stopping", "stopped"}) {
    EXPECT_EQ(events.count(event) > 0, true) << event << " missing in\n" << text;
  }
}

}  // namespace
}  // namespace esg::server
