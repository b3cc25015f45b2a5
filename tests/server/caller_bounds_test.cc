// What one caller may hold of esgd (docs/service.md "Limits", issue 40): concurrent subscription
// and export streams per caller, the bytes of unread subscription messages per caller and over
// all subscribers (slow subscribers dropped, their memory returned), and esgd's resident set
// after large predictions. Real gRPC clients over loopback, against the real esgd as a child
// process (Daemon) or in-process (LoopbackServer, where a test publishes alerts itself).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <memory>
#include <set>
#include <sstream>
#include <string>
#include <thread>
#include <tuple>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "gmock/gmock.h"
#include "grpcpp/support/channel_arguments.h"
#include "gtest/gtest.h"
#include "server/memory_release.h"
#include "server/queue_budget.h"
#include "storage/alert_store.h"
#include "storage/storage.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/status_matchers.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::Daemon;
using ::esg::testing::IsOk;
using ::esg::testing::LoopbackServer;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::esg::testing::WriteTokens;
using ::testing::EndsWith;
using ::testing::HasSubstr;
using ::testing::StartsWith;

std::chrono::system_clock::time_point In(absl::Duration d) {
  return absl::ToChronoTime(absl::Now() + d);
}

bool WaitFor(const std::function<bool()>& done, absl::Duration limit) {
  const absl::Time give_up = absl::Now() + limit;
  while (!done()) {
    if (absl::Now() > give_up) return false;
    absl::SleepFor(absl::Milliseconds(10));
  }
  return true;
}

// A channel with a connection of its own (gRPC shares one per address otherwise), accepting
// responses up to 64 MiB (a 100 000-sample prediction with AEM is about 33 MB).
std::shared_ptr<grpc::Channel> OwnChannel(const std::string& address, int index) {
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  args.SetInt("esg.test.connection", index);
  args.SetMaxReceiveMessageSize(64 << 20);
  return grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args);
}

// VmRSS of `pid` ("self" for this process) in KiB, from /proc/PID/status.
int64_t RssKiB(const std::string& pid) {
  std::ifstream in("/proc/" + pid + "/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stoll(line.substr(6));
  }
  return -1;
}

double Percentile(std::vector<double> values, double p) {
  std::sort(values.begin(), values.end());
  const size_t at = std::min(values.size() - 1, static_cast<size_t>(p * values.size()));
  return values[at];
}

const SimulatedRun& Run1h() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("CB-1", 1.0, 5));
  return *run;
}

// Configures Run1h's spacecraft on `stub`'s server and streams its frames; waits until they are
// applied (its estimates stored).
void Prepare(esg::v1::EstimationService::Stub& stub) {
  const SimulatedRun& run = Run1h();
  grpc::ClientContext context;
  esg::v1::ConfigureResponse configured;
  ASSERT_TRUE(stub.ConfigureSpacecraft(&context, ConfigureRequestFor(run.config), &configured).ok());
  const testing::StreamResult streamed = StreamFrames(stub, run.frames);
  ASSERT_TRUE(streamed.status.ok()) << streamed.status.error_message();
  ASSERT_TRUE(WaitFor(
      [&] {
        return testing::Session(stub, run.config.spacecraft_id).frames_applied() ==
               static_cast<int64_t>(run.frames.size());
      },
      absl::Seconds(120)));
}

// One subscription stream held by a client that reads its first message (which shows that the
// server admitted it) and then nothing more.
struct HeldStream {
  std::shared_ptr<grpc::Channel> channel;
  std::unique_ptr<esg::v1::EstimationService::Stub> stub;
  grpc::ClientContext context;
  std::unique_ptr<grpc::ClientReader<esg::v1::EstimateRecord>> estimates;
  std::unique_ptr<grpc::ClientReader<esg::v1::Alert>> alerts;

  // Starts SubscribeEstimates (or SubscribeAlerts) since 1970 (or, without `replay`, live only)
  // over every spacecraft with the replay marker; true when its first message arrived.
  bool Start(const std::string& address, int index, bool alert, const std::string& token = "",
             bool replay = true) {
    channel = OwnChannel(address, index);
    stub = esg::v1::EstimationService::NewStub(channel);
    if (!token.empty()) context.AddMetadata("authorization", "Bearer " + token);
    context.set_deadline(In(absl::Minutes(10)));
    if (alert) {
      esg::v1::AlertSubscription request;
      if (replay) request.mutable_since()->set_seconds(0);
      request.set_replay_marker(true);
      alerts = stub->SubscribeAlerts(&context, request);
      esg::v1::Alert first;
      return alerts->Read(&first);
    }
    esg::v1::EstimateSubscription request;
    request.mutable_since()->set_seconds(0);
    request.set_replay_marker(true);
    estimates = stub->SubscribeEstimates(&context, request);
    esg::v1::EstimateRecord first;
    return estimates->Read(&first);
  }
  // Reads what is left (a refused or dropped stream ends at once) and returns the status.
  grpc::Status Finish() {
    if (alerts != nullptr) {
      esg::v1::Alert a;
      while (alerts->Read(&a)) {
      }
      return alerts->Finish();
    }
    esg::v1::EstimateRecord e;
    while (estimates->Read(&e)) {
    }
    return estimates->Finish();
  }
  grpc::Status Cancel() {
    context.TryCancel();
    return Finish();
  }
};

// ---- QueueBudget ------------------------------------------------------------------------------

TEST(QueueBudget, RefusesTheStreamsAtOrAboveTheirShareBeyondEachBound) {
  QueueBudget budget(1000, 1500);
  QueueBudget::Account slow = budget.Open("ops");
  QueueBudget::Account fast = budget.Open("ops");
  QueueBudget::Account other = budget.Open("dash");
  ASSERT_THAT(slow.Charge(900), IsOk());
  ASSERT_THAT(fast.Charge(50), IsOk());
  // Beyond the caller's 1000 bytes: the slow stream (above the caller's average) is refused...
  EXPECT_EQ(slow.Charge(100).message(),
            "caller 'ops' holds 950 bytes of unread subscription messages (limit 1000 bytes per "
            "caller, --max-queued-mb-per-caller)");
  EXPECT_EQ(slow.Charge(100).code(), absl::StatusCode::kResourceExhausted);
  // ...the one below its share is charged.
  EXPECT_THAT(fast.Charge(100), IsOk());
  EXPECT_EQ(budget.held("ops"), 1050);
  // Beyond the total: the other caller's stream, at its share, is refused by the total bound.
  // A stream holding nothing is charged even beyond a bound (it only starts)...
  ASSERT_THAT(other.Charge(600), IsOk());
  // ...and refused once it holds its share.
  const absl::Status total = other.Charge(100);
  EXPECT_EQ(total.message(),
            "the subscribers together hold 1650 bytes of unread subscription messages (limit 1500 "
            "bytes over all subscribers, --max-queued-mb)");
  // Refunds and closing give everything back.
  slow.Refund(900);
  EXPECT_EQ(budget.held("ops"), 150);
  fast.Close();
  other = QueueBudget::Account();
  EXPECT_EQ(budget.held(), 0);
  EXPECT_EQ(budget.held("ops"), 0);
  EXPECT_EQ(ByteText(64 << 20), "64 MiB");
  EXPECT_EQ(ByteText(1000), "1000 bytes");
}

// ---- Subscriptions and exports per caller -----------------------------------------------------

// Issue 40's scenario against the real esgd with its defaults: one caller (a peer address
// without tokens) opens subscriptions since 1970 on connections of their own and never reads
// them. It holds its 64 (SubscribeEstimates and SubscribeAlerts together); the 65th is refused
// with RESOURCE_EXHAUSTED naming the bound. Meanwhile GetSession on an open connection, and on
// new connections, is answered with p99 under 50 ms. A cancelled subscription's slot is free
// again at once.
TEST(CallerBounds, OneCallerAtItsSubscriptionBoundLeavesStatusCallsFast) {
  constexpr int kLimit = 64;  // the default --max-subscriptions-per-caller
  TempDir dir;
  Daemon daemon(dir.File("var/esg.db"), dir.File("esgd.log"));
  ASSERT_GT(daemon.port(), 0);
  auto stub = esg::v1::EstimationService::NewStub(OwnChannel(daemon.address(), 100000));
  Prepare(*stub);
  if (HasFatalFailure()) return;

  std::vector<std::unique_ptr<HeldStream>> held;
  for (int i = 0; i < kLimit; ++i) {
    held.push_back(std::make_unique<HeldStream>());
    ASSERT_TRUE(held.back()->Start(daemon.address(), i, /*alert=*/i % 4 == 3)) << i;
  }
  HeldStream extra;
  EXPECT_FALSE(extra.Start(daemon.address(), kLimit, /*alert=*/false));
  const grpc::Status refused = extra.Finish();
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_EQ(refused.error_message(),
            "SubscribeEstimates: caller '127.0.0.1' already holds 64 subscriptions (limit 64 per "
            "caller); retry when one finishes");
  HeldStream extra_alerts;
  EXPECT_FALSE(extra_alerts.Start(daemon.address(), kLimit + 1, /*alert=*/true));
  EXPECT_THAT(extra_alerts.Finish().error_message(),
              StartsWith("SubscribeAlerts: caller '127.0.0.1' already holds 64 subscriptions"));

  // GetSession while the caller holds its maximum: on the open connection, then each on a new
  // connection.
  esg::v1::GetSessionRequest get;
  get.set_spacecraft_id(Run1h().config.spacecraft_id);
  std::vector<double> open_ms;
  for (int i = 0; i < 300; ++i) {
    grpc::ClientContext context;
    context.set_deadline(In(absl::Seconds(30)));
    esg::v1::SessionInfo info;
    const absl::Time start = absl::Now();
    ASSERT_TRUE(stub->GetSession(&context, get, &info).ok());
    open_ms.push_back(absl::ToDoubleMilliseconds(absl::Now() - start));
  }
  std::vector<double> new_ms;
  for (int i = 0; i < 30; ++i) {
    auto fresh = esg::v1::EstimationService::NewStub(OwnChannel(daemon.address(), 200000 + i));
    grpc::ClientContext context;
    context.set_deadline(In(absl::Seconds(30)));
    esg::v1::SessionInfo info;
    const absl::Time start = absl::Now();
    ASSERT_TRUE(fresh->GetSession(&context, get, &info).ok());
    new_ms.push_back(absl::ToDoubleMilliseconds(absl::Now() - start));
  }
  std::cout << "GetSession with 64 unread subscriptions held: open connection p50 "
            << Percentile(open_ms, 0.5) << " ms, p99 " << Percentile(open_ms, 0.99)
            << " ms; new connection p50 " << Percentile(new_ms, 0.5) << " ms, p99 "
            << Percentile(new_ms, 0.99) << " ms\n";
  EXPECT_LT(Percentile(open_ms, 0.99), 50.0);
  EXPECT_LT(Percentile(new_ms, 0.99), 50.0);

  // A cancelled subscription gives its slot back: the next one is admitted.
  EXPECT_EQ(held.front()->Cancel().error_code(), grpc::StatusCode::CANCELLED);
  held.erase(held.begin());
  HeldStream again;
  EXPECT_TRUE(again.Start(daemon.address(), kLimit + 2, /*alert=*/false));
  EXPECT_EQ(again.Cancel().error_code(), grpc::StatusCode::CANCELLED);
  for (auto& h : held) h->Cancel();
}

// With tokens the caller is the token's name: one caller at its subscription and export bounds
// leaves another's untouched; the refusals name the bound; finished streams free their slots.
TEST(CallerBounds, SubscriptionAndExportStreamsAreBoundedPerTokenName) {
  TempDir dir;
  WriteTokens(dir.File("tokens"),
              "ops-token-a-01234 read,write ops\ndash-token-012345 read dash\n");
  ServerOptions options;
  options.tokens_file = dir.File("tokens");
  options.calls.max_subscriptions_per_caller = 2;
  options.calls.max_subscriptions = 3;
  options.calls.max_exports_per_caller = 1;
  LoopbackServer server(options);
  {
    auto stub = server.Stub();
    const SimulatedRun& run = Run1h();
    grpc::ClientContext context;
    context.AddMetadata("authorization", "Bearer ops-token-a-01234");
    esg::v1::ConfigureResponse configured;
    ASSERT_TRUE(
        stub->ConfigureSpacecraft(&context, ConfigureRequestFor(run.config), &configured).ok());
    ASSERT_TRUE(StreamFrames(*stub, run.frames, "ops-token-a-01234").status.ok());
    ASSERT_THAT(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(60)), IsOk());
  }
  EstimationServiceImpl& service = server.get()->service();

  HeldStream ops1, ops2, ops3, dash1, dash2;
  ASSERT_TRUE(ops1.Start(server.address(), 1, false, "ops-token-a-01234"));
  ASSERT_TRUE(ops2.Start(server.address(), 2, true, "ops-token-a-01234"));
  EXPECT_FALSE(ops3.Start(server.address(), 3, false, "ops-token-a-01234"));
  EXPECT_EQ(ops3.Finish().error_message(),
            "SubscribeEstimates: caller 'ops' already holds 2 subscriptions (limit 2 per caller); "
            "retry when one finishes");
  ASSERT_TRUE(dash1.Start(server.address(), 4, false, "dash-token-012345"));
  EXPECT_FALSE(dash2.Start(server.address(), 5, true, "dash-token-012345"));
  EXPECT_EQ(dash2.Finish().error_message(),
            "SubscribeAlerts: the server already holds 3 subscriptions (limit 3 in total); retry "
            "when one finishes");
  EXPECT_EQ(service.subscription_limiter().Running("ops"), 2);
  ops1.Cancel();
  ops2.Cancel();
  dash1.Cancel();
  EXPECT_TRUE(WaitFor([&] { return service.subscription_limiter().Running() == 0; },
                      absl::Seconds(5)));

  // Exports: with ops's one slot taken (the test holds the permit, as a running export would),
  // ops's next export is refused and dash's runs; with the slot back, ops's runs, and its slot
  // is free once it finished.
  auto export_request = [&] {
    esg::v1::ExportTelemetryRequest request;
    request.set_spacecraft_id(Run1h().config.spacecraft_id);
    return request;
  };
  auto export_frames = [&](const std::string& token, grpc::Status* status) {
    auto stub = server.Stub();
    grpc::ClientContext context;
    context.AddMetadata("authorization", "Bearer " + token);
    auto reader = stub->ExportTelemetry(&context, export_request());
    esg::v1::ExportTelemetryResponse chunk;
    int64_t frames = 0;
    while (reader->Read(&chunk)) frames += chunk.frames_size();
    *status = reader->Finish();
    return frames;
  };
  absl::StatusOr<CallLimiter::Permit> running = service.export_limiter().Acquire("ops");
  ASSERT_THAT(running, IsOk());
  {
    auto stub = server.Stub();
    grpc::ClientContext context;
    context.AddMetadata("authorization", "Bearer ops-token-a-01234");
    esg::v1::ExportCoefficientHistoryRequest request;
    request.set_spacecraft_id(Run1h().config.spacecraft_id);
    auto second = stub->ExportCoefficientHistory(&context, request);
    esg::v1::ExportCoefficientHistoryResponse response;
    EXPECT_FALSE(second->Read(&response));
    const grpc::Status status = second->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_EQ(status.error_message(),
              "ExportCoefficientHistory: caller 'ops' already runs 1 export stream (limit 1 per "
              "caller); retry when one finishes");
  }
  grpc::Status status;
  EXPECT_EQ(export_frames("dash-token-012345", &status),
            static_cast<int64_t>(Run1h().frames.size()));
  EXPECT_TRUE(status.ok()) << status.error_message();
  running->Release();
  EXPECT_EQ(export_frames("ops-token-a-01234", &status),
            static_cast<int64_t>(Run1h().frames.size()));
  EXPECT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(service.export_limiter().Running(), 0);
}

// ---- Unread subscription messages -------------------------------------------------------------

// An alert of about 1.3 KB (a long message), published live without being stored.
storage::AlertRecord BigAlert(int64_t sequence) {
  storage::AlertRecord r;
  r.spacecraft_id = "CB-FLOOD";
  r.sequence = sequence;
  r.severity = "WARNING";
  r.reason = "INNOVATION_TEST";
  r.subsystem = "gyro1";
  r.unit = "arcsec";
  r.message = std::string(1200, 'x');
  r.first_time = r.measurement_time = r.compute_time = absl::FromUnixSeconds(1700000000 + sequence);
  return r;
}

// Publishes `n` alerts in batches, pausing between them so that a reading subscriber keeps up.
void Flood(EstimationCore& core, int64_t n) {
  for (int64_t i = 1; i <= n; ++i) {
    core.alert_hub().Publish(BigAlert(i), /*log=*/false);
    if (i % 200 == 0) absl::SleepFor(absl::Milliseconds(2));
  }
}

// Issue 40's alert scenario: subscribers that never read. Four of one caller's never read, a
// fifth of the same caller reads everything. Beyond the caller's 8 MiB of unread messages the
// non-readers (each above the caller's average) are dropped with RESOURCE_EXHAUSTED naming the
// bound; the reader gets every alert and stays. Once they are gone the budget holds nothing and
// the queues are gone.
TEST(CallerBounds, NonReadingAlertSubscribersAreDroppedAtTheCallersByteBound) {
  ServerOptions options;
  options.calls.max_queued_bytes_per_caller = 8 << 20;
  LoopbackServer server(options);
  QueueBudget& budget = server.get()->service().queue_budget();
  const int64_t baseline_kib = RssKiB("self");

  std::vector<std::unique_ptr<HeldStream>> slow;
  for (int i = 0; i < 4; ++i) {
    slow.push_back(std::make_unique<HeldStream>());
    ASSERT_TRUE(slow.back()->Start(server.address(), i, /*alert=*/true));  // the marker
  }
  HeldStream reader;
  ASSERT_TRUE(reader.Start(server.address(), 10, /*alert=*/true));
  constexpr int64_t kAlerts = 20000;  // about 26 MB for each subscriber
  std::atomic<int64_t> read{0};
  std::thread reading([&] {
    esg::v1::Alert a;
    while (read.load() < kAlerts && reader.alerts->Read(&a)) read.fetch_add(1);
  });
  int64_t peak_held = 0;
  std::thread watch([&] {
    while (read.load() < kAlerts) {
      peak_held = std::max(peak_held, budget.held());
      absl::SleepFor(absl::Milliseconds(5));
    }
  });
  Flood(server.core(), kAlerts);
  const int64_t peak_kib = RssKiB("self");
  reading.join();
  watch.join();
  EXPECT_EQ(read.load(), kAlerts);

  for (auto& s : slow) {
    const grpc::Status status = s->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_THAT(status.error_message(),
                StartsWith("alert subscriber too slow, dropped: caller '127.0.0.1' holds "));
    EXPECT_THAT(status.error_message(),
                HasSubstr("bytes of unread subscription messages (limit 8 MiB per caller, "
                          "--max-queued-mb-per-caller); subscribe again with since = the latest "
                          "measurement_time received"));
  }
  // The bound held (it may be passed by what streams below their share queue meanwhile).
  EXPECT_LE(peak_held, (8 << 20) + (1 << 20));
  EXPECT_EQ(reader.Cancel().error_code(), grpc::StatusCode::CANCELLED);
  EXPECT_TRUE(WaitFor([&] { return budget.held() == 0; }, absl::Seconds(5))) << budget.held();
  absl::SleepFor(absl::Seconds(1));
  const int64_t after_kib = RssKiB("self");
  std::cout << "test process RSS: " << baseline_kib / 1024 << " MiB before, " << peak_kib / 1024
            << " MiB at the flood's end, " << after_kib / 1024
            << " MiB 1 s after the slow subscribers were dropped (peak held by the budget "
            << peak_held / 1024 << " KiB)\n";
  // This process is client and server, so its resident set is printed, not checked: the real
  // esgd's is checked after large predictions below.
}

// The bound over all subscribers: three callers (tokens), two never read. Beyond 4 MiB over
// all, the two non-readers are dropped naming the total bound; the reader is not.
TEST(CallerBounds, NonReadingSubscribersOfSeveralCallersAreDroppedAtTheTotalBound) {
  TempDir dir;
  WriteTokens(dir.File("tokens"),
              "slow-token-a-0123 read slow-a\nslow-token-b-0123 read slow-b\n"
              "fast-token-01234 read fast\n");
  ServerOptions options;
  options.tokens_file = dir.File("tokens");
  options.calls.max_queued_bytes = 4 << 20;
  LoopbackServer server(options);
  HeldStream slow_a, slow_b, fast;
  ASSERT_TRUE(slow_a.Start(server.address(), 1, true, "slow-token-a-0123"));
  ASSERT_TRUE(slow_b.Start(server.address(), 2, true, "slow-token-b-0123"));
  ASSERT_TRUE(fast.Start(server.address(), 3, true, "fast-token-01234"));
  constexpr int64_t kAlerts = 10000;
  std::atomic<int64_t> read{0};
  std::thread reading([&] {
    esg::v1::Alert a;
    while (read.load() < kAlerts && fast.alerts->Read(&a)) read.fetch_add(1);
  });
  Flood(server.core(), kAlerts);
  reading.join();
  EXPECT_EQ(read.load(), kAlerts);
  for (HeldStream* s : {&slow_a, &slow_b}) {
    const grpc::Status status = s->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_THAT(status.error_message(),
                HasSubstr("bytes of unread subscription messages (limit 4 MiB over all "
                          "subscribers, --max-queued-mb)"));
  }
  EXPECT_EQ(fast.Cancel().error_code(), grpc::StatusCode::CANCELLED);
  EXPECT_TRUE(WaitFor([&] { return server.get()->service().queue_budget().held() == 0; },
                      absl::Seconds(5)));
}

// ---- Alert replay ------------------------------------------------------------------------------

// Stores `n` alerts of about 1.3 KB in `server`'s SQLite file, alternating between spacecraft
// CB-RA and CB-RB, four to a measurement time (so that pages end between alerts of one time).
void StoreBigAlerts(LoopbackServer& server, int64_t n) {
  storage::Storage& store = server.core().storage();
  absl::StatusOr<storage::Transaction> txn =
      store.database().Begin(storage::TransactionMode::kImmediate);
  ASSERT_THAT(txn.status(), IsOk());
  for (int64_t i = 0; i < n; ++i) {
    storage::AlertRecord r = BigAlert(0);
    r.spacecraft_id = i % 2 == 0 ? "CB-RA" : "CB-RB";
    r.first_time = r.measurement_time = r.compute_time = absl::FromUnixSeconds(1700000000 + i / 4);
    ASSERT_THAT(store.alerts().Append(*txn, r).status(), IsOk());
  }
  ASSERT_THAT(txn->Commit(), IsOk());
}

// Reads a SubscribeAlerts stream since 1970 up to its marker; returns the alerts before it.
std::vector<esg::v1::Alert> ReplayAll(const std::string& address, const std::string& spacecraft_id,
                                      grpc::Status* status) {
  auto stub = esg::v1::EstimationService::NewStub(OwnChannel(address, 500));
  grpc::ClientContext context;
  context.set_deadline(In(absl::Minutes(2)));
  esg::v1::AlertSubscription request;
  request.set_spacecraft_id(spacecraft_id);
  request.mutable_since()->set_seconds(0);
  request.set_replay_marker(true);
  auto reader = stub->SubscribeAlerts(&context, request);
  std::vector<esg::v1::Alert> alerts;
  esg::v1::Alert a;
  bool marker = false;
  while (!marker && reader->Read(&a)) {
    marker = a.replay_complete();
    if (!marker) alerts.push_back(a);
  }
  if (marker) context.TryCancel();
  *status = reader->Finish();
  return alerts;
}

// SubscribeAlerts' replay is read 1000 stored alerts at a time, each page once the previous one
// is written, and charged to the caller's unread-message bound: a client that does not read
// holds one page (about 3 MB with its messages, here; the whole replay of 12 000 alerts of
// 1.3 KB is about 17 MB, which the replay used to read, and queue, at once). A client that
// reads gets every stored alert once, in order (over all spacecraft: by time, spacecraft,
// sequence), across pages that end between alerts of one measurement time.
TEST(CallerBounds, AlertReplayIsReadInPagesChargedToTheCallersBound) {
  LoopbackServer server;
  StoreBigAlerts(server, 12000);
  if (HasFatalFailure()) return;
  QueueBudget& budget = server.get()->service().queue_budget();

  std::atomic<int64_t> peak_held{0};
  std::atomic<bool> watching{true};
  std::thread watch([&] {
    while (watching.load()) {
      peak_held.store(std::max(peak_held.load(), budget.held()));
      absl::SleepFor(absl::Microseconds(200));
    }
  });
  HeldStream idle;
  ASSERT_TRUE(idle.Start(server.address(), 1, /*alert=*/true));
  absl::SleepFor(absl::Seconds(1));
  watching.store(false);
  watch.join();
  const int64_t idle_held = budget.held("127.0.0.1");
  std::cout << "a non-reading replay of 12000 stored alerts (about 17 MB) holds " << idle_held
            << " bytes of the caller's bound after 1 s, at most " << peak_held.load() << "\n";
  EXPECT_LE(peak_held.load(), 4 << 20);

  grpc::Status status;
  const std::vector<esg::v1::Alert> all = ReplayAll(server.address(), "", &status);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::CANCELLED) << status.error_message();
  ASSERT_EQ(all.size(), 12000u);
  std::set<std::pair<std::string, int64_t>> seen;
  for (size_t i = 0; i < all.size(); ++i) {
    seen.insert({all[i].spacecraft_id(), all[i].sequence()});
    if (i == 0) continue;
    const auto key = [](const esg::v1::Alert& a) {
      return std::make_tuple(a.measurement_time().seconds(), a.spacecraft_id(), a.sequence());
    };
    EXPECT_LT(key(all[i - 1]), key(all[i])) << i;
  }
  EXPECT_EQ(seen.size(), 12000u);
  {  // one spacecraft's replay asks for a configured one
    grpc::ClientContext context;
    esg::v1::ConfigureResponse configured;
    ASSERT_TRUE(server.Stub()
                    ->ConfigureSpacecraft(&context,
                                          ConfigureRequestFor(testing::ServerTestConfig("CB-RB")),
                                          &configured)
                    .ok());
  }
  const std::vector<esg::v1::Alert> one = ReplayAll(server.address(), "CB-RB", &status);
  ASSERT_EQ(one.size(), 6000u) << status.error_message();
  for (size_t i = 0; i < one.size(); ++i) {
    EXPECT_EQ(one[i].spacecraft_id(), "CB-RB");
    EXPECT_EQ(one[i].sequence(), static_cast<int64_t>(i) + 1);
  }

  // The idle stream was not dropped: it reads the rest once it reads.
  int64_t rest = 0;
  esg::v1::Alert a;
  while (idle.alerts->Read(&a) && !a.replay_complete()) ++rest;
  EXPECT_EQ(rest, 12000 - 1);
  EXPECT_EQ(idle.Cancel().error_code(), grpc::StatusCode::CANCELLED);
  EXPECT_TRUE(WaitFor([&] { return budget.held() == 0; }, absl::Seconds(5))) << budget.held();
}

// A replay page that would pass the caller's bound, or the bound over all subscribers, ends the
// stream with RESOURCE_EXHAUSTED naming the bound, as a slow live subscriber's queue does.
TEST(CallerBounds, AlertReplayBeyondTheBoundEndsNamingIt) {
  for (const bool per_caller : {true, false}) {
    ServerOptions options;
    if (per_caller) {
      options.calls.max_queued_bytes_per_caller = 1 << 20;
    } else {
      options.calls.max_queued_bytes = 1 << 20;
    }
    LoopbackServer server(options);
    StoreBigAlerts(server, 2000);
    if (HasFatalFailure()) return;
    grpc::Status status;
    EXPECT_TRUE(ReplayAll(server.address(), "", &status).empty());
    std::cout << status.error_message() << "\n";
    EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_THAT(status.error_message(),
                StartsWith("alert replay stopped: the page of 1000 stored alerts read for it ("));
    EXPECT_THAT(status.error_message(),
                HasSubstr(per_caller ? "(limit 1 MiB per caller, --max-queued-mb-per-caller); "
                                     : "(limit 1 MiB over all subscribers, --max-queued-mb); "));
    EXPECT_THAT(status.error_message(),
                EndsWith("subscribe again with since = the latest measurement_time received"));
    EXPECT_EQ(server.get()->service().queue_budget().held(), 0);
  }
}

// ---- Memory after large answers ---------------------------------------------------------------

// Issue 40: eight concurrent 100 000-sample predictions with AEM (about 33 MB each) against the
// real esgd. Its resident set (/proc/PID/status VmRSS) is back near its baseline within a
// minute after they finished (fixed malloc thresholds and malloc_trim after large answers,
// memory_release.h).
TEST(CallerBounds, ResidentSetReturnsToBaselineAfterEightLargePredictions) {
  TempDir dir;
  Daemon daemon(dir.File("var/esg.db"), dir.File("esgd.log"), {},
                {"--max-predictions-per-caller", "8"});
  ASSERT_GT(daemon.port(), 0);
  const std::string pid = std::to_string(daemon.pid());
  auto stub = esg::v1::EstimationService::NewStub(OwnChannel(daemon.address(), 0));
  Prepare(*stub);
  if (HasFatalFailure()) return;
  const int64_t last_s = Run1h().frames.back().time().seconds();
  esg::v1::PredictRequest request;
  request.set_spacecraft_id(Run1h().config.spacecraft_id);
  request.mutable_from()->set_seconds(last_s + 1);
  request.mutable_to()->set_seconds(last_s + 48 * 3600);
  request.set_step_s(1.728);  // 100 000 samples
  request.set_aem(true);
  {  // one small prediction first: the baseline includes what any prediction keeps
    esg::v1::PredictRequest small = request;
    small.mutable_to()->set_seconds(last_s + 600);
    small.set_step_s(60);
    grpc::ClientContext context;
    esg::v1::PredictResponse response;
    ASSERT_TRUE(stub->PredictAttitude(&context, small, &response).ok());
  }
  absl::SleepFor(absl::Seconds(1));
  const int64_t baseline = RssKiB(pid);
  std::atomic<int64_t> peak{baseline};
  std::atomic<bool> running{true};
  std::thread watch([&] {
    while (running.load()) {
      peak.store(std::max(peak.load(), RssKiB(pid)));
      absl::SleepFor(absl::Milliseconds(20));
    }
  });
  std::vector<std::thread> clients;
  std::vector<int64_t> aem_bytes(8, 0);
  for (int i = 0; i < 8; ++i) {
    clients.emplace_back([&, i] {
      auto own = esg::v1::EstimationService::NewStub(OwnChannel(daemon.address(), 100 + i));
      grpc::ClientContext context;
      context.set_deadline(In(absl::Minutes(5)));
      esg::v1::PredictResponse response;
      const grpc::Status status = own->PredictAttitude(&context, request, &response);
      EXPECT_TRUE(status.ok()) << status.error_message();
      aem_bytes[i] = static_cast<int64_t>(response.ByteSizeLong());
    });
  }
  for (std::thread& t : clients) t.join();
  const absl::Time finished = absl::Now();
  running.store(false);
  watch.join();
  // Within 10% of the baseline (the esgd started at 354 MB), or 16 MiB for this small
  // one (29 MiB): what gRPC and the thread arenas keep of the first large calls (measured
  // 32-42 MiB after, on 2 loaded cores).
  const int64_t bound = baseline + std::max<int64_t>(baseline / 10, 16 << 10);
  int64_t after = RssKiB(pid);
  while (after > bound && absl::Now() - finished < absl::Minutes(1)) {
    absl::SleepFor(absl::Milliseconds(250));
    after = RssKiB(pid);
  }
  std::cout << "esgd RSS: baseline " << baseline / 1024 << " MiB, peak " << peak.load() / 1024
            << " MiB during 8 predictions of " << aem_bytes[0] / 1000000 << " MB each, "
            << after / 1024 << " MiB "
            << absl::FormatDuration(absl::Trunc(absl::Now() - finished, absl::Milliseconds(1)))
            << " after they finished\n";
  EXPECT_GT(aem_bytes[0], 20'000'000);
  EXPECT_LE(after, bound);
}

// Issue 40's alert scenario against the real esgd: eight alert subscribers (live only, one
// caller) that never read while esgd publishes 29 000 alert states of about 1.4 KB
// (acknowledgements of stored alerts, each published to every subscriber: 41 MB for each, 325 MB
// for the eight without a bound). With --max-queued-mb-per-caller 24 they are dropped, naming the
// bound, as the caller's unread messages pass 24 MiB; esgd's resident set (/proc/PID/status
// VmRSS) is then back near its baseline within a minute, while the dropped calls are still open
// and after their clients finished them (what a stream held is given back at its drop and
// malloc_trim runs after it, memory_release.h).
TEST(CallerBounds, ResidentSetReturnsToBaselineAfterNonReadingAlertSubscribersAreDropped) {
  constexpr int64_t kAlerts = 30000;
  constexpr int kSubscribers = 8;
  TempDir dir;
  std::filesystem::create_directories(dir.File("var"));
  {  // the stored alerts to acknowledge, written before esgd opens the file
    absl::StatusOr<std::unique_ptr<storage::Storage>> store =
        storage::Storage::Open(dir.File("var/esg.db"));
    ASSERT_THAT(store.status(), IsOk());
    absl::StatusOr<storage::Transaction> txn =
        (*store)->database().Begin(storage::TransactionMode::kImmediate);
    ASSERT_THAT(txn.status(), IsOk());
    for (int64_t i = 1; i <= kAlerts; ++i) {
      storage::AlertRecord r = BigAlert(i);
      r.spacecraft_id = "CB-ACK";
      ASSERT_THAT((*store)->alerts().Append(*txn, r).status(), IsOk());
    }
    ASSERT_THAT(txn->Commit(), IsOk());
  }
  Daemon daemon(dir.File("var/esg.db"), dir.File("esgd.log"), {},
                {"--sync", "normal", "--max-queued-mb-per-caller", "24"});
  ASSERT_GT(daemon.port(), 0);
  const std::string pid = std::to_string(daemon.pid());
  {
    auto stub = esg::v1::EstimationService::NewStub(OwnChannel(daemon.address(), 0));
    grpc::ClientContext context;
    esg::v1::ConfigureResponse configured;
    ASSERT_TRUE(stub->ConfigureSpacecraft(
                        &context, ConfigureRequestFor(testing::ServerTestConfig("CB-ACK")),
                        &configured)
                    .ok());
  }
  // Acknowledges alerts [first, last) from 4 clients at once.
  auto acknowledge = [&](int64_t first, int64_t last) {
    std::vector<std::thread> clients;
    for (int c = 0; c < 4; ++c) {
      clients.emplace_back([&, c] {
        auto own = esg::v1::EstimationService::NewStub(OwnChannel(daemon.address(), 10 + c));
        for (int64_t seq = first + c; seq < last; seq += 4) {
          grpc::ClientContext context;
          context.set_deadline(In(absl::Seconds(30)));
          esg::v1::AcknowledgeRequest request;
          request.set_spacecraft_id("CB-ACK");
          request.set_sequence(seq);
          request.set_operator_name("flood");
          esg::v1::Alert acknowledged;
          const grpc::Status status = own->AcknowledgeAlert(&context, request, &acknowledged);
          ASSERT_TRUE(status.ok()) << seq << ": " << status.error_message();
        }
      });
    }
    for (std::thread& t : clients) t.join();
  };
  {  // warm-up with a subscriber that reads: the baseline includes what publishing keeps
    HeldStream reader;
    ASSERT_TRUE(reader.Start(daemon.address(), 100, /*alert=*/true, "", /*replay=*/false));
    std::thread reading([&] {
      esg::v1::Alert a;
      while (reader.alerts->Read(&a)) {
      }
    });
    acknowledge(1, 1001);
    reader.context.TryCancel();
    reading.join();
    reader.alerts->Finish();
  }
  absl::SleepFor(absl::Seconds(2));
  const int64_t baseline = RssKiB(pid);

  std::vector<std::unique_ptr<HeldStream>> slow;
  for (int i = 0; i < kSubscribers; ++i) {
    slow.push_back(std::make_unique<HeldStream>());
    ASSERT_TRUE(slow.back()->Start(daemon.address(), 200 + i, /*alert=*/true, "",
                                   /*replay=*/false));
  }
  std::atomic<int64_t> peak{baseline};
  std::atomic<bool> running{true};
  std::thread watch([&] {
    while (running.load()) {
      peak.store(std::max(peak.load(), RssKiB(pid)));
      absl::SleepFor(absl::Milliseconds(20));
    }
  });
  const absl::Time flood_start = absl::Now();
  acknowledge(1001, kAlerts + 1);
  const absl::Time flood_end = absl::Now();
  running.store(false);
  watch.join();
  // The bound stated for the large predictions above: within 10% of the baseline (the issue's
  // esgd started at 30 MB), or 16 MiB for a small one: what gRPC and the thread arenas keep of
  // the first large calls. What a dropped subscriber held is returned at its drop, so the
  // resident set is back within it while the dropped clients still hold their calls without
  // reading (gRPC is done with such a call only once its client took what was written).
  const int64_t bound = baseline + std::max<int64_t>(baseline / 10, 16 << 10);
  auto back_within_bound = [&](absl::Time since) {
    int64_t rss = RssKiB(pid);
    while (rss > bound && absl::Now() - since < absl::Minutes(1)) {
      absl::SleepFor(absl::Milliseconds(250));
      rss = RssKiB(pid);
    }
    return rss;
  };
  const int64_t held_open = back_within_bound(flood_end);
  const absl::Duration held_open_after = absl::Now() - flood_end;
  // Every subscriber was dropped naming the bound (read what esgd wrote before the status).
  for (auto& s : slow) {
    const grpc::Status status = s->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
    EXPECT_THAT(status.error_message(),
                HasSubstr("bytes of unread subscription messages (limit 24 MiB per caller, "
                          "--max-queued-mb-per-caller)"));
  }
  slow.clear();
  const absl::Time finished = absl::Now();
  const int64_t after = back_within_bound(finished);
  std::cout << "esgd RSS: baseline " << baseline / 1024 << " MiB, peak " << peak.load() / 1024
            << " MiB while " << kSubscribers << " non-reading subscribers were offered "
            << kAlerts - 1000 << " alerts ("
            << absl::FormatDuration(absl::Trunc(flood_end - flood_start, absl::Milliseconds(1)))
            << "); " << held_open / 1024 << " MiB "
            << absl::FormatDuration(absl::Trunc(held_open_after, absl::Milliseconds(1)))
            << " after the last alert with the dropped calls still open, " << after / 1024
            << " MiB "
            << absl::FormatDuration(absl::Trunc(absl::Now() - finished, absl::Milliseconds(1)))
            << " after their clients finished them\n";
  EXPECT_LE(held_open, bound);
  EXPECT_LE(after, bound);
}

}  // namespace
}  // namespace esg::server
