// The alert lifecycle (docs/service.md "Alerts"), against a real esgd on loopback: the
// end-of-replay marker of SubscribeAlerts, a second acknowledgement, the cleared time; the
// collapser's clearing rules; and the alert catalog (server/alert_catalog.h) against the proto
// enum, the proto comments and the docs table.
#include <chrono>
#include <filesystem>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <tuple>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"
#include "esg/v1/estimation_service.grpc.pb.h"
#include "gmock/gmock.h"
#include "grpcpp/client_context.h"
#include "gtest/gtest.h"
#include "proto/convert.h"
#include "server/alert_catalog.h"
#include "server/proto_mapping.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/run_process.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::LoopbackServer;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StreamFrames;
using ::testing::HasSubstr;

// One SubscribeAlerts call read message by message; a deadline turns a missing message into a
// failed Read instead of a hung test.
class Subscription {
 public:
  Subscription(esg::v1::EstimationService::Stub& stub, const std::string& spacecraft_id,
               bool replay, bool marker) {
    context_.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    esg::v1::AlertSubscription request;
    request.set_spacecraft_id(spacecraft_id);
    if (replay) *request.mutable_since() = proto_convert::TimeToProto(absl::UnixEpoch());
    request.set_replay_marker(marker);
    reader_ = stub.SubscribeAlerts(&context_, request);
  }
  ~Subscription() {
    context_.TryCancel();
    reader_->Finish();
  }
  // The next message; fails the test if the stream ended.
  esg::v1::Alert Next() {
    esg::v1::Alert alert;
    EXPECT_TRUE(reader_->Read(&alert)) << "the alert stream ended";
    return alert;
  }

 private:
  grpc::ClientContext context_;
  std::unique_ptr<grpc::ClientReader<esg::v1::Alert>> reader_;
};

// Frame k (0-based) of `run` sent again by `station` with other content: refused as a conflict
// of measurement time, raising INGEST_CONFLICT with subsystem "station:<station>".
esg::v1::TelemetryFrame Conflicting(const SimulatedRun& run, size_t k, const std::string& station) {
  esg::v1::TelemetryFrame f = run.frames[k];
  f.set_station_id(station);
  f.set_sequence(1);
  f.mutable_gyros(0)->set_u_k_mv(0, f.gyros(0).u_k_mv(0) + 1.0);
  return f;
}

void SendConflict(esg::v1::EstimationService::Stub& stub, const esg::v1::TelemetryFrame& frame) {
  const esg::testing::StreamResult r = StreamFrames(stub, {frame});
  ASSERT_EQ(r.acks.size(), 1u);
  EXPECT_FALSE(r.acks[0].accepted());
}

void Configure(esg::v1::EstimationService::Stub& stub, const SimulatedRun& run) {
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse response;
  const grpc::Status status =
      stub.ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &response);
  ASSERT_TRUE(status.ok()) << status.error_message();
}

TEST(AlertLifecycle, ReplayMarkerFollowsTheStoredAlertsAndPrecedesLiveOnes) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun run = SimulateRun("LIFE-1", 0.2);
  Configure(*stub, run);
  ASSERT_EQ(StreamFrames(*stub, run.frames).acks.size(), run.frames.size());
  ASSERT_TRUE(server.core().WaitApplied("LIFE-1", absl::Seconds(60)).ok());

  // A live-only subscriber gets the marker at once (nothing to replay), then the live alerts.
  Subscription watcher(*stub, "LIFE-1", /*replay=*/false, /*marker=*/true);
  EXPECT_TRUE(watcher.Next().replay_complete());
  SendConflict(*stub, Conflicting(run, 4, "gs-a"));
  SendConflict(*stub, Conflicting(run, 5, "gs-b"));
  const esg::v1::Alert first = watcher.Next();
  const esg::v1::Alert second = watcher.Next();
  EXPECT_EQ(first.subsystem(), "station:gs-a");
  EXPECT_EQ(second.subsystem(), "station:gs-b");
  EXPECT_FALSE(first.replay_complete());

  // Both are stored now: a replaying subscriber gets them, then the marker, then a live one.
  Subscription replaying(*stub, "LIFE-1", /*replay=*/true, /*marker=*/true);
  Subscription old_client(*stub, "LIFE-1", /*replay=*/true, /*marker=*/false);
  std::vector<int64_t> replayed;
  for (;;) {
    const esg::v1::Alert a = replaying.Next();
    if (a.replay_complete()) {
      EXPECT_EQ(a.sequence(), 0);
      EXPECT_TRUE(a.spacecraft_id().empty());
      EXPECT_FALSE(a.has_measurement_time());
      break;
    }
    replayed.push_back(a.sequence());
    ASSERT_LE(replayed.size(), 100u) << "no marker after the stored alerts";
  }
  // Exactly the stored alerts (the conflicts, and any the estimator raised), in stored order.
  auto stored = server.core().storage().alerts().Since("LIFE-1", absl::UnixEpoch(), 1000);
  ASSERT_TRUE(stored.ok()) << stored.status();
  std::vector<int64_t> stored_sequences;
  for (const auto& r : *stored) stored_sequences.push_back(r.sequence);
  EXPECT_EQ(replayed, stored_sequences);
  EXPECT_THAT(replayed, ::testing::IsSupersetOf({first.sequence(), second.sequence()}));
  SendConflict(*stub, Conflicting(run, 6, "gs-c"));
  const esg::v1::Alert live = replaying.Next();
  EXPECT_FALSE(live.replay_complete());
  EXPECT_EQ(live.subsystem(), "station:gs-c");
  EXPECT_GT(live.sequence(), second.sequence());
  // A client that did not ask for the marker never sees one: the stored alerts, then the live.
  for (size_t i = 0; i <= stored_sequences.size(); ++i) {
    const esg::v1::Alert a = old_client.Next();
    EXPECT_FALSE(a.replay_complete()) << "message " << i;
    EXPECT_EQ(a.sequence(), i < stored_sequences.size() ? stored_sequences[i] : live.sequence());
  }
}

TEST(AlertLifecycle, AnotherOperatorsAcknowledgementIsRefusedNamingTheFirst) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun run = SimulateRun("LIFE-2", 0.2);
  Configure(*stub, run);
  ASSERT_EQ(StreamFrames(*stub, run.frames).acks.size(), run.frames.size());
  ASSERT_TRUE(server.core().WaitApplied("LIFE-2", absl::Seconds(60)).ok());
  Subscription watcher(*stub, "LIFE-2", /*replay=*/false, /*marker=*/true);
  ASSERT_TRUE(watcher.Next().replay_complete());
  SendConflict(*stub, Conflicting(run, 4, "gs-a"));
  const esg::v1::Alert alert = watcher.Next();

  auto acknowledge = [&](const std::string& name, esg::v1::Alert* out) {
    grpc::ClientContext ctx;
    esg::v1::AcknowledgeRequest request;
    request.set_spacecraft_id("LIFE-2");
    request.set_sequence(alert.sequence());
    request.set_operator_name(name);
    return stub->AcknowledgeAlert(&ctx, request, out);
  };
  esg::v1::Alert by_alice;
  ASSERT_TRUE(acknowledge("alice", &by_alice).ok());
  EXPECT_EQ(by_alice.acknowledged_by(), "alice");
  ASSERT_TRUE(by_alice.has_acknowledged_time());
  // The same operator again: idempotent, the first time stands.
  esg::v1::Alert again;
  ASSERT_TRUE(acknowledge("alice", &again).ok());
  EXPECT_EQ(again.acknowledged_time().seconds(), by_alice.acknowledged_time().seconds());
  EXPECT_EQ(again.acknowledged_time().nanos(), by_alice.acknowledged_time().nanos());
  // Another operator: refused, naming who acknowledged first and when.
  esg::v1::Alert by_bob;
  const grpc::Status refused = acknowledge("bob", &by_bob);
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  const absl::Time acked_at = *proto_convert::TimeFromProto(by_alice.acknowledged_time());
  EXPECT_THAT(refused.error_message(),
              HasSubstr(absl::StrCat("operator_name: alert ", alert.sequence(),
                                     " of spacecraft 'LIFE-2' was already acknowledged by "
                                     "'alice' at ",
                                     FormatUtc(acked_at))));
  // The store still holds the first acknowledgement, and subscribers saw it once.
  auto stored = server.core().storage().alerts().Get("LIFE-2", alert.sequence());
  ASSERT_TRUE(stored.ok()) << stored.status();
  EXPECT_EQ(stored->acknowledged_by, "alice");
  const esg::v1::Alert streamed = watcher.Next();
  EXPECT_TRUE(streamed.acknowledged());
  EXPECT_EQ(streamed.acknowledged_by(), "alice");
}

// A re-run over a late frame may set an alert's repeat count back or undo its clear (docs/
// service.md "Several ground stations"); the service publishes each committed state in commit
// order, and a subscriber must receive every one, lower or not, so that it ends with the stored
// state. A state it already has is not sent again, and an acknowledgement is never undone.
TEST(AlertLifecycle, LiveStatesThatSetAnAlertBackReachTheSubscriber) {
  LoopbackServer server;
  auto stub = server.Stub();
  {
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(
                        &ctx, ConfigureRequestFor(::esg::testing::ServerTestConfig("LIFE-4")), &r)
                    .ok());
  }
  storage::AlertRecord record;
  record.spacecraft_id = "LIFE-4";
  record.severity = "WARNING";
  record.reason = "STAR_TRACKER_INNOVATION";
  record.subsystem = "star_tracker";
  record.repeat_count = 5;
  absl::StatusOr<int64_t> sequence = server.core().storage().alerts().Append(record);
  ASSERT_TRUE(sequence.ok()) << sequence.status();
  record.sequence = *sequence;

  Subscription watcher(*stub, "LIFE-4", /*replay=*/true, /*marker=*/true);
  EXPECT_EQ(watcher.Next().repeat_count(), 5);  // the replay
  ASSERT_TRUE(watcher.Next().replay_complete());
  auto publish = [&](int64_t count, bool cleared, bool acknowledged) {
    storage::AlertRecord r = record;
    r.repeat_count = count;
    r.cleared = cleared;
    r.acknowledged = acknowledged;
    server.core().alert_hub().Publish(r);
  };
  publish(5, false, false);  // the state the replay sent: not again
  publish(7, true, false);   // repeated, then cleared
  publish(3, false, false);  // set back by a re-run: lower, not cleared
  publish(4, false, true);   // repeated by the re-run, acknowledged meanwhile
  publish(4, false, false);  // a read from before the acknowledgement: stale
  publish(6, true, true);
  std::vector<std::tuple<int64_t, bool, bool>> received;
  for (int i = 0; i < 4; ++i) {
    const esg::v1::Alert a = watcher.Next();
    received.emplace_back(a.repeat_count(), a.cleared(), a.acknowledged());
  }
  EXPECT_THAT(received, ::testing::ElementsAre(std::make_tuple(7, true, false),
                                               std::make_tuple(3, false, false),
                                               std::make_tuple(4, false, true),
                                               std::make_tuple(6, true, true)));
}

TEST(AlertLifecycle, ClearedTimeIsStoredAndReturned) {
  ServerOptions options;
  options.core.alert_collapse_window = absl::Minutes(10);
  LoopbackServer server(options);
  auto stub = server.Stub();
  const SimulatedRun run = SimulateRun("LIFE-3", 0.5);  // 30 frames, 60 s apart
  ASSERT_GE(run.frames.size(), 25u);
  Configure(*stub, run);
  const std::vector<esg::v1::TelemetryFrame> head(run.frames.begin(), run.frames.begin() + 8);
  const std::vector<esg::v1::TelemetryFrame> tail(run.frames.begin() + 8, run.frames.end());
  ASSERT_EQ(StreamFrames(*stub, head).acks.size(), head.size());
  ASSERT_TRUE(server.core().WaitApplied("LIFE-3", absl::Seconds(60)).ok());
  Subscription watcher(*stub, "LIFE-3", /*replay=*/false, /*marker=*/true);
  ASSERT_TRUE(watcher.Next().replay_complete());
  SendConflict(*stub, Conflicting(run, 4, "gs-a"));
  const esg::v1::Alert raised = watcher.Next();
  EXPECT_FALSE(raised.cleared());
  EXPECT_FALSE(raised.has_cleared_time());
  const absl::Time occurred = *proto_convert::TimeFromProto(run.frames[4].time());

  // Frames more than the window after the occurrence: the alert is quiet, hence cleared.
  ASSERT_EQ(StreamFrames(*stub, tail).acks.size(), tail.size());
  ASSERT_TRUE(server.core().WaitApplied("LIFE-3", absl::Seconds(60)).ok());
  // The tail may raise estimator alerts of its own; the conflict's next state is its clearing.
  esg::v1::Alert cleared;
  for (int i = 0; i < 100 && cleared.sequence() != raised.sequence(); ++i) cleared = watcher.Next();
  ASSERT_EQ(cleared.sequence(), raised.sequence());
  EXPECT_TRUE(cleared.cleared());
  ASSERT_TRUE(cleared.has_cleared_time());
  EXPECT_EQ(*proto_convert::TimeFromProto(cleared.cleared_time()), occurred + absl::Minutes(10));
  // Stored: a new subscriber's replay returns the same cleared time.
  auto stored = server.core().storage().alerts().Get("LIFE-3", raised.sequence());
  ASSERT_TRUE(stored.ok()) << stored.status();
  EXPECT_TRUE(stored->cleared);
  EXPECT_EQ(stored->cleared_time, occurred + absl::Minutes(10));
  Subscription replaying(*stub, "LIFE-3", /*replay=*/true, /*marker=*/true);
  bool seen = false;
  for (esg::v1::Alert a = replaying.Next(); !a.replay_complete(); a = replaying.Next()) {
    if (a.sequence() != raised.sequence()) continue;
    seen = true;
    EXPECT_TRUE(a.cleared());
    EXPECT_EQ(*proto_convert::TimeFromProto(a.cleared_time()), occurred + absl::Minutes(10));
  }
  EXPECT_TRUE(seen);
}

TEST(AlertLifecycle, AlertsAcknowledgementsAndSessionStateChangesAreLogged) {
  esg::testing::TempDir dir;
  const std::string log = dir.File("esgd.log");
  esg::testing::Daemon daemon(dir.File("esg.db"), log);
  ASSERT_GT(daemon.port(), 0);
  auto stub = daemon.Stub();
  const SimulatedRun run = SimulateRun("LIFE-4", 0.2);
  Configure(*stub, run);
  ASSERT_EQ(StreamFrames(*stub, run.frames).acks.size(), run.frames.size());
  esg::v1::Alert alert;
  {
    Subscription watcher(*stub, "LIFE-4", /*replay=*/false, /*marker=*/true);
    ASSERT_TRUE(watcher.Next().replay_complete());
    SendConflict(*stub, Conflicting(run, 4, "gs-a"));
    for (int i = 0; i < 100 && alert.reason() != esg::v1::ALERT_REASON_INGEST_CONFLICT; ++i) {
      alert = watcher.Next();
    }
    ASSERT_EQ(alert.reason(), esg::v1::ALERT_REASON_INGEST_CONFLICT);
  }
  grpc::ClientContext ctx;
  esg::v1::AcknowledgeRequest request;
  request.set_spacecraft_id("LIFE-4");
  request.set_sequence(alert.sequence());
  request.set_operator_name("alice");
  esg::v1::Alert acked;
  ASSERT_TRUE(stub->AcknowledgeAlert(&ctx, request, &acked).ok());
  grpc::ClientContext ctx2;
  request.set_operator_name("bob");
  EXPECT_FALSE(stub->AcknowledgeAlert(&ctx2, request, &acked).ok());
  // The acknowledgement is published (and logged) before AcknowledgeAlert returns.
  stub.reset();
  // A cancelled subscription followed by an acknowledgement once held the shutdown for the whole
  // 5 s deadline; it returns promptly (measured in the test log; the bound leaves margin for a
  // loaded machine and is no performance test).
  const absl::Time stopping = absl::Now();
  daemon.Stop(SIGTERM);
  const absl::Duration shutdown = absl::Now() - stopping;
  RecordProperty("shutdown_ms", std::to_string(absl::ToInt64Milliseconds(shutdown)));
  EXPECT_LT(shutdown, absl::Seconds(2)) << "the shutdown took " << shutdown;

  const std::string text = esg::testing::ReadFile(log);
  // Frame 1 initialises the filter: the state change is logged with the frame's identity.
  EXPECT_THAT(text, HasSubstr("INFO esgd: spacecraft LIFE-4: session state NO_DATA -> "
                              "CALIBRATING at "));
  EXPECT_THAT(text, HasSubstr("(station default, sequence 1)"));
  const std::string prefix = absl::StrCat("alert LIFE-4 #", alert.sequence(),
                                          " WARNING INGEST_CONFLICT station:gs-a, x1, ");
  EXPECT_THAT(text, HasSubstr("WARN esgd: " + prefix));  // raised, active
  EXPECT_THAT(text, HasSubstr(", acknowledged by alice at "));
  EXPECT_THAT(text, HasSubstr("WARN esgd: acknowledgement by 'bob' refused: operator_name: "));
}

// ---- The catalog: one row per reason, and the proto and docs say the same ---------------------

std::string SourceFile(const std::string& relative) {
  const std::filesystem::path root = ESG_SOURCE_DIR;  // the repository, from CMake
  std::ifstream in(root / relative);
  EXPECT_TRUE(in.good()) << (root / relative);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// The comment block right above `ALERT_REASON_<name> = ` in attitude.proto, as one line.
std::string ProtoComment(const std::string& proto, const std::string& name) {
  const size_t at = proto.find(absl::StrCat("  ALERT_REASON_", name, " = "));
  if (at == std::string::npos) return "";
  std::vector<std::string> lines = absl::StrSplit(proto.substr(0, at), '\n');
  std::vector<std::string> comment;
  for (auto it = lines.rbegin(); it != lines.rend(); ++it) {
    absl::string_view line = absl::StripAsciiWhitespace(*it);
    if (it == lines.rbegin() && line.empty()) continue;
    if (!absl::ConsumePrefix(&line, "//")) break;
    comment.insert(comment.begin(), std::string(absl::StripAsciiWhitespace(line)));
  }
  return absl::StrJoin(comment, " ");
}

// The subsystem alternatives of a catalog form: "a, b or c" -> {a, b, c}.
std::vector<std::string> SubsystemAlternatives(absl::string_view form) {
  std::vector<std::string> out;
  for (absl::string_view part : absl::StrSplit(form, " or ")) {
    for (absl::string_view p : absl::StrSplit(part, ", ")) out.emplace_back(p);
  }
  return out;
}

const char* ProtoClearPhrase(ClearRule rule) {
  switch (rule) {
    case ClearRule::kQuiet:
      return "cleared when quiet";
    case ClearRule::kStarTrackerAccepted:
      return "uses the star tracker's measurements again";
    case ClearRule::kQuarantineEnds:
      return "cleared when the quarantine ends";
    case ClearRule::kNever:
      return "never cleared by the service";
  }
  return "?";
}

TEST(AlertCatalog, EveryReasonOfTheProtoEnumHasExactlyOneRow) {
  const google::protobuf::EnumDescriptor* reasons = esg::v1::AlertReason_descriptor();
  int rows = 0;
  for (int i = 0; i < reasons->value_count(); ++i) {
    const auto reason = static_cast<esg::v1::AlertReason>(reasons->value(i)->number());
    if (reason == esg::v1::ALERT_REASON_UNSPECIFIED) continue;
    ++rows;
    const AlertKind* kind = FindAlertKind(reason);
    ASSERT_NE(kind, nullptr) << reasons->value(i)->name() << " has no row";
    EXPECT_EQ(absl::StrCat("ALERT_REASON_", kind->name), reasons->value(i)->name());
    EXPECT_EQ(FindAlertKind(kind->name), kind);
    EXPECT_NE(kind->severity, esg::v1::ALERT_SEVERITY_UNSPECIFIED) << kind->name;
    EXPECT_GT(std::string(kind->guidance).size(), 3u) << kind->name;
  }
  EXPECT_EQ(AlertCatalog().size(), static_cast<size_t>(rows));
}

TEST(AlertCatalog, EveryEstimatorEventHasARowUnderItsOwnName) {
  for (int k = 0; k <= static_cast<int>(estimator::Event::Kind::kGyroStarted); ++k) {
    const auto kind = static_cast<estimator::Event::Kind>(k);
    const AlertKind& row = AlertKindOf(kind);
    EXPECT_NE(row.reason, esg::v1::ALERT_REASON_UNSPECIFIED) << estimator::EventKindName(kind);
    EXPECT_STREQ(row.name, estimator::EventKindName(kind));
    EXPECT_EQ(SeverityOf(kind), row.severity);
    EXPECT_EQ(ReasonOf(kind), row.reason);
  }
}

TEST(AlertCatalog, SubsystemTextsOfTheEstimatorAndTheServiceTakeTheCatalogForm) {
  EXPECT_EQ(SubsystemForm("gyro 2"), "gyro_2");
  EXPECT_EQ(SubsystemForm("gyros 1,2"), "gyro_pair[1,2]");
  EXPECT_EQ(SubsystemForm("gyros and star tracker"), "gyros_and_star_tracker");
  EXPECT_EQ(SubsystemForm("station gs-1"), "station:gs-1");
  for (const char* same : {"star_tracker", "working_pair[1,2]", "reserve_pair[3,4]", "filter",
                           "model", "session", "gyro_2", "gyro_pair[1,2]", "station:gs-1"}) {
    EXPECT_EQ(SubsystemForm(same), same);
  }
}

TEST(AlertCatalog, TheProtoCommentsStateTheSameSeveritySubsystemAndClearing) {
  const std::string proto = SourceFile("proto/esg/v1/attitude.proto");
  for (const AlertKind& kind : AlertCatalog()) {
    const std::string comment = ProtoComment(proto, kind.name);
    ASSERT_FALSE(comment.empty()) << kind.name;
    EXPECT_THAT(comment, HasSubstr(absl::StrCat("Severity ", SeverityName(kind.severity), ";")))
        << kind.name;
    for (const std::string& form : SubsystemAlternatives(kind.subsystem)) {
      EXPECT_THAT(comment, HasSubstr(absl::StrCat("\"", form, "\""))) << kind.name;
    }
    EXPECT_THAT(comment, HasSubstr(ProtoClearPhrase(kind.clear_rule))) << kind.name;
  }
}

TEST(AlertCatalog, TheDocsTableStatesTheSameRowsWithGuidance) {
  const std::string docs = SourceFile("docs/service.md");
  for (const AlertKind& kind : AlertCatalog()) {
    const size_t at = docs.find(absl::StrCat("\n| ", kind.name, " |"));
    ASSERT_NE(at, std::string::npos) << kind.name << " has no row in docs/service.md";
    const std::string row = docs.substr(at + 1, docs.find('\n', at + 1) - at - 1);
    EXPECT_THAT(row, HasSubstr(absl::StrCat("| ", SeverityName(kind.severity), " |"))) << kind.name;
    for (const std::string& form : SubsystemAlternatives(kind.subsystem)) {
      EXPECT_THAT(row, HasSubstr(absl::StrCat("`", form, "`"))) << kind.name;
    }
    EXPECT_THAT(row, HasSubstr(ClearRuleText(kind.clear_rule))) << kind.name;
    EXPECT_THAT(row, HasSubstr(kind.guidance)) << kind.name;
  }
}

}  // namespace
}  // namespace esg::server
