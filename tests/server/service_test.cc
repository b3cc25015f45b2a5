// The esg.v1.EstimationService over real gRPC on loopback with a real SQLite file
// (docs/service.md): ingest acks and rejections, configuration rules, bad requests naming the
// field, prediction with its AEM, coefficient history, and the alert subscription.
#include <algorithm>
#include <cmath>
#include <map>
#include <random>
#include <set>
#include <thread>

#include "absl/synchronization/mutex.h"
#include "formats/aem.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/status_matchers.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::LoopbackServer;
using ::esg::testing::SimulateRun;
using ::esg::testing::SimulatedRun;
using ::esg::testing::StreamFrames;
using ::testing::HasSubstr;

// 3 h of the calibration profile, shared by the tests of this file (simulated once).
const SimulatedRun& Run3h() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("SVC-1", 3.0, 11));
  return *run;
}

void ExpectCode(const grpc::Status& status, grpc::StatusCode code, const std::string& text) {
  EXPECT_EQ(status.error_code(), code) << status.error_message();
  EXPECT_THAT(status.error_message(), HasSubstr(text));
}

TEST(Service, IngestAcksEveryFrameDurablyAndAppliesThem) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun& run = Run3h();
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse configured;
  ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &configured).ok());
  EXPECT_TRUE(configured.created());
  EXPECT_EQ(configured.session().state(), esg::v1::SESSION_STATE_NO_DATA);
  EXPECT_EQ(configured.session().model(), "10+11");

  auto result = StreamFrames(*stub, run.frames);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_EQ(result.acks.size(), run.frames.size());
  for (size_t i = 0; i < result.acks.size(); ++i) {
    const esg::v1::TelemetryAck& ack = result.acks[i];
    EXPECT_EQ(ack.sequence(), static_cast<int64_t>(i + 1));  // in order
    EXPECT_TRUE(ack.accepted());
    EXPECT_FALSE(ack.duplicate());
    EXPECT_GE(ack.highest_durable_sequence(), ack.sequence());  // ack follows durability
  }
  ASSERT_TRUE(server.core().WaitApplied("SVC-1", absl::Seconds(60)).ok());
  grpc::ClientContext ctx2;
  esg::v1::GetSessionRequest get;
  get.set_spacecraft_id("SVC-1");
  esg::v1::SessionInfo info;
  ASSERT_TRUE(stub->GetSession(&ctx2, get, &info).ok());
  const int64_t n = static_cast<int64_t>(run.frames.size());
  EXPECT_EQ(info.frames_accepted(), n);
  EXPECT_EQ(info.frames_applied(), n);
  EXPECT_EQ(info.highest_durable_sequence(), n);
  EXPECT_EQ(info.highest_applied_sequence(), n);
  EXPECT_EQ(info.last_sequence(), n);
  EXPECT_NE(info.state(), esg::v1::SESSION_STATE_NO_DATA);
  EXPECT_THAT(info.working_pair(), ::testing::ElementsAre(1, 2));
  ASSERT_EQ(info.latest_attitude().q_in_b_size(), 4);
  EXPECT_GE(info.latest_attitude().q_in_b(0), 0.0);

  // Resending acknowledged frames: duplicates, acknowledged again, not applied again.
  std::vector<esg::v1::TelemetryFrame> again(run.frames.end() - 5, run.frames.end());
  auto dup = StreamFrames(*stub, again);
  ASSERT_EQ(dup.acks.size(), 5u);
  for (const auto& ack : dup.acks) {
    EXPECT_TRUE(ack.accepted());
    EXPECT_TRUE(ack.duplicate());
    EXPECT_EQ(ack.highest_durable_sequence(), n);
  }
  grpc::ClientContext ctx3;
  ASSERT_TRUE(stub->GetSession(&ctx3, get, &info).ok());
  EXPECT_EQ(info.frames_duplicate(), 5);
  EXPECT_EQ(info.frames_applied(), n);
  EXPECT_EQ(info.frames_accepted(), n);

  // History: one snapshot per running gyro and measurement step, ordered by time.
  grpc::ClientContext ctx4;
  esg::v1::HistoryRequest history;
  history.set_spacecraft_id("SVC-1");
  history.set_gyro_id(1);
  esg::v1::HistoryResponse snapshots;
  ASSERT_TRUE(stub->GetCoefficientHistory(&ctx4, history, &snapshots).ok());
  ASSERT_GT(snapshots.snapshots_size(), 100);
  for (int i = 1; i < snapshots.snapshots_size(); ++i) {
    EXPECT_EQ(snapshots.snapshots(i).gyro_id(), 1);
    EXPECT_LT(snapshots.snapshots(i - 1).measurement_time().seconds(),
              snapshots.snapshots(i).measurement_time().seconds());
  }
  // The prior sigma of k0 (0.3 deg/h) shrank under calibration.
  EXPECT_LT(esg::testing::TermDegH(snapshots.snapshots(snapshots.snapshots_size() - 1).sigma(),
                                   estimator::kThetaK0),
            0.3);
}

TEST(Service, MalformedFramesAreRejectedNamingTheFieldAndTheStreamGoesOn) {
  LoopbackServer server;
  auto stub = server.Stub();
  SimulatedRun run = Run3h();
  run.config.spacecraft_id = "BAD-1";
  run.config.gyros.pop_back();  // gyro 4 not configured
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse configured;
  ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &configured).ok());
  std::vector<esg::v1::TelemetryFrame> good(run.frames.begin(), run.frames.begin() + 3);
  for (auto& f : good) f.set_spacecraft_id("BAD-1");

  struct Case {
    const char* name;
    std::function<void(esg::v1::TelemetryFrame&)> mutate;
    const char* field;
    grpc::StatusCode code = grpc::StatusCode::INVALID_ARGUMENT;
  };
  using grpc::StatusCode;
  const Case cases[] = {
      {"NaN", [](auto& f) { f.mutable_gyros(0)->set_h_k(1, std::nan("")); }, "gyros[0].h_k"},
      {"non-unit h",
       [](auto& f) {
         for (int i = 0; i < 3; ++i) f.mutable_gyros(1)->set_h_k(i, f.gyros(1).h_k(i) * 1.2);
       },
       "gyros[1].h_k"},
      {"non-unit quaternion",
       [](auto& f) { f.mutable_star_tracker()->set_q_in_b(0, f.star_tracker().q_in_b(0) + 0.5); },
       "star_tracker.q_in_b"},
      {"bad gyro id", [](auto& f) { f.mutable_gyros(0)->set_gyro_id(7); }, "gyros[0].gyro_id"},
      {"duplicate gyro", [](auto& f) { f.mutable_gyros(1)->set_gyro_id(1); }, "gyro_id"},
      {"gyro not configured",
       [](auto& f) {
         auto* g = f.add_gyros();
         *g = f.gyros(0);
         g->set_gyro_id(4);
       },
       "gyros[3].gyro_id"},
      // The time of a stored frame with other content: a conflict, not a duplicate.
      {"time of a stored frame", [&](auto& f) { *f.mutable_time() = good[0].time(); }, "time",
       StatusCode::ALREADY_EXISTS},
      {"no time", [](auto& f) { f.clear_time(); }, "time"},
      {"time 30 days later",
       [](auto& f) { f.mutable_time()->set_seconds(f.time().seconds() + 30 * 86400); }, "time",
       StatusCode::OUT_OF_RANGE},
      {"unknown spacecraft", [](auto& f) { f.set_spacecraft_id("NOPE"); }, "spacecraft_id",
       StatusCode::NOT_FOUND},
      {"sequence 0", [](auto& f) { f.set_sequence(0); }, "sequence"},
      {"year 2300 (not storable)",
       [](auto& f) { f.mutable_time()->set_seconds(10486540800); }, "time",
       StatusCode::OUT_OF_RANGE},
      {"year 1600", [](auto& f) { f.mutable_time()->set_seconds(-11676096000); }, "time",
       StatusCode::OUT_OF_RANGE},
      {"station id with a newline", [](auto& f) { f.set_station_id("A\nB"); }, "station_id"},
      {"spacecraft id of 65 characters",
       [](auto& f) { f.set_spacecraft_id(std::string(65, 'X')); }, "spacecraft_id"},
      {"frame of 9000 bytes",
       [](auto& f) { f.mutable_gyros(0)->mutable_u_k_mv()->Resize(1125, 0.0); }, "frame",
       StatusCode::RESOURCE_EXHAUSTED},
  };
  std::vector<esg::v1::TelemetryFrame> frames = {good[0]};
  for (const Case& c : cases) {
    esg::v1::TelemetryFrame f = good[1];
    c.mutate(f);
    frames.push_back(f);
  }
  frames.push_back(good[1]);
  frames.push_back(good[2]);
  auto result = StreamFrames(*stub, frames);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_EQ(result.acks.size(), frames.size());
  EXPECT_TRUE(result.acks[0].accepted());
  for (size_t i = 0; i < std::size(cases); ++i) {
    SCOPED_TRACE(cases[i].name);
    const esg::v1::TelemetryAck& ack = result.acks[i + 1];
    EXPECT_FALSE(ack.accepted());
    EXPECT_THAT(ack.rejection().field(), HasSubstr(cases[i].field));
    EXPECT_FALSE(ack.rejection().reason().empty());
    EXPECT_EQ(ack.rejection().code(), static_cast<int>(cases[i].code));
  }
  EXPECT_TRUE(result.acks[std::size(cases) + 1].accepted());
  EXPECT_TRUE(result.acks[std::size(cases) + 2].accepted());
  EXPECT_EQ(result.acks.back().highest_durable_sequence(), 3);
  grpc::ClientContext ctx2;
  esg::v1::GetSessionRequest get;
  get.set_spacecraft_id("BAD-1");
  esg::v1::SessionInfo info;
  ASSERT_TRUE(stub->GetSession(&ctx2, get, &info).ok());
  EXPECT_EQ(info.frames_accepted(), 3);
  // Neither the unknown spacecraft's nor the invalid ids' (refused before the spacecraft is
  // known) nor the oversized frame's; the conflict is counted apart.
  EXPECT_EQ(info.frames_rejected(), static_cast<int64_t>(std::size(cases)) - 5);
  EXPECT_EQ(info.frames_conflicting(), 1);
}

TEST(Service, MalformedRequestsGetTheirCodeAndNameTheField) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun& run = Run3h();
  {
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
  }
  auto configure = [&](esg::v1::ConfigureRequest request) {
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    return stub->ConfigureSpacecraft(&ctx, request, &r);
  };
  {
    auto request = ConfigureRequestFor(run.config);
    request.mutable_config()->mutable_gyros(0)->mutable_case_to_body()->RemoveLast();
    ExpectCode(configure(request), grpc::StatusCode::INVALID_ARGUMENT, "gyros[0].caseToBody");
  }
  {
    auto request = ConfigureRequestFor(run.config);
    request.mutable_config()->set_working_pair(1, 9);
    ExpectCode(configure(request), grpc::StatusCode::INVALID_ARGUMENT, "workingPair");
  }
  {
    auto request = ConfigureRequestFor(run.config);
    request.mutable_config()->mutable_star_tracker()->set_noise_arcsec(0, -5);
    ExpectCode(configure(request), grpc::StatusCode::INVALID_ARGUMENT, "starTracker");
  }
  {
    auto request = ConfigureRequestFor(run.config, "12");
    ExpectCode(configure(request), grpc::StatusCode::INVALID_ARGUMENT, "model");
  }
  // Predict.
  auto predict = [&](esg::v1::PredictRequest request) {
    grpc::ClientContext ctx;
    esg::v1::PredictResponse r;
    return stub->PredictAttitude(&ctx, request, &r);
  };
  esg::v1::PredictRequest p;
  p.set_spacecraft_id(run.config.spacecraft_id);
  *p.mutable_from() = run.frames.back().time();
  *p.mutable_to() = run.frames.front().time();
  p.set_step_s(60);
  ExpectCode(predict(p), grpc::StatusCode::INVALID_ARGUMENT, "to:");
  std::swap(*p.mutable_from(), *p.mutable_to());
  p.set_step_s(0);
  ExpectCode(predict(p), grpc::StatusCode::INVALID_ARGUMENT, "step_s");
  p.set_step_s(-1);
  ExpectCode(predict(p), grpc::StatusCode::INVALID_ARGUMENT, "step_s");
  p.set_step_s(60);
  ExpectCode(predict(p), grpc::StatusCode::FAILED_PRECONDITION, "no attitude yet");
  p.set_spacecraft_id("NOPE");
  ExpectCode(predict(p), grpc::StatusCode::NOT_FOUND, "spacecraft_id");
  p.set_spacecraft_id(run.config.spacecraft_id);
  p.add_planned_attitude()->add_q_in_b(1.0);
  ExpectCode(predict(p), grpc::StatusCode::INVALID_ARGUMENT, "planned_attitude[0].time");
  // More planned samples than a prediction may have (100 000).
  p.mutable_planned_attitude()->Reserve(100001);
  for (int i = 0; i < 100000; ++i) *p.add_planned_attitude() = p.planned_attitude(0);
  ExpectCode(predict(p), grpc::StatusCode::OUT_OF_RANGE, "planned_attitude: 100001 samples");
  p.clear_planned_attitude();
  // Sessions, history, alerts.
  {
    grpc::ClientContext ctx;
    esg::v1::GetSessionRequest get;
    get.set_spacecraft_id("NOPE");
    esg::v1::SessionInfo info;
    ExpectCode(stub->GetSession(&ctx, get, &info), grpc::StatusCode::NOT_FOUND, "spacecraft_id");
  }
  {
    grpc::ClientContext ctx;
    esg::v1::HistoryRequest h;
    h.set_spacecraft_id(run.config.spacecraft_id);
    h.set_gyro_id(7);
    esg::v1::HistoryResponse r;
    ExpectCode(stub->GetCoefficientHistory(&ctx, h, &r), grpc::StatusCode::INVALID_ARGUMENT,
               "gyro_id");
  }
  {
    grpc::ClientContext ctx;
    esg::v1::AcknowledgeRequest a;
    a.set_spacecraft_id(run.config.spacecraft_id);
    a.set_sequence(1);
    esg::v1::Alert r;
    ExpectCode(stub->AcknowledgeAlert(&ctx, a, &r), grpc::StatusCode::INVALID_ARGUMENT,
               "operator_name");
  }
  {
    grpc::ClientContext ctx;
    esg::v1::AcknowledgeRequest a;
    a.set_spacecraft_id(run.config.spacecraft_id);
    a.set_sequence(99);
    a.set_operator_name("ops");
    esg::v1::Alert r;
    ExpectCode(stub->AcknowledgeAlert(&ctx, a, &r), grpc::StatusCode::NOT_FOUND, "sequence");
  }
  {
    grpc::ClientContext ctx;
    esg::v1::AlertSubscription s;
    s.set_spacecraft_id("NOPE");
    auto reader = stub->SubscribeAlerts(&ctx, s);
    esg::v1::Alert alert;
    EXPECT_FALSE(reader->Read(&alert));
    ExpectCode(reader->Finish(), grpc::StatusCode::NOT_FOUND, "spacecraft_id");
  }
}

TEST(Service, ReconfigurationNeedsReplaceOnceTelemetryExistsAndThenReappliesTheArchive) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun& run = Run3h();
  auto configure = [&](const esg::v1::ConfigureRequest& request, esg::v1::ConfigureResponse* r) {
    grpc::ClientContext ctx;
    return stub->ConfigureSpacecraft(&ctx, request, r);
  };
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(configure(ConfigureRequestFor(run.config), &r).ok());
  std::vector<esg::v1::TelemetryFrame> part(run.frames.begin(), run.frames.begin() + 40);
  ASSERT_EQ(StreamFrames(*stub, part).acks.size(), 40u);
  ASSERT_TRUE(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(60)).ok());
  // Same configuration again: accepted, nothing changes.
  ASSERT_TRUE(configure(ConfigureRequestFor(run.config), &r).ok());
  EXPECT_FALSE(r.created());
  EXPECT_EQ(r.session().frames_applied(), 40);
  // The same model with a configuration that differs in one value (a gyro's misalignment
  // sigma; the session keeps no copy of the configuration's JSON to compare with): refused
  // without replace.
  auto retuned = ConfigureRequestFor(run.config);
  ASSERT_GT(retuned.config().gyros_size(), 0);
  retuned.mutable_config()->mutable_gyros(0)->set_misalignment_sigma_arcsec(
      retuned.config().gyros(0).misalignment_sigma_arcsec() + 1.0);
  ExpectCode(configure(retuned, &r), grpc::StatusCode::FAILED_PRECONDITION, "replace");
  // A different model without replace: refused; with replace: the archive is applied again.
  auto changed = ConfigureRequestFor(run.config, "1+11");
  ExpectCode(configure(changed, &r), grpc::StatusCode::FAILED_PRECONDITION, "replace");
  changed.set_replace(true);
  ASSERT_TRUE(configure(changed, &r).ok());
  EXPECT_EQ(r.session().model(), "1+11");
  ASSERT_TRUE(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(60)).ok());
  grpc::ClientContext ctx;
  esg::v1::GetSessionRequest get;
  get.set_spacecraft_id(run.config.spacecraft_id);
  esg::v1::SessionInfo info;
  ASSERT_TRUE(stub->GetSession(&ctx, get, &info).ok());
  EXPECT_EQ(info.frames_applied(), 40);
  EXPECT_EQ(info.highest_applied_sequence(), 40);
  EXPECT_EQ(info.frames_accepted(), 40);
}

TEST(Service, PredictionReturnsTheEnvelopeAndAValidAem) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun& run = Run3h();
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
  ASSERT_EQ(StreamFrames(*stub, run.frames).acks.size(), run.frames.size());
  ASSERT_TRUE(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(60)).ok());

  const int64_t last_s = run.frames.back().time().seconds();
  esg::v1::PredictRequest p;
  p.set_spacecraft_id(run.config.spacecraft_id);
  p.mutable_from()->set_seconds(last_s + 60);
  p.mutable_to()->set_seconds(last_s + 3600);
  p.set_step_s(60);
  p.add_times()->set_seconds(last_s + 90);
  p.set_aem(true);
  esg::v1::PredictResponse response;
  grpc::ClientContext ctx2;
  ASSERT_TRUE(stub->PredictAttitude(&ctx2, p, &response).ok());
  ASSERT_EQ(response.samples_size(), 61);  // 60 grid points + 1 explicit epoch
  double previous_sigma = 0;
  for (int i = 0; i < response.samples_size(); ++i) {
    const esg::v1::AttitudeSample& s = response.samples(i);
    ASSERT_EQ(s.q_in_b_size(), 4);
    EXPECT_GE(s.q_in_b(0), 0.0);
    EXPECT_NEAR(std::hypot(std::hypot(s.q_in_b(0), s.q_in_b(1)), std::hypot(s.q_in_b(2), s.q_in_b(3))),
                1.0, 1e-12);
    ASSERT_EQ(s.sigma_arcsec_size(), 3);
    EXPECT_GT(s.sigma_arcsec(0), 0.0);
    EXPECT_GE(s.spin_axes_size(), 2);
    EXPECT_EQ(s.spin_axes(0).gyro_id(), 1);  // working pair first
    if (i > 0) EXPECT_LT(response.samples(i - 1).time().seconds(), s.time().seconds());
    previous_sigma = s.sigma_arcsec(0);
  }
  EXPECT_GT(previous_sigma, response.samples(0).sigma_arcsec(0));  // the envelope grows
  auto aem = storage::ParseAem(response.aem_text());
  ASSERT_TRUE(aem.ok()) << aem.status() << "\n" << response.aem_text();
  ASSERT_EQ(aem->segments.size(), 1u);
  EXPECT_EQ(aem->segments[0].metadata.at("OBJECT_NAME"), run.config.spacecraft_id);
  ASSERT_EQ(aem->segments[0].samples.size(), 61u);
  const esg::v1::AttitudeSample& s0 = response.samples(0);
  const Eigen::Quaterniond q0(s0.q_in_b(0), s0.q_in_b(1), s0.q_in_b(2), s0.q_in_b(3));
  EXPECT_LT(q0.angularDistance(aem->segments[0].samples[0].q_in_b), 1e-12);

  // A planned attitude: the predicted attitude follows it (slerp between samples).
  esg::v1::PredictRequest planned;
  planned.set_spacecraft_id(run.config.spacecraft_id);
  planned.add_times()->set_seconds(last_s + 1800);
  const Eigen::Quaterniond qa = Eigen::Quaterniond(0.9, 0.1, -0.3, 0.2).normalized();
  const Eigen::Quaterniond qb = Eigen::Quaterniond(0.7, 0.5, 0.1, -0.2).normalized();
  for (auto [t, q] : {std::pair{last_s + 60, qa}, std::pair{last_s + 3540, qb}}) {
    esg::v1::AttitudeSample* a = planned.add_planned_attitude();
    a->mutable_time()->set_seconds(t);
    for (double v : {q.w(), q.x(), q.y(), q.z()}) a->add_q_in_b(v);
  }
  grpc::ClientContext ctx3;
  ASSERT_TRUE(stub->PredictAttitude(&ctx3, planned, &response).ok());
  ASSERT_EQ(response.samples_size(), 1);
  const auto& ps = response.samples(0);
  const Eigen::Quaterniond got(ps.q_in_b(0), ps.q_in_b(1), ps.q_in_b(2), ps.q_in_b(3));
  EXPECT_LT(got.angularDistance(qa.slerp(0.5, qb)), 1e-9);
  // Beyond the horizon.
  p.mutable_to()->set_seconds(last_s + 72 * 3600);
  p.set_aem(false);
  grpc::ClientContext ctx4;
  ExpectCode(stub->PredictAttitude(&ctx4, p, &response), grpc::StatusCode::OUT_OF_RANGE, "to:");
}

TEST(Service, RandomlyCorruptedFramesNeverStopTheServer) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun& run = Run3h();
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
  std::mt19937_64 rng(42);
  const double specials[] = {std::nan(""), INFINITY, -INFINITY, 1e300, -1e-300, 0.0, -1.0, 2.0};
  std::vector<esg::v1::TelemetryFrame> frames;
  for (int i = 0; i < 400; ++i) {
    esg::v1::TelemetryFrame f = run.frames[rng() % run.frames.size()];
    switch (rng() % 8) {
      case 0:
        f.mutable_gyros(rng() % f.gyros_size())->set_h_k(rng() % 3, specials[rng() % 8]);
        break;
      case 1:
        f.mutable_gyros(rng() % f.gyros_size())->set_gyro_id(static_cast<int>(rng() % 11) - 5);
        break;
      case 2:
        f.mutable_star_tracker()->add_q_in_b(specials[rng() % 8]);
        break;
      case 3:
        f.mutable_time()->set_seconds(static_cast<int64_t>(rng() % 400000000000ULL) - 100000000000LL);
        f.mutable_time()->set_nanos(static_cast<int32_t>(rng() % 2000000000ULL) - 500000000);
        break;
      case 4:
        f.set_sequence(static_cast<int64_t>(rng()));
        break;
      case 5:
        f.mutable_gyros(rng() % f.gyros_size())->add_u_k_mv(specials[rng() % 8]);
        break;
      case 6:
        f.clear_gyros();
        break;
      default:
        f.set_spacecraft_id(rng() % 2 ? "" : std::string(1000, 'x'));
        break;
    }
    frames.push_back(f);
  }
  auto result = StreamFrames(*stub, frames);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  EXPECT_EQ(result.acks.size(), frames.size());  // every frame answered
  // Whatever was accepted is applied, and the server still answers.
  ASSERT_TRUE(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(60)).ok());
  grpc::ClientContext ctx2;
  esg::v1::ListSessionsResponse sessions;
  ASSERT_TRUE(stub->ListSessions(&ctx2, {}, &sessions).ok());
  ASSERT_EQ(sessions.sessions_size(), 1);
  // Every accepted frame applies: nothing malformed got past ingest.
  EXPECT_EQ(sessions.sessions(0).frames_apply_failed(), 0);
  EXPECT_EQ(sessions.sessions(0).frames_applied(), sessions.sessions(0).frames_accepted());
  // A clean stream afterwards is applied: the frames after the last accepted one, from a
  // station of their own (the corruption may have left any sequence on the default station).
  const esg::v1::SessionInfo before = sessions.sessions(0);
  // The run's first 20 frames, moved to start a minute after the last accepted one.
  std::vector<esg::v1::TelemetryFrame> clean;
  const int64_t shift_s =
      before.last_frame_time().seconds() + 60 - run.frames.front().time().seconds();
  for (int i = 0; i < 20; ++i) {
    clean.push_back(run.frames[i]);
    clean.back().mutable_time()->set_seconds(run.frames[i].time().seconds() + shift_s);
    clean.back().set_sequence(i + 1);
    clean.back().set_station_id("clean");
  }
  ASSERT_FALSE(clean.empty());
  auto tail = StreamFrames(*stub, clean);
  ASSERT_TRUE(tail.status.ok()) << tail.status.error_message();
  for (const esg::v1::TelemetryAck& ack : tail.acks) EXPECT_TRUE(ack.accepted()) << ack.DebugString();
  ASSERT_TRUE(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(60)).ok());
  grpc::ClientContext ctx3;
  ASSERT_TRUE(stub->ListSessions(&ctx3, {}, &sessions).ok());
  EXPECT_EQ(sessions.sessions(0).frames_applied(),
            before.frames_applied() + static_cast<int64_t>(clean.size()));
  EXPECT_EQ(sessions.sessions(0).frames_apply_failed(), 0);
}

// Collects the alerts of one SubscribeAlerts call until cancelled.
class AlertCollector {
 public:
  AlertCollector(esg::v1::EstimationService::Stub& stub, const std::string& id,
                 std::optional<int64_t> since_s) {
    esg::v1::AlertSubscription s;
    s.set_spacecraft_id(id);
    if (since_s.has_value()) s.mutable_since()->set_seconds(*since_s);
    reader_ = stub.SubscribeAlerts(&context_, s);
    thread_ = std::thread([this] {
      esg::v1::Alert a;
      while (reader_->Read(&a)) {
        absl::MutexLock lock(&mu_);
        alerts_.push_back(a);
      }
    });
  }
  // Waits (up to 20 s) until the latest state received of every alert equals `expected`.
  void WaitFor(const std::map<int64_t, esg::v1::Alert>& expected) {
    const absl::Time deadline = absl::Now() + absl::Seconds(20);
    while (absl::Now() < deadline) {
      {
        absl::MutexLock lock(&mu_);
        std::map<int64_t, esg::v1::Alert> last;
        for (const auto& a : alerts_) last[a.sequence()] = a;
        if (last.size() == expected.size() &&
            std::all_of(expected.begin(), expected.end(), [&](const auto& e) {
              const esg::v1::Alert& got = last[e.first];
              return got.repeat_count() == e.second.repeat_count() &&
                     got.acknowledged() == e.second.acknowledged() &&
                     got.cleared() == e.second.cleared();
            })) {
          return;
        }
      }
      absl::SleepFor(absl::Milliseconds(5));
    }
  }
  std::vector<esg::v1::Alert> Stop() {
    context_.TryCancel();
    thread_.join();
    reader_->Finish();
    absl::MutexLock lock(&mu_);
    return alerts_;
  }

 private:
  grpc::ClientContext context_;
  std::unique_ptr<grpc::ClientReader<esg::v1::Alert>> reader_;
  std::thread thread_;
  absl::Mutex mu_;
  std::vector<esg::v1::Alert> alerts_;
};

// Waits until the server holds exactly `n` alert subscriptions (a subscription reaches the server
// asynchronously after the client starts the call).
void WaitForSubscribers(EstimationCore& core, int n) {
  const absl::Time deadline = absl::Now() + absl::Seconds(20);
  while (core.alert_hub().size() != n && absl::Now() < deadline) {
    absl::SleepFor(absl::Milliseconds(2));
  }
  ASSERT_EQ(core.alert_hub().size(), n);
}

std::map<int64_t, esg::v1::Alert> Stored(EstimationCore& core, const std::string& id) {
  std::map<int64_t, esg::v1::Alert> out;
  auto records = core.storage().alerts().Since(id, absl::InfinitePast(), 100000);
  EXPECT_TRUE(records.ok()) << records.status();
  for (const auto& r : *records) out[r.sequence] = AlertToProto(r);
  return out;
}

TEST(Service, AlertSubscribersGetEveryAlertStateExactlyOnceAcrossReconnects) {
  LoopbackServer server;
  auto stub = server.Stub();
  // Star-tracker outliers raise alerts (eq. (12), (14)).
  const SimulatedRun run = SimulateRun("ALR-1", 3.0, 5, /*outlier_probability=*/0.08);
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());

  AlertCollector live(*stub, "", std::nullopt);  // all spacecraft, live only, from the start
  AlertCollector early(*stub, "ALR-1", 0);
  WaitForSubscribers(server.core(), 2);
  const size_t half = run.frames.size() / 2;
  std::vector<esg::v1::TelemetryFrame> first(run.frames.begin(), run.frames.begin() + half);
  std::vector<esg::v1::TelemetryFrame> second(run.frames.begin() + half, run.frames.end());
  ASSERT_EQ(StreamFrames(*stub, first).acks.size(), first.size());
  ASSERT_TRUE(server.core().WaitApplied("ALR-1", absl::Seconds(60)).ok());
  early.WaitFor(Stored(server.core(), "ALR-1"));
  const std::vector<esg::v1::Alert> before = early.Stop();
  // Reconnect while the second half streams: replay since the start, then live.
  std::thread streamer([&] { StreamFrames(*stub, second); });
  AlertCollector reconnected(*stub, "ALR-1", 0);
  streamer.join();
  ASSERT_TRUE(server.core().WaitApplied("ALR-1", absl::Seconds(60)).ok());
  const std::map<int64_t, esg::v1::Alert> stored = Stored(server.core(), "ALR-1");
  ASSERT_GE(stored.size(), 2u) << "the outliers should raise alerts";
  reconnected.WaitFor(stored);
  live.WaitFor(stored);
  const std::vector<esg::v1::Alert> after = reconnected.Stop();
  const std::vector<esg::v1::Alert> live_alerts = live.Stop();
  EXPECT_FALSE(before.empty());

  for (const auto* received : {&after, &live_alerts}) {
    // Every stored alert arrives; no state twice; the last state seen is the stored one.
    std::set<std::tuple<int64_t, int64_t, bool, bool>> states;
    std::map<int64_t, esg::v1::Alert> last;
    for (const esg::v1::Alert& a : *received) {
      EXPECT_EQ(a.spacecraft_id(), "ALR-1");
      EXPECT_TRUE(states.insert({a.sequence(), a.repeat_count(), a.acknowledged(), a.cleared()}).second)
          << "alert " << a.sequence() << " state sent twice";
      if (last.count(a.sequence())) {
        EXPECT_GE(a.repeat_count(), last[a.sequence()].repeat_count());
      }
      last[a.sequence()] = a;
    }
    ASSERT_EQ(last.size(), stored.size());
    for (const auto& [seq, a] : stored) {
      ASSERT_TRUE(last.count(seq)) << seq;
      EXPECT_EQ(last[seq].repeat_count(), a.repeat_count());
      EXPECT_EQ(last[seq].cleared(), a.cleared());
      // Severity follows the reason (docs/service.md "Alerts").
      const std::map<esg::v1::AlertReason, esg::v1::AlertSeverity> severity = {
          {esg::v1::ALERT_REASON_STAR_TRACKER_INNOVATION, esg::v1::ALERT_SEVERITY_WARNING},
          {esg::v1::ALERT_REASON_STAR_TRACKER_FAULT, esg::v1::ALERT_SEVERITY_DISTRESS},
          {esg::v1::ALERT_REASON_WORKING_PAIR_FAULT, esg::v1::ALERT_SEVERITY_DISTRESS},
          {esg::v1::ALERT_REASON_RESERVE_PAIR_FAULT, esg::v1::ALERT_SEVERITY_DISTRESS},
          {esg::v1::ALERT_REASON_GYRO_DATA_REJECTED, esg::v1::ALERT_SEVERITY_WARNING},
          {esg::v1::ALERT_REASON_FILTER_RESET, esg::v1::ALERT_SEVERITY_DISTRESS}};
      ASSERT_TRUE(severity.count(a.reason())) << a.reason();
      EXPECT_EQ(a.severity(), severity.at(a.reason()));
      EXPECT_FALSE(a.subsystem().empty());
    }
  }

  // Acknowledgement is recorded with the operator and streamed to subscribers.
  WaitForSubscribers(server.core(), 0);  // the earlier streams are gone
  AlertCollector watcher(*stub, "ALR-1", std::nullopt);
  WaitForSubscribers(server.core(), 1);
  grpc::ClientContext ctx2;
  esg::v1::AcknowledgeRequest ack;
  ack.set_spacecraft_id("ALR-1");
  ack.set_sequence(stored.begin()->first);
  ack.set_operator_name("duty-officer");
  esg::v1::Alert acked;
  ASSERT_TRUE(stub->AcknowledgeAlert(&ctx2, ack, &acked).ok());
  EXPECT_TRUE(acked.acknowledged());
  EXPECT_EQ(acked.acknowledged_by(), "duty-officer");
  EXPECT_TRUE(acked.has_acknowledged_time());
  watcher.WaitFor({{acked.sequence(), acked}});
  const std::vector<esg::v1::Alert> watched = watcher.Stop();
  ASSERT_EQ(watched.size(), 1u);
  EXPECT_TRUE(watched[0].acknowledged());
  EXPECT_EQ(watched[0].sequence(), stored.begin()->first);
}

}  // namespace
}  // namespace esg::server
