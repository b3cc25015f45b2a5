// The server verbs of `esg` (configure, replay, status, history, predict, alerts) run as real
// processes against a real `esgd` (ESGD_BINARY) on 127.0.0.1 with a database in a temporary
// directory: the whole operator flow over a simulated 6 h recording with star-tracker defects,
// resuming a replay across `kill -9` of the server, rejected frames, bearer tokens, and the exit
// codes (2 for bad arguments naming the option, 1 with UNAVAILABLE when no server listens).
#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <poll.h>
#include <signal.h>
#include <spawn.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/time/time.h"
#include "client/esg_client.h"
#include "esg/v1/estimation_service.grpc.pb.h"
#include "formats/aem.h"
#include "formats/recording_csv.h"
#include "gmock/gmock.h"
#include "grpcpp/server.h"
#include "grpcpp/server_builder.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "proto/convert.h"
#include "tests/client/cli_test_support.h"
#include "tests/testing/free_port.h"
#include "tests/testing/run_process.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

extern char** environ;

namespace esg::client {
namespace {

using ::esg::testing::FreeLoopbackPort;
using ::esg::testing::IsOk;
using ::esg::testing::ReadFile;
using ::esg::testing::TempDir;
using ::esg::testing::WriteFile;
using ::testing::HasSubstr;
using ::testing::Not;
using Json = nlohmann::json;

std::string FormatUtcForTest(absl::Time t) {
  return absl::FormatTime("%Y-%m-%dT%H:%M:%E3SZ", t, absl::UTCTimeZone());
}

// A 64-bit integer of the proto JSON mapping (a string there, a number in non-proto documents).
int64_t I64(const Json& value) {
  return value.is_string() ? std::stoll(value.get<std::string>()) : value.get<int64_t>();
}

// Starts `argv` with stdout and stderr redirected to files; returns the pid (or -1).
pid_t Spawn(const std::vector<std::string>& argv, const std::string& out, const std::string& err) {
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, STDOUT_FILENO, out.c_str(),
                                   O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_addopen(&actions, STDERR_FILENO, err.c_str(),
                                   O_WRONLY | O_CREAT | O_TRUNC, 0644);
  std::vector<char*> args;
  for (const std::string& a : argv) args.push_back(const_cast<char*>(a.c_str()));
  args.push_back(nullptr);
  pid_t pid = -1;
  const int rc = posix_spawn(&pid, args[0], &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  return rc == 0 ? pid : -1;
}

// Exit code of a finished child, -1 when it did not exit normally.
int WaitExit(pid_t pid) {
  int status = 0;
  if (::waitpid(pid, &status, 0) != pid) return -1;
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

// A real esgd on 127.0.0.1:port with the database `db`.
class Esgd {
 public:
  Esgd(const TempDir& dir, std::string db, int port, std::vector<std::string> extra = {})
      : dir_(dir), db_(std::move(db)), port_(port), extra_(std::move(extra)) {}
  ~Esgd() { Stop(SIGTERM); }

  // Starts the daemon and waits for its "listening on port" line.
  bool Start() {
    ++starts_;
    out_ = dir_.File("esgd_out_" + std::to_string(starts_) + ".txt");
    err_ = dir_.File("esgd_err_" + std::to_string(starts_) + ".txt");
    std::vector<std::string> argv = {ESGD_BINARY, "--listen", address(), "--db", db_};
    argv.insert(argv.end(), extra_.begin(), extra_.end());
    pid_ = Spawn(argv, out_, err_);
    if (pid_ < 0) return false;
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
    while (std::chrono::steady_clock::now() < deadline) {
      if (ReadFile(out_).find("esgd listening on port") != std::string::npos) return true;
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        return false;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return false;
  }

  // Sends `signal` and reaps the process.
  void Stop(int signal) {
    if (pid_ <= 0) return;
    ::kill(pid_, signal);
    int status = 0;
    ::waitpid(pid_, &status, 0);
    pid_ = -1;
  }

  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }
  std::string log() const { return ReadFile(err_); }

 private:
  const TempDir& dir_;
  std::string db_;
  int port_;
  std::vector<std::string> extra_;
  pid_t pid_ = -1;
  int starts_ = 0;
  std::string out_, err_;
};

// What `esg` printed and its exit code; json(): stdout parsed (discarded when not JSON).
struct RunResult : esg::testing::RunResult {
  Json json() const { return Json::parse(out, nullptr, /*allow_exceptions=*/false); }
};

// Runs `env esg <args>` through the shell, stdout and stderr captured.
RunResult RunEsg(const TempDir& dir, const std::string& args, const std::string& env = "") {
  return {esg::testing::RunBinary(dir, ESG_BINARY, args + " < /dev/null", env)};
}

std::vector<std::string> DataLines(const std::string& text, const std::string& prefix) {
  std::vector<std::string> out;
  for (absl::string_view line : absl::StrSplit(text, '\n')) {
    if (absl::StartsWith(line, prefix)) out.emplace_back(line);
  }
  return out;
}

// `esg replay` warns when esgd sent acks without a verdict (accepted = false, no rejection):
// esgd's Ingest fills `accepted` after handing the frame to the committer, a race that shows up
// now and then. The client sends such frames again and counts the second answer, so the tests
// below still hold; the race is recorded as a test property and printed.
void NoteAckRace(const std::string& err) {
  if (err.find("acks carried no verdict") == std::string::npos) return;
  ::testing::Test::RecordProperty("esgd_ack_race", "acks without a verdict seen");
  std::fprintf(stderr, "note: esgd sent acks without a verdict (race in EstimationCore::Ingest)\n");
}

// One simulated 6 h recording (60 s telemetry, star-tracker outliers, invalid samples and an
// outage, orbital profile) shared by the tests.
class ServerVerbs : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir;
    recording_path_ = dir_->File("rec.csv");
    const RunResult r =
        RunEsg(*dir_, "simulate --config " + Quote(Rdk1()) + " --scenario " +
                          Quote(std::string(ESG_SOURCE_DIR) +
                                "/deploy/examples/scenarios/star_tracker_defects.json") +
                          " --hours 6 --seed 11 --out " + Quote(recording_path_));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    auto recording = storage::ReadRecordingCsv(recording_path_);
    ASSERT_THAT(recording, IsOk());
    recording_ = new estimator::Recording(*std::move(recording));
  }
  static void TearDownTestSuite() {
    delete recording_;
    delete dir_;
  }
  static int64_t Rows() { return static_cast<int64_t>(recording_->frames.size()); }

  static TempDir* dir_;
  static std::string recording_path_;
  static estimator::Recording* recording_;
};
TempDir* ServerVerbs::dir_ = nullptr;
std::string ServerVerbs::recording_path_;
estimator::Recording* ServerVerbs::recording_ = nullptr;

TEST_F(ServerVerbs, ConfigureReplayStatusHistoryPredictAndAlerts) {
  TempDir dir;
  Esgd server(dir, dir.File("esg.db"), FreeLoopbackPort());
  ASSERT_TRUE(server.Start()) << server.log();
  const std::string at = "--server " + server.address() + " ";
  ASSERT_EQ(Rows(), 361);

  // configure: created, then the same configuration again (accepted, nothing changes); --server
  // also after the verb.
  RunResult r = RunEsg(dir, at + "configure --config " + Quote(Rdk1()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("RDK-1: created, model 10+11"));
  r = RunEsg(dir, "configure --config " + Quote(Rdk1()) + " --json " + at);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(r.json()["created"], false);
  EXPECT_EQ(r.json()["session"]["workingPair"], Json::array({1, 2}));

  // replay: every row accepted once, then applied by the filter (--wait).
  r = RunEsg(dir, at + "replay --recording " + Quote(recording_path_) + " --wait --json");
  ASSERT_EQ(r.exit_code, 0) << r.err << server.log();
  NoteAckRace(r.err);
  Json replay = r.json();
  EXPECT_EQ(replay["spacecraftId"], "RDK-1");  // from the recording's metadata
  EXPECT_EQ(replay["sent"], Rows());
  EXPECT_EQ(replay["acked"], Rows());
  EXPECT_EQ(replay["accepted"], Rows());
  EXPECT_EQ(replay["duplicates"], 0);
  EXPECT_EQ(replay["rejected"], 0);
  EXPECT_EQ(replay["highestDurableSequence"], Rows());
  EXPECT_EQ(replay["highestAppliedSequence"], Rows());

  // status: the frames, the last frame and an attitude.
  r = RunEsg(dir, at + "status --spacecraft RDK-1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json status = r.json();
  EXPECT_EQ(I64(status["framesAccepted"]), Rows());
  EXPECT_EQ(I64(status["lastSequence"]), Rows());
  EXPECT_EQ(I64(status["framesApplied"]), Rows());
  EXPECT_EQ(status["lastFrameTime"], FormatUtcForTest(recording_->frames.back().time));
  EXPECT_NE(status["state"], "SESSION_STATE_NO_DATA");
  ASSERT_TRUE(status["latestAttitude"].is_object());
  EXPECT_EQ(status["latestAttitude"]["qInB"].size(), 4u);
  EXPECT_EQ(status["config"]["spacecraftId"], "RDK-1");
  r = RunEsg(dir, at + "status");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("RDK-1"));
  EXPECT_THAT(r.out,
              HasSubstr("accepted 361, rejected 0, duplicates 0, conflicting 0, applied 361"));

  // history --csv: one row per snapshot, inside the recording's time span, same column count.
  r = RunEsg(dir, at + "history --spacecraft RDK-1 --csv");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::vector<std::string> lines = absl::StrSplit(r.out, '\n', absl::SkipEmpty());
  ASSERT_GT(lines.size(), 10u);
  EXPECT_THAT(lines[0], ::testing::StartsWith("time_utc,gyro,k0_deg_h,k0_sigma_deg_h,c1x_deg_h,"));
  EXPECT_THAT(lines[0], HasSubstr(",misalignment_z_sigma_arcsec,"));
  const size_t columns = std::vector<std::string>(absl::StrSplit(lines[0], ',')).size();
  std::set<int> gyros;
  for (size_t i = 1; i < lines.size(); ++i) {
    const std::vector<std::string> cells = absl::StrSplit(lines[i], ',');
    ASSERT_EQ(cells.size(), columns) << lines[i];
    absl::Time t;
    std::string error;
    ASSERT_TRUE(absl::ParseTime(absl::RFC3339_full, cells[0], &t, &error)) << cells[0];
    EXPECT_GE(t, recording_->frames.front().time);
    EXPECT_LE(t, recording_->frames.back().time);
    gyros.insert(std::stoi(cells[1]));
    EXPECT_TRUE(std::isfinite(std::stod(cells[2]))) << lines[i];
  }
  EXPECT_TRUE(gyros.count(1) && gyros.count(2)) << "working-pair gyros have snapshots";
  // The whole CSV header and the table's heading as docs/cli.md shows them (the coefficients'
  // names come from estimator/model_terms.h); a table row: time, gyro, k0 +-sigma, C1, C2, mu, nu,
  // misalignment, with the CSV's k0 at the table's 5 decimals.
  std::string expected_header = "time_utc,gyro";
  for (const char* stem : {"k0", "c1x", "c1y", "c1z", "c2x", "c2y", "c2z", "mu12", "mu23", "mu31",
                           "nu23", "nu31", "nu12"}) {
    absl::StrAppend(&expected_header, ",", stem, "_deg_h,", stem, "_sigma_deg_h");
  }
  for (const char* axis : {"x", "y", "z"}) {
    absl::StrAppend(&expected_header, ",misalignment_", axis, "_arcsec,misalignment_", axis,
                    "_sigma_arcsec");
  }
  EXPECT_EQ(lines[0], expected_header + ",compute_time_utc");
  r = RunEsg(dir, at + "history --spacecraft RDK-1");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<std::string> table = absl::StrSplit(r.out, '\n', absl::SkipEmpty());
  ASSERT_GE(table.size(), lines.size() + 1) << r.out;  // heading, rows, count line
  EXPECT_EQ(table[0],
            "time_utc               gyro        k0 +- sigma  C1 x,y,z                    C2 x,y,z   "
            "                 mu 12,23,31                 nu 23,31,12                 "
            "misalignment x,y,z [arcsec]");
  const std::vector<std::string> row = absl::StrSplit(table[1], ' ', absl::SkipEmpty());
  const std::vector<std::string> first_row = absl::StrSplit(lines[1], ',');
  ASSERT_EQ(row.size(), 19u) << table[1];
  EXPECT_EQ(row[0], first_row[0]);
  EXPECT_EQ(row[1], first_row[1]);
  EXPECT_NEAR(std::stod(row[2]), std::stod(first_row[2]), 5.1e-6) << table[1];
  r = RunEsg(dir, at + "history --spacecraft RDK-1 --gyro 2 --csv");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<std::string> gyro2 = DataLines(r.out, "20");
  ASSERT_FALSE(gyro2.empty());
  EXPECT_LT(gyro2.size(), lines.size() - 1);
  for (const std::string& line : gyro2) EXPECT_THAT(line, HasSubstr("Z,2,"));

  // predict: 1 h after the last frame every 10 min = 7 epochs, as a table and as an AEM that
  // storage's reader accepts.
  const absl::Time last = recording_->frames.back().time;
  const std::string from = FormatUtcForTest(last + absl::Minutes(1));
  const std::string to = FormatUtcForTest(last + absl::Minutes(61));
  const std::string aem = dir.File("predict.aem");
  r = RunEsg(dir, at + "predict --spacecraft RDK-1 --from " + from + " --to " + to +
                      " --step 600 --aem " + Quote(aem));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(DataLines(r.out, "20").size(), 7u) << r.out;
  auto parsed = storage::ParseAem(ReadFile(aem));
  ASSERT_THAT(parsed, IsOk());
  ASSERT_EQ(parsed->segments.size(), 1u);
  EXPECT_EQ(parsed->segments[0].samples.size(), 7u);
  EXPECT_EQ(parsed->segments[0].metadata.at("OBJECT_NAME"), "RDK-1");
  r = RunEsg(
      dir, at + "predict --spacecraft RDK-1 --from " + from + " --to " + to + " --step 600 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json predicted = r.json();
  ASSERT_EQ(predicted["samples"].size(), 7u);
  for (const Json& s : predicted["samples"]) {
    double norm2 = 0.0;
    for (double q : s["qInB"]) norm2 += q * q;
    EXPECT_NEAR(norm2, 1.0, 1e-9);
    ASSERT_EQ(s["sigmaArcsec"].size(), 3u);
    for (double sigma : s["sigmaArcsec"]) EXPECT_GT(sigma, 0.0);
    EXPECT_GE(s["spinAxes"].size(), 2u);
  }
  // A prediction before the archived data is the server's OUT_OF_RANGE, exit 1 (inside it, the
  // recorded readings are used: tests/server/prediction_test.cc).
  r = RunEsg(dir, at + "predict --spacecraft RDK-1 --from " +
                      FormatUtcForTest(recording_->frames.front().time - absl::Hours(1)) +
                      " --to " + to + " --step 600");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("esg predict: OUT_OF_RANGE: from: "));

  // alerts: the listing agrees with the session's counters; acknowledging one shows up.
  r = RunEsg(dir, at + "alerts --spacecraft RDK-1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json alerts = r.json()["alerts"];
  ASSERT_FALSE(alerts.empty()) << "the star-tracker defects raise alerts";
  int active = 0, unacknowledged = 0;
  std::set<std::string> reasons;
  for (const Json& a : alerts) {
    active += a["cleared"] ? 0 : 1;
    unacknowledged += a["acknowledged"] ? 0 : 1;
    reasons.insert(a["reason"].get<std::string>());
  }
  r = RunEsg(dir, at + "status --spacecraft RDK-1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(I64(r.json()["activeAlerts"]), active);
  EXPECT_EQ(I64(r.json()["unacknowledgedAlerts"]), unacknowledged);
  EXPECT_TRUE(std::any_of(reasons.begin(), reasons.end(), [](const std::string& reason) {
    return absl::StartsWith(reason, "ALERT_REASON_STAR_TRACKER_");
  })) << alerts.dump();
  // --follow: the stored alerts first (one JSON object per line), then the acknowledgement made
  // meanwhile as it happens; Ctrl-C ends it with exit 0.
  const std::string follow_out = dir.File("follow_out.txt");
  const pid_t follow = Spawn({ESG_BINARY, "--server", server.address(), "alerts", "--spacecraft",
                              "RDK-1", "--follow", "--json"},
                             follow_out, dir.File("follow_err.txt"));
  ASSERT_GT(follow, 0);
  auto wait_for = [&](const std::function<bool(const std::string&)>& done) {
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
    while (!done(ReadFile(follow_out)) && std::chrono::steady_clock::now() < deadline) {
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
    return done(ReadFile(follow_out));
  };
  EXPECT_TRUE(wait_for([&](const std::string& text) {
    return static_cast<size_t>(std::count(text.begin(), text.end(), '\n')) >= alerts.size();
  })) << ReadFile(follow_out);

  const int64_t first = I64(alerts[0]["sequence"]);
  r = RunEsg(
      dir, at + "alerts --spacecraft RDK-1 --ack " + std::to_string(first) + " --operator tester");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("acknowledged by tester"));

  EXPECT_TRUE(wait_for([](const std::string& text) {
    return text.find("\"acknowledgedBy\":\"tester\"") != std::string::npos;
  })) << ReadFile(follow_out);
  ::kill(follow, SIGINT);
  EXPECT_EQ(WaitExit(follow), 0) << ReadFile(dir.File("follow_err.txt"));
  const std::vector<std::string> followed =
      absl::StrSplit(ReadFile(follow_out), '\n', absl::SkipEmpty());
  EXPECT_EQ(followed.size(), alerts.size() + 1);
  for (const std::string& line : followed) {
    const Json alert = Json::parse(line, nullptr, /*allow_exceptions=*/false);
    ASSERT_TRUE(alert.is_object()) << line;
    EXPECT_EQ(alert["spacecraftId"], "RDK-1");
  }
  r = RunEsg(dir, at + "alerts --spacecraft RDK-1");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("RDK-1 #" + std::to_string(first) + " "));
  EXPECT_THAT(r.out, HasSubstr(", acknowledged by tester at "));
  EXPECT_THAT(r.out, HasSubstr(std::to_string(alerts.size()) + " alerts ("));
  r = RunEsg(dir, at + "alerts --spacecraft RDK-1 --ack 99999 --operator tester");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("esg alerts: NOT_FOUND: "));
}

// Streams the recording at 3600x real time (about 6 s), stops the server with `signal` after 60
// durable frames, starts it again on the same port and database, and checks that the running
// replay resumed and that every row was stored and applied exactly once.
void ReplayAcrossServerStop(const std::string& recording_path, int64_t rows, int signal) {
  TempDir dir;
  const int port = FreeLoopbackPort();
  // A short deadline for running calls, so that a graceful stop does not wait 5 s for the stream.
  const std::vector<std::string> esgd_args = {"--shutdown-deadline", "0.3"};
  auto server = std::make_unique<Esgd>(dir, dir.File("esg.db"), port, esgd_args);
  ASSERT_TRUE(server->Start()) << server->log();
  const std::string at = "--server " + server->address() + " ";
  RunResult r = RunEsg(dir, at + "configure --config " + Quote(Rdk1()));
  ASSERT_EQ(r.exit_code, 0) << r.err;

  const pid_t replay = Spawn({"/bin/sh", "-c",
                              Quote(ESG_BINARY) + " " + at + "replay --recording " +
                                  Quote(recording_path) + " --rate 3600 --json"},
                             dir.File("replay_out.txt"), dir.File("replay_err.txt"));
  ASSERT_GT(replay, 0);
  ClientOptions options;
  options.server = server->address();
  auto client = EsgClient::Create(options);
  ASSERT_THAT(client, IsOk());
  int64_t durable = 0;
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(60);
  while (durable < 60 && std::chrono::steady_clock::now() < deadline) {
    auto session = (*client)->GetSession("RDK-1");
    if (session.ok()) durable = session->highest_durable_sequence();
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  ASSERT_GE(durable, 60);
  ASSERT_LT(durable, rows) << "the replay must still be running when the server stops";
  server->Stop(signal);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  server = std::make_unique<Esgd>(dir, dir.File("esg.db"), port, esgd_args);
  ASSERT_TRUE(server->Start()) << server->log();

  ASSERT_EQ(WaitExit(replay), 0) << ReadFile(dir.File("replay_err.txt"));
  NoteAckRace(ReadFile(dir.File("replay_err.txt")));
  const Json first = Json::parse(ReadFile(dir.File("replay_out.txt")), nullptr, false);
  EXPECT_GE(first["reconnects"], 1);
  EXPECT_EQ(first["rejected"], 0);
  // Each row made durable exactly once: acked as accepted, or found durable at the reconnect
  // (its ack lost with the server's stop); none sent again as a duplicate.
  EXPECT_EQ(first["accepted"].get<int64_t>() + first["durableWithoutAck"].get<int64_t>(), rows);
  EXPECT_EQ(first["duplicates"], 0);
  EXPECT_EQ(first["highestDurableSequence"], rows);
  EXPECT_THAT(ReadFile(dir.File("replay_err.txt")), HasSubstr("reconnecting"));

  // The whole recording again: every frame is a duplicate, nothing new is accepted.
  r = RunEsg(dir, at + "replay --recording " + Quote(recording_path) + " --wait --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json second = r.json();
  EXPECT_EQ(second["duplicates"], rows);
  EXPECT_EQ(second["accepted"], 0);
  EXPECT_EQ(second["rejected"], 0);
  r = RunEsg(dir, at + "replay --recording " + Quote(recording_path));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out,
              HasSubstr("(accepted 0, duplicates " + std::to_string(rows) + ", rejected 0)"));

  r = RunEsg(dir, at + "status --spacecraft RDK-1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json status = r.json();
  EXPECT_EQ(I64(status["framesAccepted"]), rows);
  EXPECT_EQ(I64(status["lastSequence"]), rows);
  EXPECT_EQ(I64(status["highestAppliedSequence"]), rows);
  EXPECT_EQ(I64(status["framesApplied"]), rows) << "a frame applied twice, or one lost";
  EXPECT_GE(I64(status["framesDuplicate"]), 2 * rows);
}

// A configuration with a drift term beyond eq. (1), (10) (as `esg diagnose` adds one): `esg
// history` shows the term's estimate and 1-sigma under its gyro's row, and the JSON carries it.
TEST_F(ServerVerbs, HistoryShowsTheCalibratedBasisTermsOfAGyro) {
  TempDir dir;
  Json config = Json::parse(std::ifstream(Rdk1()));
  config["gyros"][0]["basisTerms"] =
      Json::array({{{"kind", "orbital_harmonic"}, {"axis", 1}, {"periodS", 5400},
                    {"sigmaDegH", 0.05}}});
  const std::string config_path = dir.File("rdk1-basis.json");
  std::ofstream(config_path) << config.dump(2);
  Esgd server(dir, dir.File("esg.db"), FreeLoopbackPort());
  ASSERT_TRUE(server.Start()) << server.log();
  const std::string at = "--server " + server.address() + " ";
  RunResult r = RunEsg(dir, at + "configure --config " + Quote(config_path));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = RunEsg(dir, at + "replay --recording " + Quote(recording_path_) + " --wait");
  ASSERT_EQ(r.exit_code, 0) << r.err << server.log();

  const int gyro = config["gyros"][0]["id"].get<int>();
  r = RunEsg(dir, at + "history --spacecraft RDK-1 --gyro " + std::to_string(gyro));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<std::string> lines = absl::StrSplit(r.out, '\n', absl::SkipEmpty());
  int basis_lines = 0;
  for (const std::string& line : lines) {
    if (!absl::StartsWith(line, "  basis ")) continue;
    ++basis_lines;
    EXPECT_THAT(line, HasSubstr("orbit cos 1 -> x"));
    EXPECT_THAT(line, HasSubstr(" +- "));
    EXPECT_THAT(line, HasSubstr("deg/h per 1"));
  }
  EXPECT_GT(basis_lines, 10);
  // The header, a row and a basis line per snapshot, the count.
  EXPECT_EQ(2 * basis_lines + 2, static_cast<int>(lines.size())) << r.out;

  r = RunEsg(dir, at + "history --spacecraft RDK-1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json history = r.json();
  Json last_of_gyro;
  for (const Json& s : history["snapshots"]) {
    EXPECT_EQ(s["basisTerms"].size(), s["gyroId"] == gyro ? 1u : 0u);
    if (s["gyroId"] == gyro) last_of_gyro = s;
  }
  ASSERT_EQ(last_of_gyro["basisTerms"].size(), 1u);
  EXPECT_EQ(last_of_gyro["basisTerms"][0]["kind"], "orbital_harmonic");
  EXPECT_EQ(last_of_gyro["basisTerms"][0]["periodS"], 5400);
  // Calibrated over the 6 h: its 1-sigma fell below the 0.05 deg/h prior.
  EXPECT_LT(last_of_gyro["basisTerms"][0]["sigmaDegH"].get<double>(), 0.05 / 2);
}

TEST_F(ServerVerbs, ReplayResumesAfterKillDashNineWithoutApplyingAnythingTwice) {
  ReplayAcrossServerStop(recording_path_, Rows(), SIGKILL);
}

TEST_F(ServerVerbs, ReplayResumesAfterGracefulServerRestart) {
  ReplayAcrossServerStop(recording_path_, Rows(), SIGTERM);
}

TEST_F(ServerVerbs, RejectedFramesAreReportedWithTheirFieldAndMakeExitOne) {
  TempDir dir;
  // A configuration without gyro 4 and a recording in which gyro 4 reports in rows 10, 20, 30.
  auto config = proto_convert::ReadConfigFile(Rdk1());
  ASSERT_THAT(config, IsOk());
  std::erase_if(config->gyros, [](const estimator::GyroConfig& g) { return g.id == 4; });
  for (const char* id : {"RDK-R", "RDK-S"}) {
    config->spacecraft_id = id;
    ASSERT_THAT(proto_convert::WriteConfigFile(dir.File(std::string(id) + ".json"), *config),
                IsOk());
  }
  estimator::Recording recording = *recording_;
  for (int row : {10, 20, 30})
    recording.frames[row - 1].gyros[3] = recording.frames[row - 1].gyros[0];
  ASSERT_THAT(storage::WriteRecordingCsv(dir.File("bad.csv"), recording), IsOk());

  Esgd server(dir, dir.File("esg.db"), FreeLoopbackPort());
  ASSERT_TRUE(server.Start()) << server.log();
  const std::string at = "--server " + server.address() + " ";
  for (const char* id : {"RDK-R", "RDK-S"}) {
    RunResult r =
        RunEsg(dir, at + "configure --config " + Quote(dir.File(std::string(id) + ".json")));
    ASSERT_EQ(r.exit_code, 0) << r.err;
  }
  RunResult r =
      RunEsg(dir, at + "replay --spacecraft RDK-R --recording " + Quote(dir.File("bad.csv")));
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.out, HasSubstr("(accepted 358, duplicates 0, rejected 3)"));
  EXPECT_THAT(r.err, HasSubstr("3 frames rejected"));
  EXPECT_THAT(r.err, HasSubstr("sequence 10: gyros[3].gyro_id: gyro 4 is not configured"));
  EXPECT_THAT(r.err, HasSubstr("sequence 30: "));

  // --allow-rejects: the same report, exit 0; --from-sequence skips the first rows.
  r = RunEsg(dir, at +
                      "replay --spacecraft RDK-S --from-sequence 5 --allow-rejects --json "
                      "--recording " +
                      Quote(dir.File("bad.csv")));
  EXPECT_EQ(r.exit_code, 0) << r.err;
  const Json doc = r.json();
  EXPECT_EQ(doc["acked"], Rows() - 4);
  EXPECT_EQ(doc["rejected"], 3);
  ASSERT_EQ(doc["rejections"].size(), 3u);
  EXPECT_EQ(doc["rejections"][0]["sequence"], 10);
  EXPECT_EQ(doc["rejections"][0]["field"], "gyros[3].gyro_id");
  EXPECT_THAT(r.err, HasSubstr("3 frames rejected"));
  r = RunEsg(dir, at + "status --spacecraft RDK-S --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(I64(r.json()["framesAccepted"]), Rows() - 4 - 3);
  EXPECT_EQ(I64(r.json()["framesRejected"]), 3);
}

TEST_F(ServerVerbs, BearerTokenIsSentFromOptionOrEnvironment) {
  TempDir dir;
  WriteFile(dir.File("tokens"),
            "# test tokens\nw-token-0123456789 read,write wendy\nr-token-0123456789 read\n"
            "s-token-0123456789 write station\n");
  // esgd refuses a token file that group or others can read or write.
  std::filesystem::permissions(
      dir.File("tokens"), std::filesystem::perms::owner_read | std::filesystem::perms::owner_write,
      std::filesystem::perm_options::replace);
  Esgd server(dir, dir.File("esg.db"), FreeLoopbackPort(), {"--tokens", dir.File("tokens")});
  ASSERT_TRUE(server.Start()) << server.log();
  const std::string at = "--server " + server.address() + " ";
  RunResult r = RunEsg(dir, at + "status", "env -u ESG_TOKEN");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("esg status: UNAUTHENTICATED: "));
  r = RunEsg(dir, at + "configure --config " + Quote(Rdk1()), "ESG_TOKEN=r-token-0123456789");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("esg configure: PERMISSION_DENIED: "));
  r = RunEsg(dir, at + "configure --config " + Quote(Rdk1()) + " --token w-token-0123456789",
             "env -u ESG_TOKEN");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  r = RunEsg(dir, at + "status", "ESG_TOKEN=r-token-0123456789");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("RDK-1  NO_DATA"));

  // --ack without --operator acknowledges in the token's name (the service takes it from the
  // token file), not $USER's; a read token cannot acknowledge.
  r = RunEsg(dir, at + "replay --recording " + Quote(recording_path_) + " --wait",
             "ESG_TOKEN=w-token-0123456789");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  // A write-only station token replays (its GetSession is refused; the acks say what is
  // durable); --wait needs the read role and says so at once.
  r = RunEsg(dir, at + "replay --recording " + Quote(recording_path_),
             "ESG_TOKEN=s-token-0123456789");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr("the token has no read role"));
  r = RunEsg(dir, at + "replay --recording " + Quote(recording_path_) + " --wait",
             "ESG_TOKEN=s-token-0123456789");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("--wait: polls the session, which needs a token with the read role"));
  r = RunEsg(dir, at + "alerts --spacecraft RDK-1 --json", "ESG_TOKEN=r-token-0123456789");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json alerts = r.json()["alerts"];
  ASSERT_FALSE(alerts.empty()) << "the star-tracker defects raise alerts";
  const std::string ack =
      "alerts --spacecraft RDK-1 --ack " + std::to_string(I64(alerts[0]["sequence"]));
  r = RunEsg(dir, at + ack, "ESG_TOKEN=r-token-0123456789 USER=someone");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("PERMISSION_DENIED"));
  r = RunEsg(dir, at + ack, "ESG_TOKEN=w-token-0123456789 USER=someone");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("acknowledged by wendy"));
}

// A CA, or a certificate signed by `ca` for 127.0.0.1, made with openssl.
bool MakeCa(const TempDir& dir, const std::string& name) {
  const std::string p = dir.File(name);
  const std::string cmd = "openssl req -x509 -newkey rsa:2048 -nodes -days 2 -subj /CN=" + name +
                          " -keyout " + p + ".key -out " + p + ".crt >/dev/null 2>&1";
  return std::system(cmd.c_str()) == 0;
}
bool MakeCert(const TempDir& dir, const std::string& ca, const std::string& name) {
  const std::string p = dir.File(name);
  const std::string c = dir.File(ca);
  WriteFile(p + ".ext", "subjectAltName=IP:127.0.0.1,DNS:localhost\n");
  const std::string cmd =
      "openssl req -newkey rsa:2048 -nodes -subj /CN=" + name + " -keyout " + p + ".key -out " + p +
      ".csr >/dev/null 2>&1 && openssl x509 -req -in " + p + ".csr -CA " + c + ".crt -CAkey " + c +
      ".key -CAcreateserial -days 2 -extfile " + p + ".ext -out " + p + ".crt >/dev/null 2>&1";
  return std::system(cmd.c_str()) == 0;
}

TEST_F(ServerVerbs, MutualTlsWithTheGlobalTlsOptions) {
  if (std::system("openssl version >/dev/null 2>&1") != 0) GTEST_SKIP() << "openssl missing";
  TempDir dir;
  ASSERT_TRUE(MakeCa(dir, "ca"));
  ASSERT_TRUE(MakeCert(dir, "ca", "server") && MakeCert(dir, "ca", "client"));
  Esgd server(dir, dir.File("esg.db"), FreeLoopbackPort(),
              {"--tls-cert", dir.File("server.crt"), "--tls-key", dir.File("server.key"),
               "--tls-client-ca", dir.File("ca.crt")});
  ASSERT_TRUE(server.Start()) << server.log();
  const std::string at = "--server " + server.address() + " --tls-ca " + Quote(dir.File("ca.crt"));
  const std::string client_cert = " --tls-cert " + Quote(dir.File("client.crt")) + " --tls-key " +
                                  Quote(dir.File("client.key"));
  RunResult r = RunEsg(dir, at + client_cert + " status");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("no spacecraft configured"));
  r = RunEsg(dir, at + client_cert + " configure --config " + Quote(Rdk1()));
  EXPECT_EQ(r.exit_code, 0) << r.err;
  r = RunEsg(dir, at + " status");  // no client certificate: the handshake is refused
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("esg status: UNAVAILABLE: "));
  r = RunEsg(dir, "--server " + server.address() + " status");  // plaintext
  EXPECT_EQ(r.exit_code, 1);
}

// An in-process stand-in for esgd that breaks the ack contract on purpose, for the client's
// defences: `no_verdict` sequences get, on first sight, accepted = false without a rejection
// (yet are stored, like the esgd ack race); from `refuse_from` on, the first stream refuses
// frames with "frame: the server is shutting down" (a graceful stop) and ends.
class FakeService final : public esg::v1::EstimationService::Service {
 public:
  std::set<int64_t> no_verdict;
  int64_t refuse_from = 0;

  grpc::Status GetSession(grpc::ServerContext*, const esg::v1::GetSessionRequest* request,
                          esg::v1::SessionInfo* response) override {
    std::lock_guard<std::mutex> lock(mu_);
    response->set_spacecraft_id(request->spacecraft_id());
    response->set_highest_durable_sequence(stored_.empty() ? 0 : *stored_.rbegin());
    return grpc::Status::OK;
  }

  grpc::Status StreamTelemetry(
      grpc::ServerContext*,
      grpc::ServerReaderWriter<esg::v1::TelemetryAck, esg::v1::TelemetryFrame>* stream) override {
    int stream_index = 0;
    {
      std::lock_guard<std::mutex> lock(mu_);
      stream_index = ++streams_;
    }
    esg::v1::TelemetryFrame frame;
    while (stream->Read(&frame)) {
      esg::v1::TelemetryAck ack;
      ack.set_spacecraft_id(frame.spacecraft_id());
      ack.set_sequence(frame.sequence());
      {
        std::lock_guard<std::mutex> lock(mu_);
        const int64_t seq = frame.sequence();
        if (stored_.count(seq)) {
          ack.set_accepted(true);
          ack.set_duplicate(true);
        } else if (stream_index == 1 && refuse_from > 0 && seq >= refuse_from) {
          ack.mutable_rejection()->set_field("frame");
          ack.mutable_rejection()->set_reason("the server is shutting down");
        } else {
          stored_.insert(seq);
          ack.set_accepted(!no_verdict.count(seq));
          no_verdict.erase(seq);
        }
        ack.set_highest_durable_sequence(*stored_.rbegin());
      }
      if (!stream->Write(ack)) break;
    }
    return grpc::Status::OK;
  }

  size_t stored() {
    std::lock_guard<std::mutex> lock(mu_);
    return stored_.size();
  }

 private:
  std::mutex mu_;
  std::set<int64_t> stored_;
  int streams_ = 0;
};

// Runs FakeService on 127.0.0.1 for the scope.
class FakeServer {
 public:
  explicit FakeServer(FakeService* service) {
    grpc::ServerBuilder builder;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port_);
    builder.RegisterService(service);
    server_ = builder.BuildAndStart();
  }
  ~FakeServer() {
    if (server_) server_->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(1));
  }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }

 private:
  int port_ = 0;
  std::unique_ptr<grpc::Server> server_;
};

TEST_F(ServerVerbs, ReplaySendsAgainFramesWhoseAckHadNoVerdict) {
  TempDir dir;
  FakeService service;
  service.no_verdict = {7, 8, 300};
  FakeServer server(&service);
  const RunResult r = RunEsg(
      dir, "--server " + server.address() + " replay --json --recording " + Quote(recording_path_));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json doc = r.json();
  EXPECT_EQ(doc["acksWithoutVerdict"], 3);
  EXPECT_EQ(doc["acksWithoutVerdictStored"], 3);
  EXPECT_EQ(doc["accepted"], Rows());
  EXPECT_EQ(doc["rejected"], 0);
  EXPECT_EQ(doc["duplicates"], 0);
  EXPECT_EQ(service.stored(), static_cast<size_t>(Rows()));
  EXPECT_THAT(r.err, HasSubstr("3 acks carried no verdict"));
}

TEST_F(ServerVerbs, ReplayTreatsAShuttingDownRefusalAsAStreamFailure) {
  TempDir dir;
  FakeService service;
  service.refuse_from = 100;
  FakeServer server(&service);
  const RunResult r = RunEsg(
      dir, "--server " + server.address() + " replay --json --recording " + Quote(recording_path_));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json doc = r.json();
  EXPECT_EQ(doc["reconnects"], 1);
  EXPECT_EQ(doc["accepted"], Rows());
  EXPECT_EQ(doc["rejected"], 0);
  EXPECT_EQ(service.stored(), static_cast<size_t>(Rows()));
  EXPECT_THAT(r.err, HasSubstr("the server is shutting down"));
}

TEST_F(ServerVerbs, ServerDownIsUnavailableWithTheAddress) {
  TempDir dir;
  const std::string address = "127.0.0.1:" + std::to_string(FreeLoopbackPort());
  const std::vector<std::string> verbs = {"status",
                                          "status --spacecraft RDK-1",
                                          "replay --recording " + Quote(recording_path_),
                                          "history --spacecraft RDK-1",
                                          "alerts --spacecraft RDK-1",
                                          "configure --config " + Quote(Rdk1())};
  for (const std::string& verb : verbs) {
    const RunResult r = RunEsg(dir, "--server " + address + " " + verb);
    EXPECT_EQ(r.exit_code, 1) << verb;
    EXPECT_THAT(r.err, HasSubstr(": UNAVAILABLE: server not reachable at " + address)) << verb;
  }
}

// A TCP relay on 127.0.0.1 that holds each accepted connection for `delay` before it connects to
// `target` and pumps bytes both ways: the server's HTTP/2 SETTINGS reach the client only after
// the delay, as from a server too busy to answer at once.
class SlowRelay {
 public:
  SlowRelay(int target_port, std::chrono::milliseconds delay) : target_(target_port), delay_(delay) {
    listener_ = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a = Loopback(0);
    socklen_t len = sizeof a;
    if (listener_ < 0 || ::bind(listener_, reinterpret_cast<sockaddr*>(&a), sizeof a) != 0 ||
        ::listen(listener_, 16) != 0 ||
        ::getsockname(listener_, reinterpret_cast<sockaddr*>(&a), &len) != 0) {
      ADD_FAILURE() << "relay: cannot listen on 127.0.0.1";
      return;
    }
    port_ = ntohs(a.sin_port);
    acceptor_ = std::thread([this] { Accept(); });
  }
  ~SlowRelay() {
    stopping_ = true;
    ::shutdown(listener_, SHUT_RDWR);
    ::close(listener_);
    if (acceptor_.joinable()) acceptor_.join();
    for (std::thread& t : pumps_) t.join();
  }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }

 private:
  static sockaddr_in Loopback(int port) {
    sockaddr_in a{};
    a.sin_family = AF_INET;
    a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    a.sin_port = htons(static_cast<uint16_t>(port));
    return a;
  }
  void Accept() {
    for (;;) {
      const int client = ::accept(listener_, nullptr, nullptr);
      if (client < 0) return;
      pumps_.emplace_back([this, client] { Relay(client); });
    }
  }
  void Relay(int client) {
    std::this_thread::sleep_for(delay_);
    const int server = ::socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in a = Loopback(target_);
    if (server >= 0 && ::connect(server, reinterpret_cast<sockaddr*>(&a), sizeof a) == 0) {
      pollfd fds[2] = {{client, POLLIN, 0}, {server, POLLIN, 0}};
      char buffer[16384];
      while (!stopping_ && ::poll(fds, 2, 200) >= 0) {
        bool closed = false;
        for (int i = 0; i < 2 && !closed; ++i) {
          if (fds[i].revents == 0) continue;
          const ssize_t n = ::read(fds[i].fd, buffer, sizeof buffer);
          closed = n <= 0 || ::write(fds[1 - i].fd, buffer, static_cast<size_t>(n)) != n;
        }
        if (closed) break;
      }
    }
    if (server >= 0) ::close(server);
    ::close(client);
  }
  int target_;
  std::chrono::milliseconds delay_;
  int listener_ = -1;
  int port_ = 0;
  std::atomic<bool> stopping_{false};
  std::thread acceptor_;
  std::vector<std::thread> pumps_;
};

// A server that takes a second to answer a new connection (busy, or far away) is waited for:
// each connection attempt has gRPC's 20 s, not the 0.2-2 s between attempts after a refusal.
// (With the attempt bounded by 200 ms, as before, every attempt timed out before the server's
// SETTINGS and the call failed UNAVAILABLE.)
TEST_F(ServerVerbs, AServerSlowToAnswerANewConnectionIsWaitedFor) {
  TempDir dir;
  const int port = FreeLoopbackPort();
  Esgd server(dir, dir.File("esg.db"), port);
  ASSERT_TRUE(server.Start()) << server.log();
  SlowRelay relay(port, std::chrono::milliseconds(1000));
  const RunResult r = RunEsg(dir, "--server " + relay.address() + " status --json");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_TRUE(r.json().contains("sessions")) << r.out;
}

TEST_F(ServerVerbs, BadArgumentsExitTwoNamingTheOption) {
  TempDir dir;
  const std::string at = "--server 127.0.0.1:1 ";
  struct Case {
    std::string args;
    std::string message;
  };
  const std::vector<Case> cases = {
      {"replay", "--recording"},
      {"replay --recording " + Quote(dir.File("missing.csv")), "--recording"},
      {"replay --recording " + Quote(recording_path_) + " --from-sequence 0", "--from-sequence 0"},
      {"replay --recording " + Quote(recording_path_) + " --rate -1", "--rate -1"},
      {"configure --config " + Quote(dir.File("missing.json")), "--config"},
      {"configure --config " + Quote(Rdk1()) + " --model 12", "model"},
      {"predict --spacecraft RDK-1 --from yesterday --to 2019-03-01T07:00:00Z --step 60", "--from"},
      {"predict --spacecraft RDK-1 --from 2019-03-01T07:00:00Z --to 2019-03-01T06:00:00Z --step 60",
       "--to"},
      {"predict --spacecraft RDK-1 --from 2019-03-01T07:00:00Z --to 2019-03-01T08:00:00Z --step 0",
       "--step"},
      {"predict --spacecraft RDK-1 --to 2019-03-01T08:00:00Z", "--to"},  // --from: now
      {"history --spacecraft RDK-1 --gyro 7", "--gyro 7"},
      {"history --gyro 1", "--spacecraft"},
      {"alerts --since never", "--since"},
      {"alerts --ack 3", "--spacecraft"},
      {"status --bogus", "--bogus"},
      {"--tls-cert " + Quote(Rdk1()) + " status", "--tls-cert"},
      {"--tls-ca " + Quote(dir.File("missing.pem")) + " status", "--tls-ca"},
  };
  for (const Case& c : cases) {
    const RunResult r = RunEsg(dir, at + c.args);
    EXPECT_EQ(r.exit_code, 2) << c.args << "\n" << r.err;
    EXPECT_THAT(r.err, HasSubstr(c.message)) << c.args;
    EXPECT_THAT(r.err, Not(HasSubstr("UNAVAILABLE"))) << c.args;
  }
}

}  // namespace
}  // namespace esg::client
