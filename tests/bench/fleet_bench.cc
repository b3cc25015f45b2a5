// A fleet in real time on one node (docs/deploy.md "Capacity"): esgd on PostgreSQL with session
// leases (the shared test server on loopback), N spacecraft each sending one frame per second
// (1 s telemetry, the paper's calibration profile) over 4 StreamTelemetry calls, spacecraft i's
// frames spread over the second by i / N. After a warm-up the benchmark counts, over the
// measured window: the frames the filter applied per second (applied_fps), the database's write
// transactions per applied frame (commits_per_applied_frame: ingest's group commits, the
// filter's commits, lease renewals), and the acknowledgement latency of the frames sent in it
// (ack_p50_ms, ack_p99_ms: from the write of a frame to its ack, which follows its durable
// commit). With the group commit the transaction ids count each job's savepoint too, so
// xact_commit_per_applied_frame counts the commits themselves (pg_stat_database, read-only
// transactions included). Argument 2 is the filter's group commit
// (CoreOptions::filter_commit_group): 64, or 0 for one commit per filter job as before it;
// argument 3 its window in milliseconds (CoreOptions::filter_commit_window, docs/decisions.md
// D109). filter_commits_per_applied_frame counts the filter's own transactions (a group once,
// EstimationCore::filter_commit_counts), filter_jobs_per_commit the jobs each carried.
// One iteration each (wall time):
//   <dir>/tests/bench/esg_bench --benchmark_filter=BM_FleetAtOneHertz
#include <libpq-fe.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdlib>
#include <deque>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_format.h"
#include "absl/synchronization/mutex.h"
#include "benchmark/benchmark.h"
#include "grpcpp/create_channel.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/postgres_server.h"

namespace esg {
namespace {

using Clock = std::chrono::steady_clock;

constexpr int kStreams = 4;
constexpr int kWarmupSeconds = 15;
constexpr int kMeasuredSeconds = 30;

// Frames at 1 s (sequences 1..n) of spacecraft "FLEET", for the warm-up, the window and as long
// again after it (the window's snapshots may take that long).
const std::vector<esg::v1::TelemetryFrame>& OneHertzFrames() {
  static const auto* frames = [] {
    estimator::SimulationSpec spec;
    spec.config = testing::ServerTestConfig("FLEET");
    spec.duration = kWarmupSeconds + 2 * kMeasuredSeconds;
    spec.telemetry_step = 1.0;
    spec.seed = 11;
    return new std::vector<esg::v1::TelemetryFrame>(
        testing::SimulateCalibrationRun("FLEET", spec).frames);
  }();
  return *frames;
}

// One integer `sql` reads from the PostgreSQL database at `uri` (-1 on error).
int64_t QueryInt(const std::string& uri, const char* sql) {
  PGconn* conn = PQconnectdb(uri.c_str());
  int64_t value = -1;
  if (PQstatus(conn) == CONNECTION_OK) {
    PGresult* r = PQexec(conn, sql);
    if (PQresultStatus(r) == PGRES_TUPLES_OK && PQntuples(r) == 1) {
      value = std::strtoll(PQgetvalue(r, 0, 0), nullptr, 10);
    }
    PQclear(r);
  }
  PQfinish(conn);
  return value;
}

// The next transaction id of the PostgreSQL server at `uri` (write transactions get ids in
// order; this query takes one itself), as BM_IngestThroughGrpc counts them. A savepoint that
// writes takes an id of its own too, so with the filter's group commit this counts each job of
// a group, not the group's one commit: see CommittedTransactions.
int64_t NextXid(const std::string& uri) {
  return QueryInt(uri, "SELECT pg_current_xact_id()::text::bigint");
}

// Transactions committed in the database at `uri` so far (pg_stat_database.xact_commit: every
// commit, savepoints not counted, read-only transactions included; each connection reports its
// counts when idle, at most once a second).
int64_t CommittedTransactions(const std::string& uri) {
  return QueryInt(uri,
                  "SELECT xact_commit FROM pg_stat_database WHERE datname = current_database()");
}

std::string FleetId(int i) { return absl::StrFormat("FL-%05d", i); }

void BM_FleetAtOneHertz(benchmark::State& state) {
  const int n = static_cast<int>(state.range(0));
  std::string error;
  testing::PostgresServer* pg = testing::PostgresServer::Shared(&error);
  absl::StatusOr<std::string> db = pg != nullptr ? pg->CreateDatabase() : absl::UnavailableError(error);
  if (!db.ok()) {
    state.SkipWithError(std::string(db.status().message()).c_str());
    return;
  }
  server::ServerOptions options;
  options.core.node_id = "bench";
  options.core.filter_commit_group = static_cast<int>(state.range(1));
  options.core.filter_commit_window = absl::Milliseconds(state.range(2));
  testing::LoopbackServer server(options, *db);
  auto stub = server.Stub();
  const std::vector<esg::v1::TelemetryFrame>& frames = OneHertzFrames();

  for (auto _ : state) {
    // Configure the fleet, 16 calls at a time.
    const Clock::time_point setup_start = Clock::now();
    std::atomic<int> next{0};
    std::atomic<int> failed{0};
    {
      std::vector<std::thread> threads;
      for (int t = 0; t < 16; ++t) {
        threads.emplace_back([&] {
          estimator::SpacecraftConfig config = testing::ServerTestConfig("FLEET");
          for (int i = next++; i < n; i = next++) {
            config.spacecraft_id = FleetId(i);
            grpc::ClientContext context;
            esg::v1::ConfigureResponse response;
            if (!stub->ConfigureSpacecraft(&context, testing::ConfigureRequestFor(config),
                                           &response)
                     .ok()) {
              ++failed;
            }
          }
        });
      }
      for (std::thread& t : threads) t.join();
    }
    const double setup_s = std::chrono::duration<double>(Clock::now() - setup_start).count();
    if (failed > 0) {
      state.SkipWithError("a configuration failed");
      return;
    }

    // Stream: frame k of spacecraft i is written at start + k + i / n seconds.
    const Clock::time_point start = Clock::now() + std::chrono::milliseconds(200);
    const Clock::time_point window_start = start + std::chrono::seconds(kWarmupSeconds);
    const Clock::time_point window_end = window_start + std::chrono::seconds(kMeasuredSeconds);
    absl::Mutex latency_mu;
    std::vector<double> latencies_ms;
    std::atomic<int64_t> acked{0};
    std::atomic<int64_t> refused{0};
    std::vector<std::thread> streams;
    for (int s = 0; s < kStreams; ++s) {
      streams.emplace_back([&, s] {
        grpc::ClientContext context;
        auto stream = stub->StreamTelemetry(&context);
        absl::Mutex sent_mu;
        std::deque<Clock::time_point> sent;  // write times of the frames not yet acknowledged
        std::thread reader([&] {
          esg::v1::TelemetryAck ack;
          std::vector<double> mine;
          while (stream->Read(&ack)) {
            Clock::time_point at;
            {
              absl::MutexLock lock(&sent_mu);
              at = sent.front();
              sent.pop_front();
            }
            if (!ack.accepted()) ++refused;
            ++acked;
            if (at >= window_start && at < window_end) {
              mine.push_back(std::chrono::duration<double, std::milli>(Clock::now() - at).count());
            }
          }
          absl::MutexLock lock(&latency_mu);
          latencies_ms.insert(latencies_ms.end(), mine.begin(), mine.end());
        });
        for (size_t k = 0; k < frames.size(); ++k) {
          esg::v1::TelemetryFrame frame = frames[k];
          for (int i = s; i < n; i += kStreams) {
            std::this_thread::sleep_until(
                start + std::chrono::microseconds(static_cast<int64_t>(
                            1e6 * (static_cast<double>(k) + static_cast<double>(i) / n))));
            frame.set_spacecraft_id(FleetId(i));
            {
              absl::MutexLock lock(&sent_mu);
              sent.push_back(Clock::now());
            }
            if (!stream->Write(frame)) break;
          }
        }
        stream->WritesDone();
        reader.join();
        stream->Finish();
      });
    }
    // The filter's progress and the database's writes at both ends of the window.
    auto applied = [&] {
      int64_t total = 0;
      for (int i = 0; i < n; ++i) {
        absl::StatusOr<esg::v1::SessionInfo> info = server.core().GetSession(FleetId(i));
        if (info.ok()) total += info->frames_applied();
      }
      return total;
    };
    // A snapshot reads every session (GetSession) and may wait behind the database: the rates
    // are taken between the snapshots' ends, and the second snapshot's time is reported.
    std::this_thread::sleep_until(window_start);
    const int64_t applied_before = applied();
    const int64_t xid_before = NextXid(*db);
    const int64_t committed_before = CommittedTransactions(*db);
    const server::EstimationCore::FilterCommitCounts filter_before =
        server.core().filter_commit_counts();
    const Clock::time_point measured_from = Clock::now();
    std::this_thread::sleep_until(measured_from + std::chrono::seconds(kMeasuredSeconds));
    const Clock::time_point snapshot_start = Clock::now();
    const int64_t applied_after = applied();
    const int64_t xid_after = NextXid(*db);
    const int64_t committed_after = CommittedTransactions(*db);
    const server::EstimationCore::FilterCommitCounts filter_after =
        server.core().filter_commit_counts();
    const double snapshot_s = std::chrono::duration<double>(Clock::now() - snapshot_start).count();
    const double seconds = std::chrono::duration<double>(Clock::now() - measured_from).count();
    for (std::thread& t : streams) t.join();
    if (acked != static_cast<int64_t>(frames.size()) * n || refused > 0) {
      state.SkipWithError("frames not acknowledged or refused");
      return;
    }
    const int64_t applied_frames = applied_after - applied_before;
    state.counters["setup_s"] = setup_s;
    state.counters["snapshot_s"] = snapshot_s;
    state.counters["offered_fps"] = n;
    state.counters["applied_fps"] = static_cast<double>(applied_frames) / seconds;
    // The queries of the two snapshots (NextXid, CommittedTransactions) are not counted.
    const double committed = static_cast<double>(committed_after - committed_before - 2);
    state.counters["xact_commit_per_s"] = committed / seconds;
    state.counters["xact_commit_per_applied_frame"] =
        applied_frames > 0 ? committed / static_cast<double>(applied_frames) : 0;
    state.counters["commits_per_s"] = static_cast<double>(xid_after - xid_before - 1) / seconds;
    state.counters["commits_per_applied_frame"] =
        applied_frames > 0 ? static_cast<double>(xid_after - xid_before - 1) / applied_frames : 0;
    const int64_t filter_commits = filter_after.transactions - filter_before.transactions;
    state.counters["filter_commits_per_applied_frame"] =
        applied_frames > 0 ? static_cast<double>(filter_commits) / applied_frames : 0;
    state.counters["filter_jobs_per_commit"] =
        filter_commits > 0
            ? static_cast<double>(filter_after.jobs - filter_before.jobs) / filter_commits
            : 0;
    std::sort(latencies_ms.begin(), latencies_ms.end());
    if (!latencies_ms.empty()) {
      auto at = [&](double p) {
        return latencies_ms[std::min(latencies_ms.size() - 1,
                                     static_cast<size_t>(p * latencies_ms.size()))];
      };
      state.counters["ack_p50_ms"] = at(0.50);
      state.counters["ack_p99_ms"] = at(0.99);
    }
  }
  state.SetLabel(state.range(1) > 0 ? absl::StrFormat("filter group commit, window %d ms",
                                                       state.range(2))
                                     : std::string("one commit per filter job"));
}
BENCHMARK(BM_FleetAtOneHertz)
    ->ArgNames({"spacecraft", "group", "window_ms"})
    ->Args({500, 0, 0})
    ->Args({500, 64, 0})
    ->Args({500, 64, 25})
    ->Args({2000, 0, 0})
    ->Args({2000, 64, 0})
    ->Args({2000, 64, 25})
    ->Iterations(1)
    ->Unit(benchmark::kSecond)
    ->UseRealTime();

}  // namespace
}  // namespace esg
