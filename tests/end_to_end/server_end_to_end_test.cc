// End to end through esgd (docs/service.md): simulated telemetry -> gRPC ingest -> SQLite ->
// estimation session -> coefficient history, against an offline EstimationSession over the same
// frames; recovery after kill -9 of the real daemon; 100 concurrent spacecraft streams.
#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <map>
#include <thread>

#include "estimator/basis_term.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/checkpoint_codec.h"
#include "storage/coefficient_store.h"
#include "storage/storage.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::Daemon;
using ::esg::testing::LoopbackServer;
using ::esg::testing::SimulateRun;
using ::esg::testing::SimulatedRun;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::esg::testing::TermDegH;

// The same frames through a session in this process (the filter is deterministic).
struct OfflineRun {
  std::optional<estimator::EstimationSession> session;
  int measurement_steps = 0;
};
OfflineRun RunOffline(const SimulatedRun& run, const std::string& model = "10+11") {
  OfflineRun out;
  auto spec = estimator::ParseModel(model);
  EXPECT_TRUE(spec.ok());
  auto session = estimator::EstimationSession::Create(run.config, {*spec});
  EXPECT_TRUE(session.ok()) << session.status();
  out.session = std::move(*session);
  for (const esg::v1::TelemetryFrame& proto : run.frames) {
    auto frame = proto_convert::FrameFromProto(proto);
    EXPECT_TRUE(frame.ok());
    auto report = out.session->AddFrame(*frame);
    EXPECT_TRUE(report.ok()) << report.status();
    if (report.ok() && report->measurement_step) ++out.measurement_steps;
  }
  return out;
}

esg::v1::SessionInfo GetSession(esg::v1::EstimationService::Stub& stub, const std::string& id) {
  grpc::ClientContext ctx;
  esg::v1::GetSessionRequest request;
  request.set_spacecraft_id(id);
  esg::v1::SessionInfo info;
  const grpc::Status status = stub.GetSession(&ctx, request, &info);
  EXPECT_TRUE(status.ok()) << status.error_message();
  return info;
}

std::vector<esg::v1::CoefficientSnapshot> History(esg::v1::EstimationService::Stub& stub,
                                                  const std::string& id) {
  grpc::ClientContext ctx;
  esg::v1::HistoryRequest request;
  request.set_spacecraft_id(id);
  esg::v1::HistoryResponse response;
  EXPECT_TRUE(stub.GetCoefficientHistory(&ctx, request, &response).ok());
  return {response.snapshots().begin(), response.snapshots().end()};
}

// The last snapshot of each gyro equals the offline estimate (same conversion to deg/h and
// arcsec as the store: bit for bit).
void ExpectFinalEstimatesEqualOffline(const std::vector<esg::v1::CoefficientSnapshot>& history,
                                      const OfflineRun& offline) {
  std::map<int, esg::v1::CoefficientSnapshot> last;
  for (const auto& s : history) last[s.gyro_id()] = s;
  const std::vector<estimator::GyroEstimate> gyros = offline.session->Gyros();
  ASSERT_EQ(last.size(), gyros.size());
  for (const estimator::GyroEstimate& g : gyros) {
    SCOPED_TRACE(::testing::Message() << "gyro " << g.id);
    const std::vector<double> v = storage::ToCoefficientValues(g.coefficients, g.misalignment_b);
    const std::vector<double> sigma = storage::ToCoefficientValues(g.sigma, g.misalignment_sigma_b);
    const esg::v1::CoefficientSnapshot& s = last.at(g.id);
    // Records are SI, the columns and the message deg/h and arcsec: equal up to the conversions.
    const auto deg_h = [](double x) { return estimator::RadPerSecToDegPerHour(x); };
    const auto arcsec = [](double x) { return estimator::RadToArcsec(x); };
    EXPECT_DOUBLE_EQ(TermDegH(s.model(), estimator::kThetaK0), deg_h(v[estimator::kThetaK0]));
    EXPECT_DOUBLE_EQ(TermDegH(s.sigma(), estimator::kThetaK0), deg_h(sigma[estimator::kThetaK0]));
    for (int i = 0; i < 3; ++i) {
      EXPECT_DOUBLE_EQ(TermDegH(s.model(), estimator::kThetaC1 + i),
                       deg_h(v[estimator::kThetaC1 + i]));
      EXPECT_DOUBLE_EQ(TermDegH(s.model(), estimator::kThetaC2 + i),
                       deg_h(v[estimator::kThetaC2 + i]));
      EXPECT_DOUBLE_EQ(s.misalignment_arcsec(i),
                       arcsec(v[storage::kCoefficientMisalignment + i]));
      EXPECT_DOUBLE_EQ(s.misalignment_sigma_arcsec(i),
                       arcsec(sigma[storage::kCoefficientMisalignment + i]));
    }
    // The basis terms in the configuration's units (deg/h per unit of the regressor), written
    // with 15 significant digits: equal to 1e-12 deg/h.
    ASSERT_EQ(s.basis_terms_size(), static_cast<int>(g.basis_terms.size()));
    for (int k = 0; k < s.basis_terms_size(); ++k) {
      const double to_json = estimator::BasisValueToJson(g.basis_terms[k].kind);
      EXPECT_EQ(s.basis_terms(k).kind(), estimator::BasisKindName(g.basis_terms[k].kind));
      EXPECT_NEAR(s.basis_terms(k).value_deg_h(), g.basis_terms[k].value * to_json, 1e-12) << k;
      EXPECT_NEAR(s.basis_terms(k).sigma_deg_h(), g.basis_sigma[k] * to_json, 1e-12) << k;
    }
  }
}

void ExpectAttitudeEqualsOffline(const esg::v1::SessionInfo& info, const OfflineRun& offline) {
  const estimator::ScalarFirst q = estimator::ToScalarFirst(
      estimator::Canonical(offline.session->CurrentAttitude().q_in_b));
  ASSERT_EQ(info.latest_attitude().q_in_b_size(), 4);
  for (int i = 0; i < 4; ++i) EXPECT_EQ(info.latest_attitude().q_in_b(i), q[i]);
}

TEST(EndToEnd, StreamedCalibrationEqualsAnOfflineRunExactly) {
  const SimulatedRun run = SimulateRun("E2E-1", 12.0, 21);
  LoopbackServer server;
  auto stub = server.Stub();
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse configured;
  ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &configured).ok());
  auto streamed = StreamFrames(*stub, run.frames);
  ASSERT_TRUE(streamed.status.ok()) << streamed.status.error_message();
  ASSERT_EQ(streamed.acks.size(), run.frames.size());
  ASSERT_TRUE(server.core().WaitApplied("E2E-1", absl::Seconds(120)).ok());

  const OfflineRun offline = RunOffline(run);
  const esg::v1::SessionInfo info = GetSession(*stub, "E2E-1");
  EXPECT_EQ(info.frames_applied(), static_cast<int64_t>(run.frames.size()));
  EXPECT_EQ(esg::v1::SessionState_Name(info.state()),
            std::string("SESSION_STATE_") + estimator::SessionStateName(offline.session->state()));
  ExpectAttitudeEqualsOffline(info, offline);
  const auto history = History(*stub, "E2E-1");
  EXPECT_EQ(history.size(), static_cast<size_t>(offline.measurement_steps) *
                                offline.session->Gyros().size());
  ExpectFinalEstimatesEqualOffline(history, offline);
  // Calibration did something: k0's sigma fell well below its 0.3 deg/h prior.
  EXPECT_LT(TermDegH(history.back().sigma(), estimator::kThetaK0), 0.1);
}

// A drift term beyond eq. (1), (10) configured for calibration (what `esg diagnose` adds): the
// stored history carries its estimate and 1-sigma at every step, equal to the offline session's.
TEST(EndToEnd, ACalibratedBasisTermIsInTheHistoryAndEqualsTheOfflineRun) {
  SimulatedRun run = SimulateRun("E2E-B", 4.0, 23);
  estimator::BasisTerm orbit;
  orbit.kind = estimator::BasisKind::kOrbitalHarmonic;
  orbit.axis = 1;
  orbit.period = 5400.0;
  orbit.sigma = estimator::DegPerHourToRadPerSec(0.05);
  run.config.gyros[0].basis_terms = {orbit};
  LoopbackServer server;
  auto stub = server.Stub();
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse configured;
  ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &configured).ok());
  auto streamed = StreamFrames(*stub, run.frames);
  ASSERT_TRUE(streamed.status.ok()) << streamed.status.error_message();
  ASSERT_TRUE(server.core().WaitApplied("E2E-B", absl::Seconds(120)).ok());

  const OfflineRun offline = RunOffline(run);
  const auto history = History(*stub, "E2E-B");
  ExpectFinalEstimatesEqualOffline(history, offline);
  int with_term = 0;
  for (const esg::v1::CoefficientSnapshot& s : history) {
    ASSERT_EQ(s.basis_terms_size(), s.gyro_id() == run.config.gyros[0].id ? 1 : 0);
    if (s.basis_terms_size() == 0) continue;
    ++with_term;
    EXPECT_EQ(s.basis_terms(0).kind(), "orbital_harmonic");
    EXPECT_EQ(s.basis_terms(0).period_s(), 5400.0);
  }
  EXPECT_EQ(with_term, offline.measurement_steps);
  // Calibrated, not echoed: its 1-sigma fell below the 0.05 deg/h prior.
  for (auto it = history.rbegin(); it != history.rend(); ++it) {
    if (it->basis_terms_size() == 0) continue;
    EXPECT_LT(it->basis_terms(0).sigma_deg_h(), 0.05 / 2);
    break;
  }
}

TEST(EndToEnd, KillNineMidStreamLosesNoAckedFrameAndAppliesNoneTwice) {
  const SimulatedRun run = SimulateRun("CRASH-1", 8.0, 33);
  const int64_t n = static_cast<int64_t>(run.frames.size());
  TempDir dir;
  const std::string db = dir.File("var/esg.db");
  const std::string log = dir.File("esgd.log");
  int64_t acked_durable = 0;
  {
    Daemon daemon(db, log);
    ASSERT_GT(daemon.port(), 0);
    auto stub = daemon.Stub();
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
    // Stream everything; kill -9 once half of the frames are acknowledged.
    grpc::ClientContext stream_ctx;
    auto stream = stub->StreamTelemetry(&stream_ctx);
    std::atomic<int64_t> acks{0};
    std::atomic<int64_t> durable{0};
    std::thread reader([&] {
      esg::v1::TelemetryAck ack;
      while (stream->Read(&ack)) {
        EXPECT_TRUE(ack.accepted());
        durable = std::max<int64_t>(durable, ack.highest_durable_sequence());
        ++acks;
      }
    });
    std::thread writer([&] {
      for (const auto& f : run.frames) {
        if (!stream->Write(f)) break;
        if (f.sequence() % 4 == 0) absl::SleepFor(absl::Milliseconds(2));  // keep it mid-stream
      }
      stream->WritesDone();
    });
    const absl::Time give_up = absl::Now() + absl::Seconds(60);
    while (acks < n / 2 && absl::Now() < give_up) absl::SleepFor(absl::Microseconds(200));
    daemon.Stop(SIGKILL);
    writer.join();
    reader.join();
    stream->Finish();
    acked_durable = durable;
    ASSERT_GE(acked_durable, n / 2);
    ASSERT_LT(acked_durable, n) << "the kill came too late to test anything";
  }
  // Restart on the same database and resume from the last acknowledged durable sequence.
  Daemon daemon(db, log);
  ASSERT_GT(daemon.port(), 0);
  auto stub = daemon.Stub();
  esg::v1::SessionInfo info = GetSession(*stub, "CRASH-1");
  EXPECT_GE(info.highest_durable_sequence(), acked_durable);  // no acknowledged frame lost
  EXPECT_EQ(info.frames_accepted(), info.highest_durable_sequence());
  const int64_t durable_after_restart = info.highest_durable_sequence();
  std::vector<esg::v1::TelemetryFrame> rest(run.frames.begin() + acked_durable, run.frames.end());
  auto resumed = StreamFrames(*stub, rest);
  ASSERT_TRUE(resumed.status.ok()) << resumed.status.error_message();
  ASSERT_EQ(resumed.acks.size(), rest.size());
  int64_t duplicates = 0;
  for (const auto& ack : resumed.acks) {
    EXPECT_TRUE(ack.accepted());
    duplicates += ack.duplicate() ? 1 : 0;
  }
  EXPECT_EQ(duplicates, durable_after_restart - acked_durable);
  for (int i = 0; i < 6000; ++i) {  // at most 60 s
    info = GetSession(*stub, "CRASH-1");
    if (info.highest_applied_sequence() == n) break;
    absl::SleepFor(absl::Milliseconds(10));
  }
  EXPECT_EQ(info.highest_applied_sequence(), n);
  EXPECT_EQ(info.frames_accepted(), n);  // archive count
  EXPECT_EQ(info.frames_applied(), n);   // each frame applied exactly once across the crash

  // Final estimates equal an uninterrupted run; one snapshot per step and gyro (no replayed
  // step stored twice).
  const OfflineRun offline = RunOffline(run);
  ExpectAttitudeEqualsOffline(info, offline);
  const auto history = History(*stub, "CRASH-1");
  EXPECT_EQ(history.size(), static_cast<size_t>(offline.measurement_steps) *
                                offline.session->Gyros().size());
  ExpectFinalEstimatesEqualOffline(history, offline);
}

TEST(EndToEnd, SigtermDrainsTheBacklogAndLeavesACheckpointOfEveryAckedFrame) {
  const SimulatedRun run = SimulateRun("TERM-1", 6.0, 44);
  const int64_t n = static_cast<int64_t>(run.frames.size());
  TempDir dir;
  const std::string db = dir.File("var/esg.db");
  {
    Daemon daemon(db, dir.File("esgd.log"));
    ASSERT_GT(daemon.port(), 0);
    auto stub = daemon.Stub();
    {
      grpc::ClientContext ctx;
      esg::v1::ConfigureResponse r;
      ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
    }
    auto streamed = StreamFrames(*stub, run.frames);
    ASSERT_EQ(streamed.acks.size(), run.frames.size());
    // A client channel still open with just-finished calls keeps gRPC's shutdown waiting for its
    // deadline (5 s); close it, then stop right after the last ack: the filter may be behind.
    stub.reset();
    daemon.Stop(SIGTERM);
  }
  // The daemon is gone; its database holds every frame and a checkpoint after the last one.
  auto storage = storage::Storage::Open(db);
  ASSERT_TRUE(storage.ok()) << storage.status();
  auto checkpoint = (*storage)->sessions().GetCheckpoint("TERM-1");
  ASSERT_TRUE(checkpoint.ok()) << checkpoint.status();
  EXPECT_EQ(checkpoint->last_sequence, n);
  auto highest = (*storage)->archive().HighestSequence("TERM-1");
  ASSERT_TRUE(highest.ok());
  EXPECT_EQ(highest->value_or(0), n);
  auto server_checkpoint = DecodeCheckpoint(checkpoint->state_blob);
  ASSERT_TRUE(server_checkpoint.ok()) << server_checkpoint.status();
  EXPECT_EQ(server_checkpoint->frames_applied, n);
  ASSERT_TRUE(server_checkpoint->session.has_value());
  // The checkpoint is the uninterrupted run's state, value for value.
  const OfflineRun offline = RunOffline(run);
  const estimator::SessionCheckpoint expected = offline.session->ExportCheckpoint();
  EXPECT_EQ(server_checkpoint->session->values, expected.values);
}

TEST(EndToEnd, HundredConcurrentSpacecraftStreamsAreAllAckedAndArchived) {
  constexpr int kSpacecraft = 100;
  const SimulatedRun run = SimulateRun("LOAD", 59.0 / 60.0, 3);  // 60 frames
  ASSERT_EQ(run.frames.size(), 60u);
  LoopbackServer server;
  auto stub = server.Stub();
  for (int s = 0; s < kSpacecraft; ++s) {
    estimator::SpacecraftConfig config = run.config;
    config.spacecraft_id = "LOAD-" + std::to_string(s);
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(config), &r).ok());
  }
  std::vector<std::thread> clients;
  std::vector<esg::testing::StreamResult> results(kSpacecraft);
  for (int s = 0; s < kSpacecraft; ++s) {
    clients.emplace_back([&, s] {
      std::vector<esg::v1::TelemetryFrame> frames = run.frames;
      for (auto& f : frames) f.set_spacecraft_id("LOAD-" + std::to_string(s));
      auto own_stub = server.Stub();  // its own channel: a separate ground station
      results[s] = StreamFrames(*own_stub, frames);
    });
  }
  for (auto& t : clients) t.join();
  for (int s = 0; s < kSpacecraft; ++s) {
    SCOPED_TRACE(s);
    ASSERT_TRUE(results[s].status.ok()) << results[s].status.error_message();
    ASSERT_EQ(results[s].acks.size(), 60u);
    for (const auto& ack : results[s].acks) ASSERT_TRUE(ack.accepted() && !ack.duplicate());
    EXPECT_EQ(results[s].acks.back().highest_durable_sequence(), 60);
  }
  for (int s = 0; s < kSpacecraft; ++s) {
    const std::string id = "LOAD-" + std::to_string(s);
    ASSERT_TRUE(server.core().WaitApplied(id, absl::Seconds(120)).ok());
    const esg::v1::SessionInfo info = GetSession(*stub, id);
    EXPECT_EQ(info.frames_accepted(), 60);
    EXPECT_EQ(info.frames_applied(), 60);
  }
  // Every session saw the same frames: identical estimates.
  const esg::v1::SessionInfo first = GetSession(*stub, "LOAD-0");
  const esg::v1::SessionInfo last = GetSession(*stub, "LOAD-99");
  ASSERT_EQ(first.latest_attitude().q_in_b_size(), 4);
  for (int i = 0; i < 4; ++i) {
    EXPECT_EQ(first.latest_attitude().q_in_b(i), last.latest_attitude().q_in_b(i));
  }
}

}  // namespace
}  // namespace esg::server
