// Per-spacecraft isolation (docs/service.md "Session states"): a checkpoint that cannot be used
// (corrupt, missing, ahead of the archive, of an unknown estimator version) or a configuration
// that cannot be used quarantines that spacecraft only; the session is rebuilt from the archive
// where possible, without writing its coefficient history twice, and the others and the server
// run on. Checkpoints of the older server format and of a session that was never initialised
// restore without quarantine.
#include <chrono>
#include <cmath>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "estimator/calibration_model.h"
#include "estimator/session.h"
#include "fuzz/next_frame.h"
#include "proto/convert.h"
#include "server/checkpoint_codec.h"
#include "storage/storage.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/run_process.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::LoopbackServer;
using ::esg::testing::OfflineSessionValues;
using ::esg::testing::Session;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StoredSessionValues;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;

const SimulatedRun& RunA() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("QA-1", 1.5, 31));
  return *run;
}
const SimulatedRun& RunB() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("QB-1", 1.5, 32));
  return *run;
}

// Both spacecraft configured and their whole runs applied, then the server stopped.
void Populate(const std::string& db) {
  LoopbackServer server({}, db);
  auto stub = server.Stub();
  for (const SimulatedRun* run : {&RunA(), &RunB()}) {
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run->config), &r).ok());
    ASSERT_EQ(StreamFrames(*stub, run->frames).acks.size(), run->frames.size());
    ASSERT_TRUE(server.core().WaitApplied(run->config.spacecraft_id, absl::Seconds(60)).ok());
  }
}

// Runs `sql` on the stopped server's database.
void Tamper(const std::string& db, const std::string& sql) {
  auto storage = storage::Storage::Open(db);
  ASSERT_TRUE(storage.ok()) << storage.status();
  ASSERT_TRUE((*storage)->database().Execute(sql).ok()) << sql;
}

// Replaces the stored checkpoint blob of `id` by `blob`.
void PutBlob(const std::string& db, const std::string& id, const std::string& blob,
             int64_t last_sequence) {
  auto storage = storage::Storage::Open(db);
  ASSERT_TRUE(storage.ok()) << storage.status();
  auto record = (*storage)->sessions().GetCheckpoint(id);
  ASSERT_TRUE(record.ok()) << record.status();
  record->state_blob = blob;
  record->last_sequence = last_sequence;
  ASSERT_TRUE((*storage)->sessions().PutCheckpoint(*record).ok());
}

struct Effects {
  size_t coefficients = 0;
  std::vector<storage::AlertRecord> alerts;
};
Effects StoredEffects(const std::string& db, const std::string& id) {
  Effects e;
  auto storage = storage::Storage::Open(db);
  EXPECT_TRUE(storage.ok()) << storage.status();
  auto history =
      (*storage)->coefficients().History(id, 0, absl::InfinitePast(), absl::InfiniteFuture());
  EXPECT_TRUE(history.ok());
  e.coefficients = history->size();
  auto alerts = (*storage)->alerts().Since(id, absl::InfinitePast(), 1000);
  EXPECT_TRUE(alerts.ok());
  e.alerts = *alerts;
  return e;
}

// After a restart on a tampered database: A is quarantined and rebuilt, B is untouched; both end
// exactly where an uninterrupted offline run ends, and A's history is not written twice.
void ExpectRebuiltAndIsolated(const std::string& db, const std::string& why) {
  const Effects before = StoredEffects(db, "QA-1");
  {
    LoopbackServer server({}, db);
    ASSERT_NE(server.get(), nullptr) << "the server must start";
    auto stub = server.Stub();
    ASSERT_TRUE(server.core().WaitApplied("QA-1", absl::Seconds(60)).ok());
    ASSERT_TRUE(server.core().WaitApplied("QB-1", absl::Seconds(60)).ok());
    const esg::v1::SessionInfo a = Session(*stub, "QA-1");
    EXPECT_NE(a.state(), esg::v1::SESSION_STATE_QUARANTINED) << a.quarantine_reason();
    EXPECT_TRUE(a.quarantine_reason().empty());
    EXPECT_EQ(a.frames_applied(), static_cast<int64_t>(RunA().frames.size()));
    EXPECT_NE(Session(*stub, "QB-1").state(), esg::v1::SESSION_STATE_QUARANTINED);
  }
  EXPECT_EQ(StoredSessionValues(db, "QA-1"),
            OfflineSessionValues(RunA().config, "10+11", RunA().frames));
  EXPECT_EQ(StoredSessionValues(db, "QB-1"),
            OfflineSessionValues(RunB().config, "10+11", RunB().frames));
  const Effects after = StoredEffects(db, "QA-1");
  EXPECT_EQ(after.coefficients, before.coefficients) << "coefficient history written twice";
  // One quarantine alert saying why, cleared once the rebuild caught up; no other new alert.
  ASSERT_EQ(after.alerts.size(), before.alerts.size() + 1);
  const storage::AlertRecord& q = after.alerts.back();
  EXPECT_EQ(q.reason, "SESSION_QUARANTINED");
  EXPECT_THAT(q.message, HasSubstr(why));
  EXPECT_THAT(q.message, HasSubstr("rebuilding"));
  EXPECT_TRUE(q.cleared);
}

TEST(Quarantine, CorruptCheckpointQuarantinesThatSpacecraftOnlyAndItIsRebuilt) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  Populate(db);
  PutBlob(db, "QA-1", "ESGSRV02 not a checkpoint", 5);
  ExpectRebuiltAndIsolated(db, "cannot be decoded");
}

TEST(Quarantine, DeletedCheckpointIsRebuiltWithoutWritingTheHistoryTwice) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  Populate(db);
  Tamper(db, "DELETE FROM checkpoints WHERE spacecraft_id = 'QA-1'");
  ExpectRebuiltAndIsolated(db, "missing");
}

TEST(Quarantine, CheckpointOfAnUnknownEstimatorVersionIsRebuilt) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  Populate(db);
  auto storage = storage::Storage::Open(db);
  ASSERT_TRUE(storage.ok());
  auto record = (*storage)->sessions().GetCheckpoint("QA-1");
  ASSERT_TRUE(record.ok());
  auto checkpoint = DecodeCheckpoint(record->state_blob);
  ASSERT_TRUE(checkpoint.ok());
  checkpoint->session->version = 99;  // a future layout of the filter state
  const std::string blob = EncodeCheckpoint(*checkpoint);
  const int64_t last = record->last_sequence;
  storage->reset();
  PutBlob(db, "QA-1", blob, last);
  ExpectRebuiltAndIsolated(db, "cannot be restored");
}

TEST(Quarantine, CheckpointAheadOfTheArchiveIsRebuiltFromWhatIsArchived) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  Populate(db);
  const std::vector<esg::v1::TelemetryFrame> kept(RunA().frames.begin(),
                                                  RunA().frames.begin() + 40);
  Tamper(db, "DELETE FROM telemetry_frames WHERE spacecraft_id = 'QA-1' AND sequence > 40");
  const Effects before = StoredEffects(db, "QA-1");
  {
    LoopbackServer server({}, db);
    auto stub = server.Stub();
    ASSERT_TRUE(server.core().WaitApplied("QA-1", absl::Seconds(60)).ok());
    EXPECT_EQ(Session(*stub, "QA-1").frames_applied(), 40);
    EXPECT_TRUE(Session(*stub, "QA-1").quarantine_reason().empty());
  }
  EXPECT_EQ(StoredSessionValues(db, "QA-1"), OfflineSessionValues(RunA().config, "10+11", kept));
  const Effects after = StoredEffects(db, "QA-1");
  EXPECT_EQ(after.coefficients, before.coefficients);
  ASSERT_FALSE(after.alerts.empty());
  EXPECT_THAT(after.alerts.back().message, HasSubstr("ahead of the archive"));
}

// The first server checkpoint format ("ESGSRV01": no apply cursor, the last applied sequence in
// the record) restores as it is: no quarantine, and the session resumes where it was.
std::string EncodeFormat1(const ServerCheckpoint& c) {
  std::string out = "ESGSRV01";
  auto i64 = [&](int64_t v) { out.append(reinterpret_cast<const char*>(&v), sizeof v); };
  auto str = [&](const std::string& s) {
    i64(static_cast<int64_t>(s.size()));
    out += s;
  };
  str(c.model);
  i64(c.frames_applied);
  i64(c.frames_apply_failed);
  i64(c.star_tracker_rejections);
  i64(static_cast<int64_t>(c.alert_tracks.size()));
  for (const AlertTrack& t : c.alert_tracks) {
    str(t.reason);
    str(t.subsystem);
    i64(t.sequence);
    i64(t.repeat_count);
    i64(absl::ToUnixNanos(t.last_time));
  }
  i64(c.session.has_value() ? 1 : 0);
  if (c.session.has_value()) {
    i64(c.session->version);
    i64(static_cast<int64_t>(c.session->values.size()));
    for (double v : c.session->values) out.append(reinterpret_cast<const char*>(&v), sizeof v);
  }
  return out;
}

TEST(Quarantine, CheckpointOfTheFirstServerFormatRestoresWithoutQuarantine) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  const SimulatedRun& run = RunA();
  const size_t half = run.frames.size() / 2;
  {
    LoopbackServer server({}, db);
    auto stub = server.Stub();
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
    std::vector<esg::v1::TelemetryFrame> first(run.frames.begin(), run.frames.begin() + half);
    ASSERT_EQ(StreamFrames(*stub, first).acks.size(), half);
    ASSERT_TRUE(server.core().WaitApplied("QA-1", absl::Seconds(60)).ok());
  }
  {
    auto storage = storage::Storage::Open(db);
    ASSERT_TRUE(storage.ok());
    auto record = (*storage)->sessions().GetCheckpoint("QA-1");
    ASSERT_TRUE(record.ok());
    auto checkpoint = DecodeCheckpoint(record->state_blob);
    ASSERT_TRUE(checkpoint.ok());
    ASSERT_EQ(record->last_sequence, static_cast<int64_t>(half));
    record->state_blob = EncodeFormat1(*checkpoint);
    ASSERT_TRUE((*storage)->sessions().PutCheckpoint(*record).ok());
  }
  {
    LoopbackServer server({}, db);
    auto stub = server.Stub();
    const esg::v1::SessionInfo info = Session(*stub, "QA-1");
    EXPECT_TRUE(info.quarantine_reason().empty()) << info.quarantine_reason();
    EXPECT_EQ(info.highest_applied_sequence(), static_cast<int64_t>(half));
    std::vector<esg::v1::TelemetryFrame> rest(run.frames.begin() + half, run.frames.end());
    ASSERT_EQ(StreamFrames(*stub, rest).acks.size(), rest.size());
    ASSERT_TRUE(server.core().WaitApplied("QA-1", absl::Seconds(60)).ok());
  }
  EXPECT_EQ(StoredSessionValues(db, "QA-1"), OfflineSessionValues(run.config, "10+11", run.frames));
  for (const storage::AlertRecord& a : StoredEffects(db, "QA-1").alerts) {
    EXPECT_NE(a.reason, "SESSION_QUARANTINED") << a.message;
  }
}

// A routine start: the first frames carry no valid star-tracker attitude, so the checkpoint is
// of an uninitialised session. Every later start must load it (it once crashed esgd for ever).
TEST(Quarantine, CheckpointOfAnUninitialisedSessionLoadsAndTheRunEqualsOffline) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  SimulatedRun run = RunA();
  for (int i = 0; i < 6; ++i) run.frames[i].clear_star_tracker();
  {
    LoopbackServer server({}, db);
    auto stub = server.Stub();
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
    std::vector<esg::v1::TelemetryFrame> first(run.frames.begin(), run.frames.begin() + 6);
    ASSERT_EQ(StreamFrames(*stub, first).acks.size(), 6u);
    ASSERT_TRUE(server.core().WaitApplied("QA-1", absl::Seconds(60)).ok());
  }
  for (int restart = 0; restart < 2; ++restart) {
    LoopbackServer server({}, db);
    ASSERT_NE(server.get(), nullptr);
    auto stub = server.Stub();
    const esg::v1::SessionInfo info = Session(*stub, "QA-1");
    EXPECT_TRUE(info.quarantine_reason().empty()) << info.quarantine_reason();
    EXPECT_EQ(info.frames_applied(), 6);
  }
  {
    LoopbackServer server({}, db);
    auto stub = server.Stub();
    std::vector<esg::v1::TelemetryFrame> rest(run.frames.begin() + 6, run.frames.end());
    ASSERT_EQ(StreamFrames(*stub, rest).acks.size(), rest.size());
    ASSERT_TRUE(server.core().WaitApplied("QA-1", absl::Seconds(60)).ok());
  }
  EXPECT_EQ(StoredSessionValues(db, "QA-1"), OfflineSessionValues(run.config, "10+11", run.frames));
}

// The configuration of the checkpoint fuzz target's blobs as the target sets it
// (fuzz/fuzz_checkpoint.cc): deploy/examples/rdk1.json propagated at 1 Hz, so a frame given to a
// restored session is propagated as the fuzzer propagated it.
const estimator::SpacecraftConfig& Rdk1() {
  static const estimator::SpacecraftConfig* config = [] {
    absl::StatusOr<estimator::SpacecraftConfig> c =
        proto_convert::ReadConfigFile(ESG_SOURCE_DIR "/deploy/examples/rdk1.json");
    EXPECT_TRUE(c.ok()) << c.status();
    if (c.ok()) c->filter.integration_rate_hz = 1.0;
    return new estimator::SpacecraftConfig(c.ok() ? *c : estimator::SpacecraftConfig{});
  }();
  return *config;
}

// A checkpoint blob of fuzz/corpus/checkpoint/ restored as esgd restores a spacecraft of
// rdk1.json: its session under the model it names.
absl::StatusOr<estimator::EstimationSession> RestoreCorpusBlob(const std::string& name,
                                                               estimator::SessionOptions* options) {
  std::ifstream in(ESG_SOURCE_DIR "/fuzz/corpus/checkpoint/" + name, std::ios::binary);
  if (!in.good()) return absl::NotFoundError(name);
  const std::string blob((std::istreambuf_iterator<char>(in)), {});
  absl::StatusOr<ServerCheckpoint> decoded = DecodeCheckpoint(blob);
  if (!decoded.ok()) return decoded.status();
  if (!decoded->session.has_value()) return absl::InvalidArgumentError("no session in " + name);
  absl::StatusOr<estimator::ModelSpec> model = estimator::ParseModel(decoded->model);
  if (!model.ok()) return model.status();
  options->model = *model;
  return estimator::EstimationSession::FromCheckpoint(Rdk1(), *options, *decoded->session);
}

// Found by fuzz/fuzz_checkpoint.cc (docs/fuzzing.md, finding 3): this blob (a version-1 session
// of deploy/examples/rdk1.json whose initial covariance has a zero diagonal entry) restored, and
// after one frame the session's own checkpoint did not. It must be DataLoss at the restore, so
// esgd quarantines and rebuilds the spacecraft instead of running on with it.
TEST(Quarantine, CheckpointWithAZeroInitialVarianceIsRefusedAtTheRestore) {
  estimator::SessionOptions options;
  const absl::Status restored =
      RestoreCorpusBlob("regression-zero-initial-variance.bin", &options).status();
  EXPECT_EQ(restored.code(), absl::StatusCode::kDataLoss) << restored;
  EXPECT_THAT(std::string(restored.message()), HasSubstr("initial covariance diagonal"));
}

// Found by fuzz/fuzz_checkpoint.cc (docs/fuzzing.md, finding 7): a coefficient's P/P0
// overflowed, and sqrt(P/P0) = inf went into the session's own checkpoint after one frame, which
// then did not restore. In blobs a and b the tiny P0 entry is subnormal, which no configuration
// gives (ValidateConfig): DataLoss at the restore, so esgd quarantines and rebuilds.
TEST(Quarantine, CheckpointWithASubnormalInitialVarianceIsRefusedAtTheRestore) {
  for (const char* name : {"regression-relative-sigma-overflow-a.bin",
                           "regression-relative-sigma-overflow-b.bin"}) {
    estimator::SessionOptions options;
    const absl::Status restored = RestoreCorpusBlob(name, &options).status();
    EXPECT_EQ(restored.code(), absl::StatusCode::kDataLoss) << name << ": " << restored;
    EXPECT_THAT(std::string(restored.message()), HasSubstr("not a positive normal number")) << name;
  }
}

// Finding 7, blob c, found by the long run against the first fix, which refused a checkpoint with
// P/P0 not finite on any diagonal entry: P0 is normal (1.7e-307) and every P/P0 finite at the
// restore, and the next frame's propagation raised a spin-axis variance to 1.6e31, so P/P0
// overflowed on that state (where no relative sigma is formed) and the first fix refused the
// session's own checkpoint. The blob restores, every relative sigma stays finite, and after the
// frame the fuzz target gives it (a failed step is a status) the session's own checkpoint
// restores.
TEST(Quarantine, CheckpointWithATinyNormalInitialVarianceStaysRestorableAfterAFrame) {
  estimator::SessionOptions options;
  absl::StatusOr<estimator::EstimationSession> s =
      RestoreCorpusBlob("regression-relative-sigma-overflow-c.bin", &options);
  ASSERT_TRUE(s.ok()) << s.status();
  (void)s->AddFrame(fuzz::NextFrame(*s, Rdk1()));
  int ratios = 0;
  for (const estimator::GyroConfig& g : Rdk1().gyros) {
    for (const auto& [coefficient, ratio] : s->RelativeSigma(g.id)) {
      EXPECT_TRUE(std::isfinite(ratio)) << "gyro " << g.id << " coefficient " << coefficient;
      ++ratios;
    }
  }
  EXPECT_GT(ratios, 0);
  const absl::StatusOr<estimator::EstimationSession> again =
      estimator::EstimationSession::FromCheckpoint(Rdk1(), options, s->ExportCheckpoint());
  EXPECT_TRUE(again.ok()) << again.status();
}

// Found by fuzz/fuzz_checkpoint.cc (docs/fuzzing.md, finding 9): a checkpoint that restores,
// whose next frame moves a gyro's track by about 1e149 rad/s; the reading-fault monitor's
// verdict "beyond the drift bound" is right, but its chi-square overflowed to inf, the session
// kept it as the gyro's reading verdict, and its own checkpoint, which refuses a non-finite real,
// did not restore. The verdict's figures now saturate at the largest double.
TEST(Quarantine, AReadingVerdictWhoseStatisticOverflowsLeavesARestorableCheckpoint) {
  estimator::SessionOptions options;
  absl::StatusOr<estimator::EstimationSession> s =
      RestoreCorpusBlob("regression-rate-change-overflow.bin", &options);
  ASSERT_TRUE(s.ok()) << s.status();
  (void)s->AddFrame(fuzz::NextFrame(*s, Rdk1()));
  const estimator::SessionCheckpoint after = s->ExportCheckpoint();
  for (size_t i = 0; i < after.values.size(); ++i) {
    ASSERT_TRUE(std::isfinite(after.values[i])) << "value " << i;
  }
  const absl::StatusOr<estimator::EstimationSession> again =
      estimator::EstimationSession::FromCheckpoint(Rdk1(), options, after);
  EXPECT_TRUE(again.ok()) << again.status();
}

TEST(Quarantine, UnusableConfigurationRefusesItsFramesUntilReconfigured) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  Populate(db);
  Tamper(db,
         "UPDATE spacecraft_configs SET config_json = '{\"gyros\": 7}' "
         "WHERE spacecraft_id = 'QA-1'");
  LoopbackServer server({}, db);
  ASSERT_NE(server.get(), nullptr);
  auto stub = server.Stub();
  const esg::v1::SessionInfo a = Session(*stub, "QA-1");
  EXPECT_EQ(a.state(), esg::v1::SESSION_STATE_QUARANTINED);
  EXPECT_THAT(a.quarantine_reason(), HasSubstr("configuration cannot be used"));
  EXPECT_FALSE(a.rebuilding());
  // Its frames are refused with the reason; the other spacecraft is served.
  esg::v1::TelemetryFrame next = RunA().frames.back();
  next.set_sequence(next.sequence() + 1);
  next.mutable_time()->set_seconds(next.time().seconds() + 60);
  auto refused = StreamFrames(*stub, {next});
  ASSERT_EQ(refused.acks.size(), 1u);
  EXPECT_EQ(refused.acks[0].rejection().code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_THAT(refused.acks[0].rejection().reason(), HasSubstr("quarantined"));
  EXPECT_NE(Session(*stub, "QB-1").state(), esg::v1::SESSION_STATE_QUARANTINED);
  // A reconfiguration ends it: the archive is applied again under the new configuration.
  auto request = ConfigureRequestFor(RunA().config);
  request.set_replace(true);
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, request, &r).ok());
  ASSERT_TRUE(server.core().WaitApplied("QA-1", absl::Seconds(60)).ok());
  const esg::v1::SessionInfo fixed = Session(*stub, "QA-1");
  EXPECT_TRUE(fixed.quarantine_reason().empty());
  EXPECT_EQ(fixed.frames_applied(), static_cast<int64_t>(RunA().frames.size()));
}

// The quarantine ended by a reconfiguration clears its alert like every other clear: cleared_time
// stored (the latest archived frame at the reconfiguration), the clear published to a subscriber
// and logged. Against esgd as a process, for its log.
TEST(Quarantine, ReconfigurationClearsTheQuarantineAlertWithItsTimePublishedAndLogged) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  const std::string log = dir.File("esgd.log");
  Populate(db);
  Tamper(db,
         "UPDATE spacecraft_configs SET config_json = '{\"gyros\": 7}' "
         "WHERE spacecraft_id = 'QA-1'");
  const absl::Time last_frame = *proto_convert::TimeFromProto(RunA().frames.back().time());
  int64_t sequence = 0;
  {
    esg::testing::Daemon daemon(db, log);
    ASSERT_GT(daemon.port(), 0);
    auto stub = daemon.Stub();
    ASSERT_EQ(Session(*stub, "QA-1").state(), esg::v1::SESSION_STATE_QUARANTINED);
    // Stored alerts, the marker, then live changes.
    grpc::ClientContext watch;
    watch.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    esg::v1::AlertSubscription subscription;
    subscription.set_spacecraft_id("QA-1");
    *subscription.mutable_since() = proto_convert::TimeToProto(absl::UnixEpoch());
    subscription.set_replay_marker(true);
    auto reader = stub->SubscribeAlerts(&watch, subscription);
    esg::v1::Alert alert;
    while (reader->Read(&alert) && !alert.replay_complete()) {
    }
    ASSERT_TRUE(alert.replay_complete());
    auto request = ConfigureRequestFor(RunA().config);
    request.set_replace(true);
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, request, &r).ok());
    // The quarantine alert's clear is published (raised and cleared at once if the first job had
    // not stored it before the reconfiguration).
    esg::v1::Alert cleared;
    for (int i = 0; i < 1000 && !(cleared.reason() == esg::v1::ALERT_REASON_SESSION_QUARANTINED &&
                                  cleared.cleared());
         ++i) {
      ASSERT_TRUE(reader->Read(&cleared)) << "the alert stream ended";
    }
    ASSERT_TRUE(cleared.has_cleared_time());
    EXPECT_EQ(*proto_convert::TimeFromProto(cleared.cleared_time()), last_frame);
    EXPECT_THAT(cleared.message(), HasSubstr("configuration cannot be used"));
    sequence = cleared.sequence();
    watch.TryCancel();
    reader->Finish();
  }
  auto storage = storage::Storage::Open(db);
  ASSERT_TRUE(storage.ok()) << storage.status();
  auto stored = (*storage)->alerts().Get("QA-1", sequence);
  ASSERT_TRUE(stored.ok()) << stored.status();
  EXPECT_EQ(stored->reason, "SESSION_QUARANTINED");
  EXPECT_TRUE(stored->cleared);
  EXPECT_EQ(stored->cleared_time, last_frame);
  // Logged once cleared: "alert QA-1 #N DISTRESS SESSION_QUARANTINED session, x1, ..., cleared
  // at <time>: <reason>".
  const std::string text = esg::testing::ReadFile(log);
  EXPECT_THAT(text, HasSubstr(absl::StrCat("INFO esgd: alert QA-1 #", sequence,
                                           " DISTRESS SESSION_QUARANTINED session, x1, ")));
  EXPECT_THAT(text, HasSubstr(absl::StrCat(", cleared at ", FormatUtc(last_frame),
                                           ": the stored configuration cannot be used")));
}

}  // namespace
}  // namespace esg::server
