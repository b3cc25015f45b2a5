// A PostgreSQL outage under a real esgd (docs/service.md "Reconnects and retries", issue 33): the
// database of a running esgd (a session lease held, the alert relay listening) is killed with
// kill -9 for kOutage, while a station tries to send a frame. Checked: the log lines written
// during the outage are a handful (one per state change: the relay's connection lost, the lease
// renewal failing, the commit failing, the stream's summary), not one per reconnect attempt; the
// daemon's CPU time over the outage stays small; after the database is back, the relay and the
// ingest recover by themselves and a resent frame is stored. Measured figures are printed and
// recorded (RecordProperty), the assertions are counts and loose bounds.
//
// kOutage is 10 s, not the 30 s of the issue: every loop reaches its longest wait (1 s) after
// about 1.6 s of failures, so the rest of the outage repeats the same steady state.
#include <unistd.h>

#include <chrono>
#include <fstream>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/postgres_server.h"
#include "tests/testing/run_process.h"

namespace esg {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::Daemon;
using ::esg::testing::PostgresServer;
using ::esg::testing::SimulateRun;
using ::esg::testing::SimulatedRun;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;

constexpr std::chrono::seconds kOutage{10};

// utime + stime of `pid` [s] (/proc/<pid>/stat fields 14 and 15).
double CpuSeconds(pid_t pid) {
  std::ifstream in(absl::StrCat("/proc/", pid, "/stat"));
  std::string stat((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  const size_t paren = stat.rfind(')');
  if (paren == std::string::npos) return -1;
  std::vector<std::string> fields = absl::StrSplit(stat.substr(paren + 2), ' ');
  // After ") " the fields start at field 3 (state): utime is field 14, stime field 15.
  const double ticks = std::stod(fields[11]) + std::stod(fields[12]);
  return ticks / static_cast<double>(sysconf(_SC_CLK_TCK));
}

std::vector<std::string> Lines(const std::string& text) {
  return absl::StrSplit(text, '\n', absl::SkipEmpty());
}

// The text a JSON log line of `event` holds.
std::string Event(const std::string& event) { return absl::StrCat("\"event\":\"", event, "\""); }

int Count(const std::vector<std::string>& lines, const std::string& what) {
  int n = 0;
  for (const std::string& l : lines) n += absl::StrContains(l, what) ? 1 : 0;
  return n;
}

TEST(PostgresOutage, ReconnectLoopsBackOffLogOncePerStateChangeAndRecoverWhenTheDatabaseReturns) {
  std::string error;
  // A server of this process's own: it is killed.
  PostgresServer* pg = PostgresServer::Own(&error);
  ASSERT_NE(pg, nullptr) << "PostgreSQL could not start: " << error;
  absl::StatusOr<std::string> db = pg->CreateDatabase();
  ASSERT_TRUE(db.ok()) << db.status();
  TempDir dir;
  const std::string log = dir.File("esgd.log");
  Daemon daemon(*db, log, testing::DaemonLimits{},
                {"--node-id", "outage-0", "--log-format", "json"});
  ASSERT_GT(daemon.port(), 0) << testing::ReadFile(log);
  auto stub = daemon.Stub();
  const SimulatedRun run = SimulateRun("PGO-1", 1.0, 71);
  {
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
  }
  const std::vector<esg::v1::TelemetryFrame> first(run.frames.begin(), run.frames.begin() + 20);
  ASSERT_EQ(StreamFrames(*stub, first).acks.size(), first.size());
  std::this_thread::sleep_for(std::chrono::milliseconds(500));

  const size_t lines_before = Lines(testing::ReadFile(log)).size();
  const double cpu_before = CpuSeconds(daemon.pid());
  ASSERT_TRUE(pg->Kill().ok());
  const auto down = std::chrono::steady_clock::now();
  // A station sends during the outage: its stream fails UNAVAILABLE, ingest is refused.
  std::this_thread::sleep_for(std::chrono::seconds(1));
  const std::vector<esg::v1::TelemetryFrame> second(run.frames.begin() + 20,
                                                    run.frames.begin() + 21);
  const auto refused = StreamFrames(*stub, second);
  EXPECT_EQ(refused.status.error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_TRUE(refused.acks.empty());
  std::this_thread::sleep_until(down + kOutage);
  const double outage_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - down).count();
  const double cpu_s = CpuSeconds(daemon.pid()) - cpu_before;
  const std::vector<std::string> all = Lines(testing::ReadFile(log));
  const std::vector<std::string> during(all.begin() + static_cast<long>(lines_before), all.end());

  ASSERT_TRUE(pg->Restart().ok());
  const auto up = std::chrono::steady_clock::now();
  // Recovery: the relay follows again, and a resent frame is stored.
  double relay_s = -1;
  double ingest_s = -1;
  while (std::chrono::steady_clock::now() - up < std::chrono::seconds(20) &&
         (relay_s < 0 || ingest_s < 0)) {
    const double t = std::chrono::duration<double>(std::chrono::steady_clock::now() - up).count();
    if (relay_s < 0 && Count(Lines(testing::ReadFile(log)), Event("relay_recovered")) > 0) {
      relay_s = t;
    }
    if (ingest_s < 0) {
      const auto resent = StreamFrames(*stub, second);
      if (resent.status.ok() && resent.acks.size() == 1 && resent.acks[0].accepted()) ingest_s = t;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  std::ostringstream during_text;
  for (const std::string& l : during) during_text << l << "\n";
  std::printf(
      "PostgreSQL outage of %.1f s: %zu log lines, %.3f s of esgd CPU (%.2f %% of a core); "
      "after the restart: relay following again at %.3f s, a frame stored at %.3f s\n%s",
      outage_s, during.size(), cpu_s, 100.0 * cpu_s / outage_s, relay_s, ingest_s,
      during_text.str().c_str());
  RecordProperty("outage_log_lines", static_cast<int>(during.size()));
  RecordProperty("outage_cpu_ms", static_cast<int>(cpu_s * 1000));
  RecordProperty("relay_recovery_ms", static_cast<int>(relay_s * 1000));
  RecordProperty("ingest_recovery_ms", static_cast<int>(ingest_s * 1000));

  // One line per state change: the relay's loss, the lease renewal failing (every 5 s with the
  // default 15 s lease), the commit failing, the refused stream's summary; issue 33 saw 70,000
  // relay_interrupted lines a second.
  EXPECT_LE(Count(during, Event("relay_interrupted")) + Count(during, Event("relay_failed")), 1)
      << during_text.str();
  EXPECT_LE(Count(during, Event("lease_renewal_failed")), 1) << during_text.str();
  EXPECT_LE(Count(during, Event("storage_error")), 1) << during_text.str();
  EXPECT_LE(during.size(), 8u) << during_text.str();
  // A loose bound (the loops sleep between attempts): a core's tenth, where it was 98.7 %.
  EXPECT_LT(cpu_s, 0.1 * outage_s);
  EXPECT_GE(relay_s, 0) << testing::ReadFile(log);
  EXPECT_GE(ingest_s, 0) << testing::ReadFile(log);
  // Each loop waits at most 1 s between attempts; loose here, measured above.
  EXPECT_LT(relay_s, 5.0);
  EXPECT_LT(ingest_s, 5.0);
  const std::vector<std::string> after = Lines(testing::ReadFile(log));
  EXPECT_EQ(Count(after, Event("relay_recovered")), 1) << testing::ReadFile(log);
  EXPECT_EQ(Count(after, Event("storage_recovered")), 1) << testing::ReadFile(log);
}

}  // namespace
}  // namespace esg
