// Resource limits of esgd (docs/service.md "Limits"): the per-caller and total bounds on
// concurrent predictions and diagnoses (CallLimiter, and over gRPC with peer addresses and token
// names as callers), predictions on the service's own threads, cancellation of a running
// diagnosis, the request-size bound, and a burst of connections beyond the file-descriptor limit
// the daemon inherited (the real esgd as a child process).
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <sstream>
#include <thread>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "estimator/discovery/diagnose.h"
#include "gmock/gmock.h"
#include "grpcpp/support/channel_arguments.h"
#include "gtest/gtest.h"
#include "server/call_limiter.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/status_matchers.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::Daemon;
using ::esg::testing::IsOk;
using ::esg::testing::LoopbackServer;
using ::esg::testing::SimulateRun;
using ::esg::testing::SimulatedRun;
using ::esg::testing::StatusIs;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::esg::testing::WriteTokens;
using ::testing::Eq;
using ::testing::HasSubstr;

// Polls `done` until it holds or `limit` passes (a bound on a wait, not a timing assertion).
bool WaitFor(const std::function<bool()>& done, absl::Duration limit) {
  const absl::Time give_up = absl::Now() + limit;
  while (!done()) {
    if (absl::Now() > give_up) return false;
    absl::SleepFor(absl::Milliseconds(5));
  }
  return true;
}

std::chrono::system_clock::time_point In(absl::Duration d) {
  return absl::ToChronoTime(absl::Now() + d);
}

// A stub on its own channel that accepts responses up to 64 MiB (a 100 000-sample prediction is
// larger than gRPC's default 4 MiB client limit), optionally with a bearer token.
std::unique_ptr<esg::v1::EstimationService::Stub> BigStub(const std::string& address) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(64 << 20);
  return esg::v1::EstimationService::NewStub(
      grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args));
}

// ---- CallLimiter ------------------------------------------------------------------------------

TEST(CallLimiter, BoundsEachCallerAndTheTotal) {
  CallLimiter limiter("PredictAttitude", "prediction", "predictions", /*per_caller=*/2,
                      /*total=*/3);
  absl::StatusOr<CallLimiter::Permit> ops1 = limiter.Acquire("ops");
  absl::StatusOr<CallLimiter::Permit> ops2 = limiter.Acquire("ops");
  ASSERT_THAT(ops1, IsOk());
  ASSERT_THAT(ops2, IsOk());
  EXPECT_THAT(limiter.Acquire("ops"),
              StatusIs(absl::StatusCode::kResourceExhausted,
                       Eq("PredictAttitude: caller 'ops' already runs 2 predictions (limit 2 per "
                          "caller); retry when one finishes")));
  absl::StatusOr<CallLimiter::Permit> dash1 = limiter.Acquire("dash");
  ASSERT_THAT(dash1, IsOk());
  EXPECT_THAT(limiter.Acquire("dash"),
              StatusIs(absl::StatusCode::kResourceExhausted,
                       Eq("PredictAttitude: the server already runs 3 predictions (limit 3 in "
                          "total); retry when one finishes")));
  EXPECT_EQ(limiter.Running("ops"), 2);
  EXPECT_EQ(limiter.Running("dash"), 1);
  EXPECT_EQ(limiter.Running("nobody"), 0);
  EXPECT_EQ(limiter.Running(), 3);

  // A destroyed permit gives its slot back, to any caller.
  { CallLimiter::Permit gone = std::move(*ops1); }
  EXPECT_FALSE(ops1->held());  // moved from
  EXPECT_EQ(limiter.Running("ops"), 1);
  absl::StatusOr<CallLimiter::Permit> dash2 = limiter.Acquire("dash");
  ASSERT_THAT(dash2, IsOk());
  EXPECT_EQ(limiter.Running(), 3);

  // Release is idempotent; a moved-from permit gives nothing back.
  ops1->Release();
  dash2->Release();
  dash2->Release();
  EXPECT_EQ(limiter.Running("dash"), 1);
  EXPECT_EQ(limiter.Running(), 2);
  // Move assignment gives back the slot the target held.
  *ops2 = std::move(*dash1);
  EXPECT_EQ(limiter.Running("ops"), 0);
  EXPECT_EQ(limiter.Running("dash"), 1);
  ops2->Release();
  EXPECT_EQ(limiter.Running(), 0);
}

TEST(CallLimiter, NamesOneRunningCallInTheSingular) {
  CallLimiter limiter("Diagnose", "diagnosis", "diagnoses", 1, 2);
  absl::StatusOr<CallLimiter::Permit> held = limiter.Acquire("10.0.0.7");
  ASSERT_THAT(held, IsOk());
  EXPECT_THAT(limiter.Acquire("10.0.0.7"),
              StatusIs(absl::StatusCode::kResourceExhausted,
                       Eq("Diagnose: caller '10.0.0.7' already runs 1 diagnosis (limit 1 per "
                          "caller); retry when one finishes")));
}

TEST(CallLimiter, ConcurrentCallersNeverExceedTheBounds) {
  CallLimiter limiter("PredictAttitude", "prediction", "predictions", 2, 5);
  std::atomic<int> over_total{0}, over_caller{0}, granted{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 8; ++t) {
    threads.emplace_back([&, caller = "c" + std::to_string(t % 4)] {
      for (int i = 0; i < 2000; ++i) {
        absl::StatusOr<CallLimiter::Permit> p = limiter.Acquire(caller);
        if (!p.ok()) continue;
        ++granted;
        if (limiter.Running() > 5) ++over_total;
        if (limiter.Running(caller) > 2) ++over_caller;
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_GT(granted.load(), 0);
  EXPECT_EQ(over_total.load(), 0);
  EXPECT_EQ(over_caller.load(), 0);
  EXPECT_EQ(limiter.Running(), 0);
}

TEST(CallerFromPeer, DropsTheSchemeAndThePort) {
  EXPECT_EQ(CallerFromPeer("ipv4:127.0.0.1:54321"), "127.0.0.1");
  EXPECT_EQ(CallerFromPeer("ipv4:10.1.2.3:50051"), "10.1.2.3");
  EXPECT_EQ(CallerFromPeer("ipv6:[::1]:5432"), "::1");
  EXPECT_EQ(CallerFromPeer("ipv6:%5B::1%5D:5432"), "::1");
  EXPECT_EQ(CallerFromPeer("ipv6:%5Bfe80::2:3%5D:80"), "fe80::2:3");
  EXPECT_EQ(CallerFromPeer("unix:/run/esg.sock"), "unix:/run/esg.sock");
  EXPECT_EQ(CallerFromPeer(""), "");
}

// ---- PredictAttitude --------------------------------------------------------------------------

// A configured spacecraft with an attitude (1 h of the calibration profile applied).
const SimulatedRun& Run1h() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("LIM-1", 1.0, 5));
  return *run;
}

void Prepare(LoopbackServer& server, esg::v1::EstimationService::Stub& stub) {
  const SimulatedRun& run = Run1h();
  grpc::ClientContext context;
  esg::v1::ConfigureResponse configured;
  ASSERT_TRUE(stub.ConfigureSpacecraft(&context, ConfigureRequestFor(run.config), &configured).ok());
  const testing::StreamResult streamed = StreamFrames(stub, run.frames);
  ASSERT_TRUE(streamed.status.ok()) << streamed.status.error_message();
  ASSERT_THAT(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(60)), IsOk());
}

// The largest prediction the defaults allow: 48 h after the last frame at 100 000 samples.
esg::v1::PredictRequest LargestPrediction() {
  const int64_t last_s = Run1h().frames.back().time().seconds();
  esg::v1::PredictRequest request;
  request.set_spacecraft_id(Run1h().config.spacecraft_id);
  request.mutable_from()->set_seconds(last_s + 1);
  request.mutable_to()->set_seconds(last_s + 48 * 3600);
  request.set_step_s(1.728);  // floor(172799 s / 1.728 s) + 1 = 100 000 samples
  return request;
}

TEST(Limits, PredictionsRunOffTheGrpcThreadsAndAreBoundedPerCaller) {
  LoopbackServer server;
  auto stub = BigStub(server.address());
  Prepare(server, *stub);
  CallLimiter& limiter = server.get()->service().prediction_limiter();
  const std::string caller = "127.0.0.1";  // no tokens: the peer address is the caller
  const int limit = limiter.per_caller();
  ASSERT_EQ(limit, 4);  // the default

  const esg::v1::PredictRequest request = LargestPrediction();
  std::vector<grpc::Status> statuses(limit);
  std::vector<int> samples(limit, 0);
  std::vector<std::thread> clients;
  for (int i = 0; i < limit; ++i) {
    clients.emplace_back([&, i] {
      grpc::ClientContext context;
      context.set_deadline(In(absl::Minutes(5)));
      esg::v1::PredictResponse response;
      statuses[i] = stub->PredictAttitude(&context, request, &response);
      samples[i] = response.samples_size();
    });
  }
  ASSERT_TRUE(WaitFor([&] { return limiter.Running(caller) == limit; }, absl::Minutes(2)))
      << "the " << limit << " predictions never ran together";

  // While they run, a status call is answered: the predictions hold no gRPC thread.
  grpc::ClientContext status_context;
  status_context.set_deadline(In(absl::Seconds(2)));
  esg::v1::GetSessionRequest get;
  get.set_spacecraft_id(Run1h().config.spacecraft_id);
  esg::v1::SessionInfo info;
  const grpc::Status status_call = stub->GetSession(&status_context, get, &info);

  // One more prediction of the same caller is refused at once. Its refusal also shows that all
  // of them were still running through the status call (nothing else starts a prediction).
  grpc::ClientContext extra_context;
  extra_context.set_deadline(In(absl::Minutes(1)));
  esg::v1::PredictResponse extra_response;
  const grpc::Status extra = stub->PredictAttitude(&extra_context, request, &extra_response);

  for (std::thread& t : clients) t.join();
  EXPECT_TRUE(status_call.ok()) << status_call.error_code() << " " << status_call.error_message();
  EXPECT_EQ(info.spacecraft_id(), Run1h().config.spacecraft_id);
  EXPECT_EQ(extra.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << extra.error_message();
  EXPECT_EQ(extra.error_message(),
            "PredictAttitude: caller '127.0.0.1' already runs 4 predictions (limit 4 per caller); "
            "retry when one finishes");
  for (int i = 0; i < limit; ++i) {
    EXPECT_TRUE(statuses[i].ok()) << statuses[i].error_message();
    EXPECT_EQ(samples[i], 100000);
  }
  EXPECT_EQ(limiter.Running(), 0);

  // Slots come back before the response: back-to-back predictions are never refused.
  for (int i = 0; i < 2 * limit; ++i) {
    grpc::ClientContext context;
    esg::v1::PredictRequest small = request;
    small.mutable_to()->set_seconds(small.from().seconds() + 600);
    small.set_step_s(60);
    esg::v1::PredictResponse response;
    ASSERT_TRUE(stub->PredictAttitude(&context, small, &response).ok());
  }
}

TEST(Limits, CallersAreTokenNamesAndTheTotalBoundsThemAll) {
  TempDir dir;
  // Two tokens of one caller (a rotation), two other callers.
  WriteTokens(dir.File("tokens"),
              "ops-token-a-01234 read ops\nops-token-b-01234 read ops\ndash-token-012345 read dash\n"
              "third-token-01234 read third\n");
  ServerOptions options;
  options.tokens_file = dir.File("tokens");
  LoopbackServer server(options);
  auto stub = server.Stub();
  CallLimiter& predictions = server.get()->service().prediction_limiter();
  CallLimiter& diagnoses = server.get()->service().diagnosis_limiter();

  auto predict = [&](const std::string& token) {
    grpc::ClientContext context;
    context.AddMetadata("authorization", "Bearer " + token);
    esg::v1::PredictRequest request;
    request.set_spacecraft_id("NOT-CONFIGURED");
    request.add_times()->set_seconds(1551400000);
    esg::v1::PredictResponse response;
    return stub->PredictAttitude(&context, request, &response);
  };
  auto diagnose = [&](const std::string& token) {
    grpc::ClientContext context;
    context.AddMetadata("authorization", "Bearer " + token);
    esg::v1::DiagnoseRequest request;
    request.set_spacecraft_id("NOT-CONFIGURED");
    auto reader = stub->Diagnose(&context, request);
    esg::v1::DiagnoseUpdate update;
    while (reader->Read(&update)) {
    }
    return reader->Finish();
  };

  // 'ops' runs its 4 predictions (held here): both of its tokens are refused, 'dash' is not.
  std::vector<CallLimiter::Permit> held;
  for (int i = 0; i < 4; ++i) held.push_back(std::move(*predictions.Acquire("ops")));
  for (const char* token : {"ops-token-a-01234", "ops-token-b-01234"}) {
    const grpc::Status refused = predict(token);
    EXPECT_EQ(refused.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << token;
    EXPECT_EQ(refused.error_message(),
              "PredictAttitude: caller 'ops' already runs 4 predictions (limit 4 per caller); "
              "retry when one finishes");
  }
  EXPECT_EQ(predict("dash-token-012345").error_code(), grpc::StatusCode::NOT_FOUND);  // got through
  // The role check comes first: an unknown token is UNAUTHENTICATED, not counted.
  EXPECT_EQ(predict("who-knows").error_code(), grpc::StatusCode::UNAUTHENTICATED);
  // 'dash' takes the other 4: the total of 8 refuses 'third'.
  for (int i = 0; i < 4; ++i) held.push_back(std::move(*predictions.Acquire("dash")));
  const grpc::Status full = predict("third-token-01234");
  EXPECT_EQ(full.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_EQ(full.error_message(),
            "PredictAttitude: the server already runs 8 predictions (limit 8 in total); retry "
            "when one finishes");
  held.clear();
  EXPECT_EQ(predict("third-token-01234").error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(predictions.Running(), 0);

  // Diagnoses: 1 per caller, 2 in total.
  std::vector<CallLimiter::Permit> diagnosing;
  diagnosing.push_back(std::move(*diagnoses.Acquire("dash")));
  const grpc::Status busy = diagnose("dash-token-012345");
  EXPECT_EQ(busy.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_EQ(busy.error_message(),
            "Diagnose: caller 'dash' already runs 1 diagnosis (limit 1 per caller); retry when "
            "one finishes");
  EXPECT_EQ(diagnose("ops-token-a-01234").error_code(), grpc::StatusCode::NOT_FOUND);
  diagnosing.push_back(std::move(*diagnoses.Acquire("ops")));
  const grpc::Status all_busy = diagnose("third-token-01234");
  EXPECT_EQ(all_busy.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_THAT(all_busy.error_message(),
              HasSubstr("the server already runs 2 diagnoses (limit 2 in total)"));
  diagnosing.clear();
  EXPECT_EQ(diagnose("third-token-01234").error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_EQ(diagnoses.Running(), 0);
}

// ---- Diagnose cancellation --------------------------------------------------------------------

TEST(Limits, DiagnosisStopsAtTheNextCheckOnceCancelled) {
  const SimulatedRun run = SimulateRun("LIM-D1", 12.0, 3);
  std::vector<estimator::TelemetryFrame> frames;
  for (const esg::v1::TelemetryFrame& proto : run.frames) {
    auto frame = proto_convert::FrameFromProto(proto);
    ASSERT_THAT(frame, IsOk());
    frames.push_back(*frame);
  }
  // Cancelled once the user's model starts: no later stage is reached.
  std::atomic<bool> cancelled{false};
  std::vector<std::string> stages;
  estimator::discovery::DiagnoseOptions options;
  options.cancelled = [&] { return cancelled.load(); };
  auto report = estimator::discovery::Diagnose(
      run.config, frames, options, [&](double, const std::string& stage) {
        stages.push_back(stage);
        if (stage == "user model") cancelled = true;
      });
  EXPECT_THAT(report, StatusIs(absl::StatusCode::kCancelled, Eq("diagnosis cancelled")));
  EXPECT_THAT(stages, ::testing::ElementsAre("regimes", "user model"));

  // Cancelled in the first round of candidates: the round's fits stop, nothing later runs.
  cancelled = false;
  stages.clear();
  report = estimator::discovery::Diagnose(
      run.config, frames, options, [&](double, const std::string& stage) {
        stages.push_back(stage);
        if (absl::StrContains(stage, "fitted")) cancelled = true;
      });
  EXPECT_THAT(report, StatusIs(absl::StatusCode::kCancelled, Eq("diagnosis cancelled")));
  // At most the fits already running report after the cancel: without a runner (as here) the
  // fits run one after another on this thread, with the server's runner on options.threads.
  int fitted = 0;
  for (const std::string& s : stages) fitted += absl::StrContains(s, "fitted");
  EXPECT_LE(fitted, options.threads);
  EXPECT_THAT(stages.back(), HasSubstr("fitted"));

  // Without cancellation the same recording completes.
  cancelled = false;
  options.cancelled = [&] { return cancelled.load(); };
  EXPECT_THAT(estimator::discovery::Diagnose(run.config, frames, options), IsOk());
}

TEST(Limits, CancelledDiagnoseCallStopsStoresNothingAndFreesTheCallersSlot) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun run = SimulateRun("LIM-D2", 48.0, 21);
  {
    grpc::ClientContext context;
    esg::v1::ConfigureResponse configured;
    ASSERT_TRUE(
        stub->ConfigureSpacecraft(&context, ConfigureRequestFor(run.config), &configured).ok());
  }
  ASSERT_TRUE(StreamFrames(*stub, run.frames).status.ok());
  CallLimiter& limiter = server.get()->service().diagnosis_limiter();
  ASSERT_EQ(limiter.per_caller(), 1);  // the default
  esg::v1::DiagnoseRequest request;
  request.set_spacecraft_id("LIM-D2");
  auto stored = [&] {
    grpc::ClientContext context;
    esg::v1::ListDiagnosesRequest list;
    list.set_spacecraft_id("LIM-D2");
    esg::v1::ListDiagnosesResponse listed;
    EXPECT_TRUE(stub->ListDiagnoses(&context, list, &listed).ok());
    return listed.diagnoses_size();
  };
  // Starts a diagnosis, reads its first progress update, cancels the call.
  auto start_and_cancel = [&] {
    grpc::ClientContext context;
    context.set_deadline(In(absl::Minutes(5)));
    auto reader = stub->Diagnose(&context, request);
    esg::v1::DiagnoseUpdate update;
    const bool started = reader->Read(&update);
    EXPECT_FALSE(update.has_result());
    EXPECT_EQ(limiter.Running("127.0.0.1"), started ? 1 : 0);
    context.TryCancel();
    while (reader->Read(&update)) {
    }
    const grpc::Status status = reader->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::CANCELLED) << status.error_message();
    return started;
  };

  ASSERT_TRUE(start_and_cancel()) << "the first diagnosis sent no progress";
  // The server-side run stops: the caller's only slot comes free ...
  const absl::Time cancelled_at = absl::Now();
  ASSERT_TRUE(WaitFor([&] { return limiter.Running() == 0; }, absl::Minutes(2)));
  RecordProperty("cancel_to_free_slot_ms",
                 std::to_string(absl::ToInt64Milliseconds(absl::Now() - cancelled_at)));
  // ... and nothing was stored.
  EXPECT_EQ(stored(), 0);
  // A new diagnosis of the same caller starts at once despite the limit of 1 per caller.
  ASSERT_TRUE(start_and_cancel()) << "the second diagnosis was refused";
  ASSERT_TRUE(WaitFor([&] { return limiter.Running() == 0; }, absl::Minutes(2)));
  EXPECT_EQ(stored(), 0);
}

// ---- Message size -----------------------------------------------------------------------------

TEST(Limits, OversizedRequestsAreRefusedByGrpcAndTheServerGoesOn) {
  LoopbackServer server;
  auto stub = server.Stub();
  // A 10 MB spacecraft id.
  estimator::SpacecraftConfig config = testing::ServerTestConfig("X");
  config.spacecraft_id = std::string(10 << 20, 'x');
  {
    grpc::ClientContext context;
    esg::v1::ConfigureResponse response;
    const grpc::Status status =
        stub->ConfigureSpacecraft(&context, ConfigureRequestFor(config), &response);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << status.error_message();
  }
  {  // Still serving, and nothing was stored.
    grpc::ClientContext context;
    context.set_deadline(In(absl::Seconds(10)));
    esg::v1::ListSessionsResponse sessions;
    ASSERT_TRUE(stub->ListSessions(&context, {}, &sessions).ok());
    EXPECT_EQ(sessions.sessions_size(), 0);
  }

  // The default bound holds the largest prediction request: 100 000 explicit epochs and a
  // planned attitude of 100 000 samples (times with nanoseconds, full-precision quaternions).
  esg::v1::PredictRequest largest;
  largest.set_spacecraft_id("NOT-CONFIGURED");
  for (int i = 0; i < 100000; ++i) {
    google::protobuf::Timestamp* t = largest.add_times();
    t->set_seconds(1551400000 + 2 * i);
    t->set_nanos(999999999);
    esg::v1::AttitudeSample* s = largest.add_planned_attitude();
    s->mutable_time()->set_seconds(1551400000 + 2 * i);
    s->mutable_time()->set_nanos(123456789);
    const double a = 1e-3 * i;
    for (double v : {std::cos(a), 0.5 * std::sin(a), -0.5 * std::sin(a), std::sqrt(0.5) * std::sin(a)}) {
      s->add_q_in_b(v);
    }
  }
  const int64_t size = static_cast<int64_t>(largest.ByteSizeLong());
  RecordProperty("largest_predict_request_bytes", std::to_string(size));
  EXPECT_LT(size, ServerOptions{}.max_message_bytes);
  EXPECT_GT(size, 4 << 20);  // beyond gRPC's 4 MiB default: why the bound is 8 MiB
  grpc::ClientContext context;
  esg::v1::PredictResponse response;
  const grpc::Status status = stub->PredictAttitude(&context, largest, &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND) << status.error_message();
}

// ---- File descriptors -------------------------------------------------------------------------

// A channel with a connection of its own (no subchannel shared with other channels).
std::shared_ptr<grpc::Channel> OwnConnection(const std::string& address, int index) {
  grpc::ChannelArguments args;
  args.SetInt(GRPC_ARG_USE_LOCAL_SUBCHANNEL_POOL, 1);
  args.SetInt("esg.test.connection", index);
  return grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args);
}

// One ListSessions on `channel`; true when answered.
bool Answers(const std::shared_ptr<grpc::Channel>& channel) {
  auto stub = esg::v1::EstimationService::NewStub(channel);
  grpc::ClientContext context;
  context.set_deadline(In(absl::Seconds(10)));
  esg::v1::ListSessionsResponse response;
  return stub->ListSessions(&context, {}, &response).ok();
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// Started with the soft limit of a default shell (here 128 descriptors), esgd raises it to the
// hard limit, so a burst of connections beyond the inherited limit is served; after they close,
// new connections are still accepted. (Without the raise, accept() would fail with EMFILE near
// connection 110 and gRPC 1.51 would never accept again: grpc/grpc#20418.)
TEST(Limits, BurstBeyondTheInheritedFdLimitIsServedAndTheServerStillAccepts) {
  constexpr rlim_t kInheritedSoft = 128;
  constexpr int kConnections = 300;
  rlimit own{};
  ASSERT_EQ(getrlimit(RLIMIT_NOFILE, &own), 0);
  if (own.rlim_max != RLIM_INFINITY && own.rlim_max < 2 * kConnections + 256) {
    GTEST_SKIP() << "hard RLIMIT_NOFILE " << own.rlim_max << " is too low for this test";
  }
  if (own.rlim_cur != RLIM_INFINITY && own.rlim_cur < 2 * kConnections + 256) {
    rlimit raised = own;
    raised.rlim_cur = own.rlim_max;
    ASSERT_EQ(setrlimit(RLIMIT_NOFILE, &raised), 0);  // the client's own sockets
  }
  TempDir dir;
  const std::string log = dir.File("esgd.log");
  {
    Daemon daemon(dir.File("var/esg.db"), log, {kInheritedSoft, 0});
    ASSERT_GT(daemon.port(), 0);
    std::vector<std::shared_ptr<grpc::Channel>> channels;
    int answered = 0;
    for (int i = 0; i < kConnections; ++i) {
      channels.push_back(OwnConnection(daemon.address(), i));
      if (!Answers(channels.back())) break;
      ++answered;
    }
    EXPECT_EQ(answered, kConnections);
    channels.clear();  // every connection closes
    // New connections are accepted and answered.
    for (int i = 0; i < 3; ++i) {
      EXPECT_TRUE(Answers(OwnConnection(daemon.address(), kConnections + i))) << i;
    }
  }
  const std::string text = ReadText(log);
  EXPECT_THAT(text, HasSubstr(absl::StrCat("(raised from ", kInheritedSoft, ")"))) << text;
}

// What remains of grpc/grpc#20418 in gRPC 1.51 (docs/service.md "Limits"): at the HARD limit
// accept() fails with EMFILE, the listener stops for good, and even after every connection
// closed no new one is answered. Disabled: it pins an upstream defect, not our behaviour; run
// with --gtest_also_run_disabled_tests to see it.
TEST(Limits, DISABLED_AtTheHardFdLimitGrpc151StopsAcceptingForGood) {
  TempDir dir;
  const std::string log = dir.File("esgd.log");
  Daemon daemon(dir.File("var/esg.db"), log, {128, 128});
  ASSERT_GT(daemon.port(), 0);
  std::vector<std::shared_ptr<grpc::Channel>> channels;
  int answered = 0;
  for (int i = 0; i < 200; ++i) {
    channels.push_back(OwnConnection(daemon.address(), i));
    if (!Answers(channels.back())) break;
    ++answered;
  }
  channels.clear();
  absl::SleepFor(absl::Seconds(2));
  const bool answers_after = Answers(OwnConnection(daemon.address(), 1000));
  std::cout << "answered " << answered << " of 200 connections; a new one after they closed: "
            << (answers_after ? "answered" : "not answered") << "\n"
            << ReadText(log);
  EXPECT_LT(answered, 200);
}

}  // namespace
}  // namespace esg::server
