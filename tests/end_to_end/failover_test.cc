// Sessions that move with the routing (docs/service.md "Several servers", docs/deploy.md): a
// real PostgreSQL on loopback, three real esgd child processes sharing its database with session
// leases, and a real nginx running the shipped deploy/nginx/esg.conf in front of them. 60
// spacecraft are configured and streamed through nginx; mid-stream the node serving the first
// spacecraft is killed with kill -9. Each spacecraft's station goes on as a ground station does:
// it resends every frame not acknowledged yet, through nginx, which routes the killed node's
// spacecraft to the remaining nodes; those answer UNAVAILABLE (lease held) until the dead
// node's leases expire, then take the sessions over (checkpoint plus archive after it) and go
// on.
//
// Checked, for every spacecraft: each frame is archived exactly once (the archive holds exactly
// the recording's frames, each once), its whole coefficient history equals that of an
// uninterrupted offline calibration of the recording to 1e-12 deg/h (no frame applied twice or
// lost, by the node that died or the one that took over), and the final session state equals
// the offline one exactly; the killed node's spacecraft are served by another node under a new
// lease epoch, the others kept theirs.
//
// Also here, with two esgd on one database and no router: the fleet seen from any server, the
// alerts and estimates relayed between them, the retry delay a refused call or frame carries,
// and `esg replay` waiting for it.
#include <signal.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/units.h"
#include "formats/recording_csv.h"
#include "gmock/gmock.h"
#include "grpcpp/support/channel_arguments.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "proto/convert.h"
#include "storage/storage.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/nginx.h"
#include "tests/testing/postgres_server.h"
#include "tests/testing/prometheus_text.h"
#include "tests/testing/run_process.h"

namespace esg {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::Daemon;
using ::esg::testing::Nginx;
using ::esg::testing::NginxBinary;
using ::esg::testing::OfflineCoefficientHistory;
using ::esg::testing::OfflineSessionValues;
using ::esg::testing::PostgresServer;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StoredSessionValues;
using ::esg::testing::TempDir;

constexpr int kNodes = 3;
constexpr int kSpacecraft = 60;
constexpr double kHours = 1.0;  // 61 frames at 60 s each
// The node port on 127.0.0.21, .22 and .23 (fixed addresses: see nginx_routing_test.cc).
constexpr int kNodePort = 29061;
constexpr int kLeaseSeconds = 2;
// Frames a station sends per stream before it looks at the acks again: small, so that the kill
// lands in the middle of many streams.
constexpr int kFramesPerStream = 4;

std::string NodeHost(int node) { return absl::StrCat("127.0.0.", 21 + node); }
std::string NodeId(int node) { return absl::StrCat("node-", node); }

// Configures `run` on the node behind `stub`, streams all its frames there (each acknowledged) and
// waits up to 60 s until that node has applied them; `applied` is its session then.
void ConfigureStreamAndAwaitApplied(esg::v1::EstimationService::Stub& stub,
                                    const SimulatedRun& run, esg::v1::SessionInfo& applied) {
  {
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse configured;
    ASSERT_TRUE(stub.ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &configured).ok());
  }
  const auto streamed = testing::StreamFrames(stub, run.frames);
  ASSERT_TRUE(streamed.status.ok()) << streamed.status.error_message();
  ASSERT_EQ(streamed.acks.size(), run.frames.size());
  for (int attempt = 0; attempt < 600; ++attempt) {
    applied = testing::Session(stub, run.config.spacecraft_id);
    if (applied.frames_applied() == static_cast<int64_t>(run.frames.size())) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  }
  ASSERT_EQ(applied.frames_applied(), static_cast<int64_t>(run.frames.size()));
}

// Starts two esgd on `db` with leases of `lease` (an esgd duration, "30s"), logs in `dir`.
void StartTwoNodes(const std::string& db, const TempDir& dir, const std::string& lease,
                   std::vector<std::unique_ptr<Daemon>>& daemons) {
  for (int n = 0; n < 2; ++n) {
    daemons.push_back(std::make_unique<Daemon>(
        db, dir.File(absl::StrCat("node", n, ".log")), testing::DaemonLimits{},
        std::vector<std::string>{"--node-id", NodeId(n), "--lease-duration", lease}));
    ASSERT_GT(daemons.back()->port(), 0)
        << testing::ReadFile(dir.File(absl::StrCat("node", n, ".log")));
  }
}
// StartTwoNodes on a new database of the shared PostgreSQL server, with leases of `lease_ms`
// (whole seconds); the database's URL in `db_url` when given.
void StartTwoNodesOnANewDatabase(const TempDir& dir, int lease_ms,
                                 std::vector<std::unique_ptr<Daemon>>& daemons,
                                 std::string* db_url = nullptr) {
  std::string pg_error;
  PostgresServer* pg = PostgresServer::Shared(&pg_error);
  ASSERT_NE(pg, nullptr) << "PostgreSQL could not start: " << pg_error;
  absl::StatusOr<std::string> db = pg->CreateDatabase();
  ASSERT_TRUE(db.ok()) << db.status();
  if (db_url != nullptr) *db_url = *db;
  StartTwoNodes(*db, dir, absl::StrCat(lease_ms / 1000, "s"), daemons);
}

// Configures `run`'s spacecraft on the server of `stub`, which so takes its session.
void Configure(esg::v1::EstimationService::Stub& stub, const SimulatedRun& run) {
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse configured;
  const grpc::Status status =
      stub.ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &configured);
  ASSERT_TRUE(status.ok()) << status.error_message();
}
std::string SpacecraftId(int i) { return absl::StrFormat("FO-%02d", i); }

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

// What one station saw.
struct StationLog {
  int64_t acknowledged = 0;  // frames acknowledged (accepted, new or duplicate)
  int64_t duplicates = 0;    // acknowledged as already stored (resent after a lost ack)
  int64_t unavailable = 0;   // refusals and failed streams while the session moved
  std::string error;         // a refusal a station cannot recover from
};

// A ground station for one spacecraft: sends the frames in order through the router, a few per
// stream, and resends every frame not acknowledged (a stream that fails, a frame refused
// UNAVAILABLE) until each is acknowledged or `deadline` passes. `pace` pauses between streams.
StationLog RunStation(esg::v1::EstimationService::Stub& router, const std::string& id,
                      const std::vector<esg::v1::TelemetryFrame>& frames, size_t first,
                      std::chrono::milliseconds pace,
                      std::chrono::steady_clock::time_point deadline) {
  StationLog log;
  size_t next = first;
  while (next < frames.size()) {
    if (std::chrono::steady_clock::now() > deadline) {
      log.error = absl::StrCat("frames from ", next + 1, " not acknowledged before the deadline");
      return log;
    }
    const size_t end = std::min(frames.size(), next + kFramesPerStream);
    const std::vector<esg::v1::TelemetryFrame> batch(frames.begin() + next, frames.begin() + end);
    const auto streamed = testing::StreamFrames(router, batch, "", /*routed_by=*/id);
    size_t acked = 0;  // acknowledged in order from `next`
    for (const esg::v1::TelemetryAck& ack : streamed.acks) {
      if (!ack.accepted()) {
        if (ack.rejection().code() != static_cast<int>(grpc::StatusCode::UNAVAILABLE)) {
          log.error = absl::StrCat("frame ", ack.sequence(), " refused: ",
                                   ack.rejection().reason());
          return log;
        }
        ++log.unavailable;
        break;
      }
      if (ack.sequence() != static_cast<int64_t>(next + acked + 1)) break;
      if (ack.duplicate()) ++log.duplicates;
      ++acked;
    }
    if (!streamed.status.ok()) ++log.unavailable;
    log.acknowledged += static_cast<int64_t>(acked);
    next += acked;
    if (acked < batch.size()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    } else {
      std::this_thread::sleep_for(pace);
    }
  }
  return log;
}

grpc::Status GetSession(esg::v1::EstimationService::Stub& stub, const std::string& id,
                        esg::v1::SessionInfo* info) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
  ctx.AddMetadata("x-esg-spacecraft", id);
  esg::v1::GetSessionRequest request;
  request.set_spacecraft_id(id);
  return stub.GetSession(&ctx, request, info);
}

TEST(Failover, SessionsOfAKilledNodeFinishOnTheOthersWithEveryFrameStoredAndAppliedOnce) {
  ASSERT_FALSE(NginxBinary().empty())
      << "nginx not found: this test needs Debian's package nginx (scripts/install-deps.sh)";
  std::string pg_error;
  PostgresServer* pg = PostgresServer::Shared(&pg_error);
  ASSERT_NE(pg, nullptr) << "PostgreSQL could not start: " << pg_error;
  absl::StatusOr<std::string> db = pg->CreateDatabase();
  ASSERT_TRUE(db.ok()) << db.status();
  const auto test_start = std::chrono::steady_clock::now();
  TempDir dir;

  std::vector<std::unique_ptr<Daemon>> daemons;
  std::vector<std::string> node_addresses;
  for (int n = 0; n < kNodes; ++n) {
    const std::string listen = absl::StrCat(NodeHost(n), ":", kNodePort);
    daemons.push_back(std::make_unique<Daemon>(
        *db, dir.File(absl::StrCat("node", n, ".log")), testing::DaemonLimits{},
        std::vector<std::string>{"--node-id", NodeId(n), "--lease-duration",
                                 absl::StrCat(kLeaseSeconds, "s"), "--metrics-listen",
                                 absl::StrCat(NodeHost(n), ":0")},
        listen));
    ASSERT_EQ(daemons.back()->port(), kNodePort)
        << "esgd did not start on " << listen << ": "
        << testing::ReadFile(dir.File(absl::StrCat("node", n, ".log")));
    node_addresses.push_back(listen);
  }
  Nginx nginx(dir.File("nginx"), node_addresses);
  ASSERT_TRUE(nginx.running());
  auto router = esg::v1::EstimationService::NewStub(
      grpc::CreateChannel(nginx.address(), grpc::InsecureChannelCredentials()));
  std::printf("[ measured ] start of PostgreSQL database, 3 esgd and nginx: %.2f s\n",
              Seconds(test_start));

  std::vector<SimulatedRun> runs;
  for (int i = 0; i < kSpacecraft; ++i) runs.push_back(SimulateRun(SpacecraftId(i), kHours, 300 + i));
  for (int i = 0; i < kSpacecraft; ++i) {
    grpc::ClientContext ctx;
    ctx.AddMetadata("x-esg-spacecraft", SpacecraftId(i));
    esg::v1::ConfigureResponse configured;
    const grpc::Status status =
        router->ConfigureSpacecraft(&ctx, ConfigureRequestFor(runs[i].config), &configured);
    ASSERT_TRUE(status.ok()) << SpacecraftId(i) << ": " << status.error_message();
  }

  // The leases taken at configuration: who serves what before the kill.
  auto storage = storage::Storage::Open(*db);
  ASSERT_TRUE(storage.ok()) << storage.status();
  std::map<std::string, storage::SessionLease> before;
  for (int i = 0; i < kSpacecraft; ++i) {
    absl::StatusOr<storage::SessionLease> lease = (*storage)->leases().Get(SpacecraftId(i));
    ASSERT_TRUE(lease.ok()) << lease.status();
    before[SpacecraftId(i)] = *lease;
  }
  const std::string killed_node = before[SpacecraftId(0)].owner;
  int killed = -1;
  for (int n = 0; n < kNodes; ++n) {
    if (NodeId(n) == killed_node) killed = n;
  }
  ASSERT_GE(killed, 0) << killed_node;
  int on_killed = 0;
  for (const auto& [id, lease] : before) on_killed += lease.owner == killed_node ? 1 : 0;

  // Every station streams at once; the killed node dies while they do.
  const auto stream_start = std::chrono::steady_clock::now();
  const auto deadline = stream_start + std::chrono::seconds(240);
  std::vector<StationLog> logs(kSpacecraft);
  std::vector<std::thread> stations;
  for (int i = 0; i < kSpacecraft; ++i) {
    stations.emplace_back([&, i] {
      logs[i] = RunStation(*router, SpacecraftId(i), runs[i].frames, 0,
                           std::chrono::milliseconds(50), deadline);
    });
  }
  // Mid-stream: once the killed node's first spacecraft has about a third of its frames durable.
  int64_t durable_at_kill = 0;
  for (;;) {
    esg::v1::SessionInfo info;
    if (GetSession(*router, SpacecraftId(0), &info).ok() &&
        info.highest_durable_sequence() >= static_cast<int64_t>(runs[0].frames.size()) / 3) {
      durable_at_kill = info.highest_durable_sequence();
      break;
    }
    ASSERT_LT(Seconds(stream_start), 60.0) << "the first spacecraft made no progress";
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  daemons[killed]->Stop(SIGKILL);
  const auto kill_time = std::chrono::steady_clock::now();
  for (std::thread& t : stations) t.join();
  std::printf("[ measured ] kill -9 of %s (serving %d of %d spacecraft) with %lld of %zu frames "
              "of %s durable; all stations done %.2f s after the kill\n",
              killed_node.c_str(), on_killed, kSpacecraft,
              static_cast<long long>(durable_at_kill), runs[0].frames.size(),
              SpacecraftId(0).c_str(), Seconds(kill_time));

  int64_t unavailable = 0;
  int64_t duplicates = 0;
  for (int i = 0; i < kSpacecraft; ++i) {
    ASSERT_TRUE(logs[i].error.empty()) << SpacecraftId(i) << ": " << logs[i].error;
    EXPECT_EQ(logs[i].acknowledged, static_cast<int64_t>(runs[i].frames.size()))
        << SpacecraftId(i);
    unavailable += logs[i].unavailable;
    duplicates += logs[i].duplicates;
  }
  std::printf("[ measured ] stations saw %lld UNAVAILABLE refusals or failed streams and %lld "
              "duplicate acks (frames stored before the kill whose acks were lost)\n",
              static_cast<long long>(unavailable), static_cast<long long>(duplicates));

  // Every session applied everything, wherever it is now.
  for (int i = 0; i < kSpacecraft; ++i) {
    const std::string id = SpacecraftId(i);
    const int64_t n = static_cast<int64_t>(runs[i].frames.size());
    esg::v1::SessionInfo info;
    for (int attempt = 0;; ++attempt) {
      const grpc::Status status = GetSession(*router, id, &info);
      if (status.ok() && info.frames_applied() >= n) break;
      ASSERT_LT(attempt, 600) << id << ": " << status.error_message() << ", applied "
                              << info.frames_applied() << " of " << n;
      std::this_thread::sleep_for(std::chrono::milliseconds(100));
    }
    EXPECT_EQ(info.frames_accepted(), n) << id;
    EXPECT_EQ(info.highest_applied_sequence(), n) << id;
  }

  // Exactly once in the archive; the coefficient history and the session as offline.
  for (int i = 0; i < kSpacecraft; ++i) {
    const std::string id = SpacecraftId(i);
    SCOPED_TRACE(id);
    absl::StatusOr<std::vector<storage::ArchivedFrame>> archived =
        (*storage)->archive().ReadTimeRange(id, absl::InfinitePast(), absl::InfiniteFuture());
    ASSERT_TRUE(archived.ok()) << archived.status();
    ASSERT_EQ(archived->size(), runs[i].frames.size());
    std::set<int64_t> sequences;
    for (const storage::ArchivedFrame& f : *archived) sequences.insert(f.sequence);
    EXPECT_EQ(sequences.size(), runs[i].frames.size());
    EXPECT_EQ(*sequences.begin(), 1);
    EXPECT_EQ(*sequences.rbegin(), static_cast<int64_t>(runs[i].frames.size()));

    const std::vector<testing::OfflineSnapshot> offline =
        OfflineCoefficientHistory(runs[i].config, "10+11", runs[i].frames);
    absl::StatusOr<std::vector<storage::CoefficientRecord>> stored =
        (*storage)->coefficients().History(id, 0, absl::InfinitePast(), absl::InfiniteFuture());
    ASSERT_TRUE(stored.ok()) << stored.status();
    ASSERT_EQ(stored->size(), offline.size());
    double worst_deg_h = 0.0;
    for (size_t k = 0; k < offline.size(); ++k) {
      ASSERT_EQ((*stored)[k].measurement_time, offline[k].time) << k;
      ASSERT_EQ((*stored)[k].gyro_id, offline[k].gyro_id) << k;
      for (size_t v = 0; v < offline[k].values.size(); ++v) {
        const double a = (*stored)[k].values[v];
        const double b = offline[k].values[v];
        if (std::isnan(a) || std::isnan(b)) {
          EXPECT_EQ(std::isnan(a), std::isnan(b)) << k << "/" << v;
          continue;
        }
        worst_deg_h = std::max(worst_deg_h, std::abs(estimator::RadPerSecToDegPerHour(a - b)));
      }
    }
    EXPECT_LE(worst_deg_h, 1e-12);
    EXPECT_EQ(StoredSessionValues(*db, id), OfflineSessionValues(runs[i].config, "10+11",
                                                                 runs[i].frames));
  }

  // The killed node's sessions moved under a new epoch; the others stayed where they were.
  int moved = 0;
  for (int i = 0; i < kSpacecraft; ++i) {
    const std::string id = SpacecraftId(i);
    absl::StatusOr<storage::SessionLease> lease = (*storage)->leases().Get(id);
    ASSERT_TRUE(lease.ok()) << lease.status();
    if (before[id].owner == killed_node) {
      EXPECT_NE(lease->owner, killed_node) << id;
      EXPECT_GT(lease->epoch, before[id].epoch) << id;
      ++moved;
    } else {
      EXPECT_EQ(lease->owner, before[id].owner) << id;
      EXPECT_EQ(lease->epoch, before[id].epoch) << id;
    }
  }
  EXPECT_EQ(moved, on_killed);
  EXPECT_GE(moved, 1);

  // The surviving nodes' metrics: every spacecraft's lease taken once on them (configured there,
  // or taken over), none lost, and every session held by one of them.
  double taken = 0;
  double lost = 0;
  double held = 0;
  for (int n = 0; n < kNodes; ++n) {
    if (n == killed) continue;
    const auto scraped = testing::RunBinary(
        dir, "curl",
        absl::StrCat("-sS --max-time 10 http://", NodeHost(n), ":", daemons[n]->metrics_port(),
                     "/metrics"));
    ASSERT_EQ(scraped.exit_code, 0) << scraped.err;
    const std::string& text = scraped.out;
    absl::StatusOr<testing::Exposition> metrics = testing::ParseExposition(text);
    ASSERT_TRUE(metrics.ok()) << metrics.status() << "\n" << text;
    taken += metrics->Sum("esg_session_lease_events_total", {{"event", "taken"}});
    lost += metrics->Sum("esg_session_lease_events_total", {{"event", "lost"}});
    held += metrics->Sum("esg_sessions");
  }
  EXPECT_EQ(taken, kSpacecraft);
  EXPECT_EQ(lost, 0);
  EXPECT_EQ(held, kSpacecraft);
  std::printf("[ measured ] %d sessions moved off %s; whole test %.2f s\n", moved,
              killed_node.c_str(), Seconds(test_start));
}

// Fleet views across servers (docs/service.md "Several servers"): two esgd sharing one
// PostgreSQL database, no router. A spacecraft served by node A (configured and streamed there,
// with star-tracker outliers that raise alerts) is seen from node B: ListSessions lists it
// served by A, GetSession answers from the database without taking A's lease, the coefficient
// history is A's, and an all-spacecraft alert subscription on B receives the alerts A raises
// while it streams (LISTEN/NOTIFY), the same alerts A stores.
TEST(Failover, AnyServerShowsEverySpacecraftAndRelaysAlertsRaisedOnAnother) {
  TempDir dir;
  std::vector<std::unique_ptr<Daemon>> daemons;
  ASSERT_NO_FATAL_FAILURE(StartTwoNodesOnANewDatabase(dir, 30000, daemons));
  auto a = daemons[0]->Stub();
  auto b = daemons[1]->Stub();

  // B subscribes to every spacecraft's alerts before anything exists.
  grpc::ClientContext watch;
  esg::v1::AlertSubscription subscription;
  subscription.set_replay_marker(true);
  auto reader = b->SubscribeAlerts(&watch, subscription);
  esg::v1::Alert marker;
  ASSERT_TRUE(reader->Read(&marker));
  ASSERT_TRUE(marker.replay_complete());
  std::vector<esg::v1::Alert> relayed;
  std::thread collect([&] {
    esg::v1::Alert alert;
    while (reader->Read(&alert)) relayed.push_back(alert);
  });

  const SimulatedRun run = SimulateRun("FV-1", 3.0, 41, /*outlier_probability=*/0.08);
  const std::string id = run.config.spacecraft_id;
  esg::v1::SessionInfo on_a;
  ASSERT_NO_FATAL_FAILURE(ConfigureStreamAndAwaitApplied(*a, run, on_a));
  EXPECT_EQ(on_a.served_by(), NodeId(0));

  // ListSessions and GetSession on B: A's session, as A committed it, A still holding it.
  {
    grpc::ClientContext ctx;
    esg::v1::ListSessionsResponse listed;
    ASSERT_TRUE(b->ListSessions(&ctx, {}, &listed).ok());
    ASSERT_EQ(listed.sessions_size(), 1);
    EXPECT_EQ(listed.sessions(0).spacecraft_id(), id);
    EXPECT_EQ(listed.sessions(0).served_by(), NodeId(0));
    EXPECT_EQ(listed.sessions(0).frames_applied(), on_a.frames_applied());
    EXPECT_EQ(listed.sessions(0).state(), on_a.state());
  }
  esg::v1::SessionInfo on_b;
  {
    grpc::ClientContext ctx;
    esg::v1::GetSessionRequest get;
    get.set_spacecraft_id(id);
    const grpc::Status status = b->GetSession(&ctx, get, &on_b);
    ASSERT_TRUE(status.ok()) << status.error_message();
  }
  EXPECT_EQ(on_b.served_by(), NodeId(0));
  EXPECT_EQ(on_b.highest_applied_sequence(), on_a.highest_applied_sequence());
  EXPECT_EQ(testing::Session(*a, id).served_by(), NodeId(0)) << "B took A's session";

  // The coefficient history read on B is A's.
  auto history = [&](esg::v1::EstimationService::Stub& stub) {
    grpc::ClientContext ctx;
    esg::v1::HistoryRequest request;
    request.set_spacecraft_id(id);
    request.set_page_size(100000);
    esg::v1::HistoryResponse response;
    EXPECT_TRUE(stub.GetCoefficientHistory(&ctx, request, &response).ok());
    return response.SerializeAsString();
  };
  EXPECT_EQ(history(*b), history(*a));

  // The alerts A raised reached B's subscription: every stored alert state of the spacecraft,
  // as stored (waiting for the relay to catch up with the last one).
  grpc::ClientContext replay_ctx;
  esg::v1::AlertSubscription replay;
  replay.set_spacecraft_id(id);
  *replay.mutable_since() = proto_convert::TimeToProto(absl::UnixEpoch());
  replay.set_replay_marker(true);
  auto stored_reader = a->SubscribeAlerts(&replay_ctx, replay);
  std::vector<esg::v1::Alert> stored;
  esg::v1::Alert s;
  while (stored_reader->Read(&s) && !s.replay_complete()) stored.push_back(s);
  replay_ctx.TryCancel();
  ASSERT_FALSE(stored.empty()) << "the outliers raised no alert: the test shows nothing";
  std::this_thread::sleep_for(std::chrono::seconds(1));
  watch.TryCancel();
  collect.join();
  std::map<int64_t, esg::v1::Alert> last_relayed;
  for (const esg::v1::Alert& r : relayed) {
    EXPECT_EQ(r.spacecraft_id(), id);
    last_relayed[r.sequence()] = r;
  }
  ASSERT_EQ(last_relayed.size(), stored.size());
  for (const esg::v1::Alert& st : stored) {
    ASSERT_TRUE(last_relayed.count(st.sequence())) << st.sequence();
    const esg::v1::Alert& r = last_relayed[st.sequence()];
    EXPECT_EQ(r.reason(), st.reason());
    EXPECT_EQ(r.repeat_count(), st.repeat_count());
    EXPECT_EQ(r.cleared(), st.cleared());
  }
  std::printf("[ measured ] %zu alerts raised on node A, %zu alert changes relayed to node B\n",
              stored.size(), relayed.size());
}

// The retry delay of a refusal (docs/service.md "Several servers"): node B, asked for a session
// node A holds, answers UNAVAILABLE with the trailing metadata grpc-retry-pushback-ms, the time
// until A's lease expires (at most the lease duration), on a unary call (ConfigureSpacecraft),
// on one run off the callback thread (PredictAttitude) and on a stream (Diagnose). After A is
// killed, a client whose gRPC retry policy would give up within about 50 ms (5 attempts, 10 ms
// apart) succeeds on B because it waits as told until the lease expired.
TEST(Failover, ARefusedCallCarriesTheTimeUntilTheLeaseExpiresAsItsRetryPushback) {
  constexpr int kLeaseMs = 3000;
  TempDir dir;
  std::vector<std::unique_ptr<Daemon>> daemons;
  ASSERT_NO_FATAL_FAILURE(StartTwoNodesOnANewDatabase(dir, kLeaseMs, daemons));
  auto a = daemons[0]->Stub();
  auto b = daemons[1]->Stub();
  const SimulatedRun run = SimulateRun("RP-1", 1.0, 51);
  const std::string id = run.config.spacecraft_id;
  ASSERT_NO_FATAL_FAILURE(Configure(*a, run));

  // The pushback of a finished call, -1 when it has none.
  auto pushback_ms = [](const grpc::ClientContext& ctx) -> int64_t {
    const auto& trailers = ctx.GetServerTrailingMetadata();
    EXPECT_LE(trailers.count("grpc-retry-pushback-ms"), 1u);
    const auto found = trailers.find("grpc-retry-pushback-ms");
    if (found == trailers.end()) return -1;
    int64_t ms = -1;
    EXPECT_TRUE(
        absl::SimpleAtoi(absl::string_view(found->second.data(), found->second.size()), &ms))
        << std::string(found->second.data(), found->second.size());
    return ms;
  };
  auto expect_refused = [&](const grpc::Status& status, const grpc::ClientContext& ctx,
                            const char* call) {
    SCOPED_TRACE(call);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAVAILABLE) << status.error_message();
    EXPECT_THAT(status.error_message(),
                ::testing::HasSubstr(absl::StrCat("is served by node ", NodeId(0), " until")));
    const int64_t ms = pushback_ms(ctx);
    EXPECT_GT(ms, 0);
    EXPECT_LE(ms, kLeaseMs);
    return ms;
  };
  {
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse configured;
    const grpc::Status status =
        b->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &configured);
    const int64_t ms = expect_refused(status, ctx, "ConfigureSpacecraft");
    std::printf(
        "[ measured ] ConfigureSpacecraft refused by node B: grpc-retry-pushback-ms %lld "
        "(lease %d ms, renewed every third)\n",
        static_cast<long long>(ms), kLeaseMs);
  }
  {
    grpc::ClientContext ctx;
    esg::v1::PredictRequest request;
    request.set_spacecraft_id(id);
    esg::v1::PredictResponse predicted;
    const grpc::Status status = b->PredictAttitude(&ctx, request, &predicted);
    expect_refused(status, ctx, "PredictAttitude");
  }
  {
    grpc::ClientContext ctx;
    esg::v1::DiagnoseRequest request;
    request.set_spacecraft_id(id);
    auto reader = b->Diagnose(&ctx, request);
    esg::v1::DiagnoseUpdate update;
    while (reader->Read(&update)) {
    }
    const grpc::Status status = reader->Finish();
    expect_refused(status, ctx, "Diagnose");
  }
  // Other failures carry no pushback.
  {
    grpc::ClientContext ctx;
    esg::v1::PredictRequest request;
    request.set_spacecraft_id("NOT-CONFIGURED");
    esg::v1::PredictResponse predicted;
    EXPECT_EQ(b->PredictAttitude(&ctx, request, &predicted).error_code(),
              grpc::StatusCode::NOT_FOUND);
    EXPECT_EQ(pushback_ms(ctx), -1);
  }

  // A dies; a client with a short retry policy reaches B, which takes the session once A's
  // lease expired. Without the pushback its five attempts would all be refused within ~50 ms.
  daemons[0]->Stop(SIGKILL);
  grpc::ChannelArguments args;
  args.SetServiceConfigJSON(R"({"methodConfig": [{
      "name": [{"service": "esg.v1.EstimationService"}],
      "retryPolicy": {"maxAttempts": 5, "initialBackoff": "0.01s", "maxBackoff": "0.01s",
                      "backoffMultiplier": 1.0, "retryableStatusCodes": ["UNAVAILABLE"]}}]})");
  auto retrying = esg::v1::EstimationService::NewStub(
      grpc::CreateCustomChannel(daemons[1]->address(), grpc::InsecureChannelCredentials(), args));
  const auto start = std::chrono::steady_clock::now();
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
  esg::v1::ConfigureResponse configured;
  const grpc::Status status =
      retrying->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &configured);
  const double waited_s = Seconds(start);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(configured.session().served_by(), NodeId(1));
  EXPECT_LE(waited_s, kLeaseMs / 1000.0 + 5.0);
  std::printf(
      "[ measured ] after kill -9 of node A the retrying call succeeded on node B after "
      "%.2f s (lease %d ms)\n",
      waited_s, kLeaseMs);
}

// Estimates across servers (docs/service.md "Several servers"): two esgd on one PostgreSQL
// database. An all-spacecraft estimate subscription on node B, opened before anything exists,
// receives every per-step estimate node A stores while a spacecraft streams to A (the trigger on
// the estimates table, LISTEN/NOTIFY), each as stored (same compute time and attitude); and a
// later subscription on B with `since` replays A's stored estimates before its marker.
TEST(Failover, AnEstimateSubscriptionOnAnyServerSeesTheEstimatesAnotherServerStores) {
  TempDir dir;
  std::vector<std::unique_ptr<Daemon>> daemons;
  std::string db;
  ASSERT_NO_FATAL_FAILURE(StartTwoNodesOnANewDatabase(dir, 30000, daemons, &db));
  auto a = daemons[0]->Stub();
  auto b = daemons[1]->Stub();

  grpc::ClientContext watch;
  esg::v1::EstimateSubscription subscription;
  subscription.set_replay_marker(true);
  auto reader = b->SubscribeEstimates(&watch, subscription);
  esg::v1::EstimateRecord marker;
  ASSERT_TRUE(reader->Read(&marker));
  ASSERT_TRUE(marker.replay_complete());
  std::vector<esg::v1::EstimateRecord> relayed;
  std::thread collect([&] {
    esg::v1::EstimateRecord record;
    while (reader->Read(&record)) relayed.push_back(record);
  });

  const SimulatedRun run = SimulateRun("FE-1", 3.0, 43);
  const std::string id = run.config.spacecraft_id;
  esg::v1::SessionInfo on_a;
  ASSERT_NO_FATAL_FAILURE(ConfigureStreamAndAwaitApplied(*a, run, on_a));

  auto storage = storage::Storage::Open(db);
  ASSERT_TRUE(storage.ok()) << storage.status();
  absl::StatusOr<storage::EstimatePage> stored = (*storage)->estimates().Page(
      id, absl::InfinitePast(), absl::InfiniteFuture(), std::nullopt, 100000);
  ASSERT_TRUE(stored.ok()) << stored.status();
  ASSERT_FALSE(stored->records.empty()) << "no estimate stored: the test shows nothing";
  // The relay has a moment to catch up with the last step; then the last relayed record of
  // each step is the stored one.
  std::this_thread::sleep_for(std::chrono::seconds(2));
  watch.TryCancel();
  collect.join();
  std::map<int64_t, esg::v1::EstimateRecord> last_relayed;
  for (const esg::v1::EstimateRecord& r : relayed) {
    EXPECT_EQ(r.spacecraft_id(), id);
    last_relayed[absl::ToUnixNanos(*proto_convert::TimeFromProto(r.measurement_time()))] = r;
  }
  ASSERT_EQ(last_relayed.size(), stored->records.size());
  for (const storage::EstimateRecord& s : stored->records) {
    const int64_t key = absl::ToUnixNanos(s.measurement_time);
    ASSERT_TRUE(last_relayed.count(key)) << absl::FormatTime(s.measurement_time);
    const esg::v1::EstimateRecord& r = last_relayed[key];
    EXPECT_EQ(*proto_convert::TimeFromProto(r.compute_time()), s.compute_time);
    EXPECT_EQ(r.has_attitude(), s.attitude_valid);
    EXPECT_EQ(r.star_tracker_used(), s.star_tracker_used);
  }

  // A later subscription on B replays A's stored estimates (B holds no session).
  grpc::ClientContext replay_ctx;
  esg::v1::EstimateSubscription replay;
  *replay.mutable_since() = proto_convert::TimeToProto(absl::UnixEpoch());
  replay.set_replay_marker(true);
  auto replay_reader = b->SubscribeEstimates(&replay_ctx, replay);
  size_t replayed = 0;
  esg::v1::EstimateRecord r;
  while (replay_reader->Read(&r) && !r.replay_complete()) ++replayed;
  replay_ctx.TryCancel();
  EXPECT_EQ(replayed, stored->records.size());
  std::printf("[ measured ] %zu estimates stored on node A, %zu relayed to node B\n",
              stored->records.size(), relayed.size());
}


// A telemetry frame refused by a server that does not hold the spacecraft's session
// (docs/service.md "Ingest contract", "Several servers"): node B, streamed frames of a
// spacecraft node A holds, acknowledges each with accepted = false, code 14 (UNAVAILABLE),
// field spacecraft_id naming A, and retry_after_ms, the time until A's lease expires (above 0,
// at most the lease duration); no other refusal carries a delay. `esg replay` to B with
// --max-lease-wait 0 gives up at once with exit 1, naming A; B stores nothing, A keeps the
// session and takes the frames afterwards.
TEST(Failover, AFrameRefusedWhileAnotherServerHoldsTheSessionCarriesTheTimeUntilItsLeaseExpires) {
  constexpr int kLeaseMs = 3000;
  TempDir dir;
  std::vector<std::unique_ptr<Daemon>> daemons;
  ASSERT_NO_FATAL_FAILURE(StartTwoNodesOnANewDatabase(dir, kLeaseMs, daemons));
  auto a = daemons[0]->Stub();
  auto b = daemons[1]->Stub();
  const SimulatedRun run = SimulateRun("RA-1", 0.2, 52);
  const std::string id = run.config.spacecraft_id;
  ASSERT_NO_FATAL_FAILURE(Configure(*a, run));
  const std::vector<esg::v1::TelemetryFrame> first(run.frames.begin(), run.frames.begin() + 4);
  const auto streamed = testing::StreamFrames(*b, first);
  ASSERT_TRUE(streamed.status.ok()) << streamed.status.error_message();
  ASSERT_EQ(streamed.acks.size(), first.size());
  int64_t longest_ms = 0;
  for (const esg::v1::TelemetryAck& ack : streamed.acks) {
    SCOPED_TRACE(ack.sequence());
    EXPECT_FALSE(ack.accepted());
    EXPECT_EQ(ack.rejection().code(), 14);
    EXPECT_EQ(ack.rejection().field(), "spacecraft_id");
    EXPECT_THAT(ack.rejection().reason(),
                ::testing::StartsWith(absl::StrCat("'", id, "' is served by node ", NodeId(0),
                                                   " until ")));
    EXPECT_GT(ack.rejection().retry_after_ms(), 0);
    EXPECT_LE(ack.rejection().retry_after_ms(), kLeaseMs);
    longest_ms = std::max(longest_ms, ack.rejection().retry_after_ms());
  }
  // Any other refusal carries no delay: a spacecraft nobody configured.
  std::vector<esg::v1::TelemetryFrame> unknown = {run.frames[0]};
  unknown[0].set_spacecraft_id("RA-UNKNOWN");
  const auto refused = testing::StreamFrames(*b, unknown);
  ASSERT_EQ(refused.acks.size(), 1u);
  EXPECT_EQ(refused.acks[0].rejection().code(), 5);
  EXPECT_EQ(refused.acks[0].rejection().retry_after_ms(), 0);

  // esg replay with no wait allowed: exit 1, the holder named, nothing stored by B.
  estimator::Recording recording;
  recording.metadata["spacecraft_id"] = id;
  for (const esg::v1::TelemetryFrame& f : run.frames) {
    absl::StatusOr<estimator::TelemetryFrame> frame = proto_convert::FrameFromProto(f);
    ASSERT_TRUE(frame.ok()) << frame.status();
    recording.frames.push_back(*frame);
  }
  const std::string csv = dir.File("ra.csv");
  ASSERT_TRUE(storage::WriteRecordingCsv(csv, recording).ok());
  const auto gave_up = testing::RunBinary(
      dir, ESG_BINARY,
      absl::StrCat("--server ", daemons[1]->address(), " replay --recording ", csv,
                   " --max-lease-wait 0"));
  EXPECT_EQ(gave_up.exit_code, 1) << gave_up.err;
  EXPECT_THAT(gave_up.err, ::testing::HasSubstr("another server holds the session"));
  EXPECT_THAT(gave_up.err,
              ::testing::HasSubstr(absl::StrCat("is served by node ", NodeId(0), " until")));
  EXPECT_THAT(gave_up.err, ::testing::HasSubstr("--max-lease-wait"));
  EXPECT_THAT(gave_up.err, ::testing::HasSubstr("continue with --from-sequence 1"));
  const esg::v1::SessionInfo on_a = testing::Session(*a, id);
  EXPECT_EQ(on_a.served_by(), NodeId(0));
  EXPECT_EQ(on_a.frames_accepted(), 0);
  // A, which holds the session, takes the frames.
  const auto accepted = testing::StreamFrames(*a, first);
  ASSERT_EQ(accepted.acks.size(), first.size());
  for (const esg::v1::TelemetryAck& ack : accepted.acks) EXPECT_TRUE(ack.accepted());
  std::printf("[ measured ] frames refused by node B: retry_after_ms up to %lld (lease %d ms)\n",
              static_cast<long long>(longest_ms), kLeaseMs);
}

// `esg replay` honours the retry delay (docs/cli.md "replay"): node A holds a spacecraft's
// session with a 3 s lease and has stored its first frames; A is killed (its lease is no longer
// renewed but still runs), and the whole recording is replayed to node B. B refuses the frames
// with the time until A's lease expires; the replay waits that long, sends them again, B takes
// the session over and the replay completes: exit 0, no frame rejected, every frame of the
// recording stored exactly once (the ones A stored acknowledged as duplicates).
TEST(Failover, ReplayToAnotherServerWaitsForTheLeaseAndStoresEveryFrameOnce) {
  constexpr int kLeaseMs = 3000;
  constexpr int kStoredByA = 10;
  TempDir dir;
  std::vector<std::unique_ptr<Daemon>> daemons;
  std::string db;
  ASSERT_NO_FATAL_FAILURE(StartTwoNodesOnANewDatabase(dir, kLeaseMs, daemons, &db));
  auto a = daemons[0]->Stub();
  auto b = daemons[1]->Stub();
  const SimulatedRun run = SimulateRun("RB-1", 1.0, 53);
  const std::string id = run.config.spacecraft_id;
  const int64_t n = static_cast<int64_t>(run.frames.size());
  ASSERT_NO_FATAL_FAILURE(Configure(*a, run));
  const std::vector<esg::v1::TelemetryFrame> first(run.frames.begin(),
                                                   run.frames.begin() + kStoredByA);
  const auto on_a = testing::StreamFrames(*a, first);
  ASSERT_TRUE(on_a.status.ok()) << on_a.status.error_message();
  for (const esg::v1::TelemetryAck& ack : on_a.acks) ASSERT_TRUE(ack.accepted());

  estimator::Recording recording;
  recording.metadata["spacecraft_id"] = id;
  for (const esg::v1::TelemetryFrame& f : run.frames) {
    absl::StatusOr<estimator::TelemetryFrame> frame = proto_convert::FrameFromProto(f);
    ASSERT_TRUE(frame.ok()) << frame.status();
    recording.frames.push_back(*frame);
  }
  const std::string csv = dir.File("rb.csv");
  ASSERT_TRUE(storage::WriteRecordingCsv(csv, recording).ok());

  daemons[0]->Stop(SIGKILL);
  const auto start = std::chrono::steady_clock::now();
  const auto replayed = testing::RunBinary(
      dir, ESG_BINARY,
      absl::StrCat("--server ", daemons[1]->address(), " replay --recording ", csv, " --json"));
  const double replay_s = Seconds(start);
  ASSERT_EQ(replayed.exit_code, 0) << replayed.err;
  EXPECT_THAT(replayed.err, ::testing::HasSubstr("another server holds the session"));
  const nlohmann::json tally = nlohmann::json::parse(replayed.out, nullptr, false);
  ASSERT_FALSE(tally.is_discarded()) << replayed.out;
  EXPECT_EQ(tally["rejected"], 0);
  EXPECT_GT(tally["deferred"].get<int64_t>(), 0);
  EXPECT_GT(tally["leaseWaitS"].get<double>(), 0.0);
  EXPECT_LE(tally["leaseWaitS"].get<double>(), kLeaseMs / 1000.0 + 0.1);
  EXPECT_EQ(tally["acked"], n);
  EXPECT_EQ(tally["duplicates"], kStoredByA);
  EXPECT_EQ(tally["accepted"], n - kStoredByA);

  // Exactly once in the archive, and B serves the session now.
  auto storage = storage::Storage::Open(db);
  ASSERT_TRUE(storage.ok()) << storage.status();
  absl::StatusOr<std::vector<storage::ArchivedFrame>> archived =
      (*storage)->archive().ReadTimeRange(id, absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_TRUE(archived.ok()) << archived.status();
  ASSERT_EQ(static_cast<int64_t>(archived->size()), n);
  std::set<int64_t> sequences;
  for (const storage::ArchivedFrame& f : *archived) sequences.insert(f.sequence);
  EXPECT_EQ(static_cast<int64_t>(sequences.size()), n);
  EXPECT_EQ(*sequences.begin(), 1);
  EXPECT_EQ(*sequences.rbegin(), n);
  const esg::v1::SessionInfo on_b = testing::Session(*b, id);
  EXPECT_EQ(on_b.served_by(), NodeId(1));
  EXPECT_EQ(on_b.frames_accepted(), n);
  std::printf(
      "[ measured ] replay to node B after kill -9 of node A: %lld frames deferred, %.2f s "
      "waited for the lease, whole replay %.2f s (lease %d ms)\n",
      static_cast<long long>(tally["deferred"].get<int64_t>()),
      tally["leaseWaitS"].get<double>(), replay_s, kLeaseMs);
}

}  // namespace
}  // namespace esg
