// The automatic diagnosis (server/auto_diagnosis.h, docs/service.md "Automatic diagnosis")
// against an in-process esgd on loopback with a real SQLite file: the follow-up alert's message
// for each kind of verdict; a MODEL_INCONSISTENT alert given to the scheduler diagnoses the
// archive once (stored as automatic, answering it) and raises MODEL_DIAGNOSED referring to it;
// the debounce; waiting for a free diagnosis slot; cancellation by an operator
// (CancelAutoDiagnosis) and by a reconfiguration, which store nothing; the rpc's refusals. The
// trigger from a real filter alert and the apply are tested end to end in
// tests/client/operator_actions_cli_test.cc (AutoDiagnosis.*).
#include "server/auto_diagnosis.h"

#include <chrono>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "proto/convert.h"
#include "tests/server/server_test_util.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::LoopbackServer;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StreamFrames;
using ::testing::HasSubstr;
using ::testing::Not;

esg::v1::DiagnosisResult Result(const std::string& verdict) {
  esg::v1::DiagnosisResult r;
  r.set_id(12);
  r.set_spacecraft_id("RDK-1");
  r.set_verdict(verdict);
  r.set_frames(721);
  r.set_config_version(3);
  *r.mutable_first_frame_time() = proto_convert::TimeToProto(absl::FromUnixSeconds(1551398400));
  *r.mutable_last_frame_time() = proto_convert::TimeToProto(absl::FromUnixSeconds(1551441600));
  return r;
}

storage::AlertRecord Inconsistent(const std::string& id, int64_t sequence, absl::Time at) {
  storage::AlertRecord a;
  a.spacecraft_id = id;
  a.sequence = sequence;
  a.reason = "MODEL_INCONSISTENT";
  a.severity = "WARNING";
  a.subsystem = "model:gyro_2";
  a.first_time = at;
  a.measurement_time = at;
  return a;
}

TEST(AutoDiagnosisMessage, NamesTheVerdictTheDiagnosisTheAlertAndWhatToDo) {
  const storage::AlertRecord alert =
      Inconsistent("RDK-1", 5, absl::FromUnixSeconds(1551398400) + absl::Hours(3));
  esg::v1::DiagnosisResult effect = Result("rotor_displacement");
  effect.add_applies("rotor_displacement (gyro 2): gyros[2].model C11, C12 freed");
  const std::string applied = FollowUpMessage(effect, alert);
  EXPECT_THAT(applied, HasSubstr("automatic diagnosis #12 of RDK-1 answers alert #5 "
                                 "(MODEL_INCONSISTENT model:gyro_2 at 2019-03-01T03:00:00"));
  EXPECT_THAT(applied, HasSubstr("721 frames, configuration version 3"));
  EXPECT_THAT(applied, HasSubstr("verdict rotor_displacement: the model lacks rotor_displacement "
                                 "(gyro 2): gyros[2].model C11, C12 freed"));
  EXPECT_THAT(applied, HasSubstr("`esg model apply --spacecraft RDK-1 --diagnosis 12`"));
  for (const char* verdict : {"none", "unexplained"}) {
    const std::string m = FollowUpMessage(Result(verdict), alert);
    EXPECT_THAT(m, HasSubstr(absl::StrCat("verdict ", verdict, ": ")));
    EXPECT_THAT(m, HasSubstr("nothing to apply"));
    EXPECT_THAT(m, Not(HasSubstr("esg model apply")));
  }
  // Any other verdict (one this service does not know yet) whose findings do not map.
  esg::v1::DiagnosisResult other = Result("partly_explained");
  other.add_does_not_apply("drift_step (gyro 3): a change in time");
  const std::string m = FollowUpMessage(other, alert);
  EXPECT_THAT(m, HasSubstr("verdict partly_explained: none of its findings maps to the "
                           "configuration (drift_step (gyro 3): a change in time)"));
  EXPECT_THAT(m, HasSubstr("esg diagnoses show --id 12"));
  EXPECT_THAT(m, Not(HasSubstr("esg model apply")));
}

// A result whose span cannot be read (a timestamp with nanos out of range, as a corrupt or
// hand-made DiagnosisResult may carry) gives the message with that said instead of a time: the
// span's ends are not dereferenced unchecked.
TEST(AutoDiagnosisMessage, StatesASpanItCannotReadInsteadOfATime) {
  const storage::AlertRecord alert =
      Inconsistent("RDK-1", 5, absl::FromUnixSeconds(1551398400) + absl::Hours(3));
  esg::v1::DiagnosisResult bad_first = Result("none");
  bad_first.mutable_first_frame_time()->set_nanos(-1);
  const std::string first = FollowUpMessage(bad_first, alert);
  EXPECT_THAT(first, HasSubstr("automatic diagnosis #12 of RDK-1 answers alert #5"));
  EXPECT_THAT(first, HasSubstr(", over a span whose first frame time cannot be read ("));
  EXPECT_THAT(first, HasSubstr("721 frames, configuration version 3"));
  EXPECT_THAT(first, HasSubstr("verdict none: "));
  esg::v1::DiagnosisResult bad_last = Result("none");
  bad_last.mutable_last_frame_time()->set_seconds(int64_t{1} << 62);
  EXPECT_THAT(FollowUpMessage(bad_last, alert),
              HasSubstr(", over a span whose last frame time cannot be read ("));
  // Both readable: the span in UTC.
  EXPECT_THAT(FollowUpMessage(Result("none"), alert),
              HasSubstr(", over 2019-03-01T00:00:00.000Z .. 2019-03-01T12:00:00.000Z ("));
}

// A configured spacecraft with `hours` of archived, applied telemetry.
struct Flight {
  explicit Flight(const std::string& id, double hours, server::ServerOptions options = {})
      : server(options), run(SimulateRun(id, hours, 11)) {
    stub = server.Stub();
    grpc::ClientContext context;
    esg::v1::ConfigureResponse configured;
    EXPECT_TRUE(
        stub->ConfigureSpacecraft(&context, ConfigureRequestFor(run.config), &configured).ok());
    EXPECT_TRUE(StreamFrames(*stub, run.frames).status.ok());
    EXPECT_TRUE(server.core().WaitApplied(id, absl::Minutes(2)).ok());
  }
  absl::Time last_time() const {
    return *proto_convert::TimeFromProto(run.frames.back().time());
  }
  std::vector<storage::DiagnosisRecord> Stored(const std::string& id) {
    absl::StatusOr<std::vector<storage::DiagnosisRecord>> list =
        server.core().storage().diagnoses().List(id);
    EXPECT_TRUE(list.ok()) << list.status();
    return list.ok() ? *list : std::vector<storage::DiagnosisRecord>{};
  }
  std::vector<storage::AlertRecord> Diagnosed(const std::string& id) {
    std::vector<storage::AlertRecord> out;
    absl::StatusOr<std::vector<storage::AlertRecord>> all =
        server.core().storage().alerts().Since(id, absl::UnixEpoch(), 10000);
    EXPECT_TRUE(all.ok()) << all.status();
    if (!all.ok()) return out;
    for (const storage::AlertRecord& a : *all) {
      if (a.reason == "MODEL_DIAGNOSED") out.push_back(a);
    }
    return out;
  }

  LoopbackServer server;
  SimulatedRun run;
  std::unique_ptr<esg::v1::EstimationService::Stub> stub;
};

bool WaitFor(const std::function<bool()>& done, absl::Duration timeout) {
  const absl::Time deadline = absl::Now() + timeout;
  while (absl::Now() < deadline) {
    if (done()) return true;
    absl::SleepFor(absl::Milliseconds(50));
  }
  return done();
}

grpc::Status CancelAuto(esg::v1::EstimationService::Stub& stub, const std::string& id,
                        esg::v1::CancelAutoDiagnosisResponse* response) {
  grpc::ClientContext context;
  esg::v1::CancelAutoDiagnosisRequest request;
  request.set_spacecraft_id(id);
  return stub.CancelAutoDiagnosis(&context, request, response);
}

TEST(AutoDiagnosis, AnAlertIsDiagnosedOnceStoredAsAutomaticAndAnsweredByAnAlert) {
  Flight f("AUTO-1", 12.0);
  AutoDiagnosis& scheduler = f.server.get()->service().auto_diagnosis();
  const storage::AlertRecord alert = Inconsistent("AUTO-1", 4, f.last_time() - absl::Hours(2));
  scheduler.OnModelAlert(alert);
  ASSERT_TRUE(WaitFor([&] { return !f.Diagnosed("AUTO-1").empty(); }, absl::Minutes(3)));
  const std::vector<storage::DiagnosisRecord> stored = f.Stored("AUTO-1");
  ASSERT_EQ(stored.size(), 1u);
  EXPECT_EQ(stored[0].requested_by, "service");
  EXPECT_EQ(stored[0].answers_alert, 4);
  EXPECT_EQ(stored[0].config_version, 1);
  EXPECT_EQ(stored[0].to_time, f.last_time());
  EXPECT_EQ(stored[0].frames, static_cast<int64_t>(f.run.frames.size()));  // 12 h < 48 h
  const std::vector<storage::AlertRecord> answers = f.Diagnosed("AUTO-1");
  ASSERT_EQ(answers.size(), 1u);
  EXPECT_EQ(answers[0].severity, "WARNING");
  EXPECT_EQ(answers[0].subsystem, "model");
  EXPECT_EQ(answers[0].value, static_cast<double>(stored[0].id));
  EXPECT_EQ(answers[0].threshold, 4.0);
  EXPECT_EQ(answers[0].measurement_time, f.last_time());
  EXPECT_THAT(answers[0].message,
              HasSubstr(absl::StrCat("automatic diagnosis #", stored[0].id,
                                     " of AUTO-1 answers alert #4 (MODEL_INCONSISTENT")));
  EXPECT_THAT(answers[0].message, HasSubstr(absl::StrCat("verdict ", stored[0].verdict)));

  // The same mismatch again under the same configuration, within 48 h of telemetry: no run.
  scheduler.OnModelAlert(Inconsistent("AUTO-1", 9, f.last_time()));
  absl::SleepFor(absl::Seconds(2));
  EXPECT_EQ(f.Stored("AUTO-1").size(), 1u);
  EXPECT_EQ(f.Diagnosed("AUTO-1").size(), 1u);
  // ListDiagnoses says which is automatic.
  grpc::ClientContext context;
  esg::v1::ListDiagnosesRequest list;
  list.set_spacecraft_id("AUTO-1");
  esg::v1::ListDiagnosesResponse listed;
  ASSERT_TRUE(f.stub->ListDiagnoses(&context, list, &listed).ok());
  ASSERT_EQ(listed.diagnoses_size(), 1);
  EXPECT_EQ(listed.diagnoses(0).requested_by(), "service");
  EXPECT_EQ(listed.diagnoses(0).answers_alert(), 4);
}

// With every diagnosis slot taken, the automatic diagnosis waits (it never refuses an operator);
// an operator's cancel drops it, nothing is stored, and none starts again under this
// configuration; a reconfiguration lifts that.
TEST(AutoDiagnosis, WaitsForAFreeSlotAndAnOperatorCancelStoresNothing) {
  server::ServerOptions options;
  options.auto_diagnosis.slot_retry = absl::Milliseconds(100);
  Flight f("AUTO-2", 6.0, options);
  CallLimiter& limiter = f.server.get()->service().diagnosis_limiter();
  std::vector<CallLimiter::Permit> held;
  for (const char* caller : {"ops-a", "ops-b"}) {
    absl::StatusOr<CallLimiter::Permit> p = limiter.Acquire(caller);
    ASSERT_TRUE(p.ok()) << p.status();
    held.push_back(std::move(*p));
  }
  ASSERT_EQ(limiter.Running(), limiter.total());
  AutoDiagnosis& scheduler = f.server.get()->service().auto_diagnosis();
  scheduler.OnModelAlert(Inconsistent("AUTO-2", 3, f.last_time()));
  absl::SleepFor(absl::Milliseconds(500));
  EXPECT_EQ(limiter.Running(kAutoDiagnosisCaller), 0);
  esg::v1::CancelAutoDiagnosisResponse cancelled;
  ASSERT_TRUE(CancelAuto(*f.stub, "AUTO-2", &cancelled).ok());
  EXPECT_TRUE(cancelled.cancelled());
  EXPECT_EQ(cancelled.answers_alert(), 3);
  held.clear();  // the slots come free: nothing starts
  absl::SleepFor(absl::Seconds(1));
  EXPECT_TRUE(f.Stored("AUTO-2").empty());
  EXPECT_TRUE(f.Diagnosed("AUTO-2").empty());
  ASSERT_TRUE(CancelAuto(*f.stub, "AUTO-2", &cancelled).ok());
  EXPECT_FALSE(cancelled.cancelled());
  // Suppressed under this configuration version ...
  scheduler.OnModelAlert(Inconsistent("AUTO-2", 6, f.last_time()));
  absl::SleepFor(absl::Seconds(2));
  EXPECT_TRUE(f.Stored("AUTO-2").empty());
  // ... not under the next one.
  {
    grpc::ClientContext context;
    estimator::SpacecraftConfig changed = f.run.config;
    changed.readout_noise *= 1.5;  // a new configuration version
    esg::v1::ConfigureRequest request = ConfigureRequestFor(changed);
    request.set_replace(true);
    esg::v1::ConfigureResponse configured;
    ASSERT_TRUE(f.stub->ConfigureSpacecraft(&context, request, &configured).ok());
  }
  ASSERT_TRUE(f.server.core().WaitApplied("AUTO-2", absl::Minutes(2)).ok());
  scheduler.OnModelAlert(Inconsistent("AUTO-2", 20, f.last_time()));
  ASSERT_TRUE(WaitFor([&] { return f.Stored("AUTO-2").size() == 1; }, absl::Minutes(3)));
  EXPECT_EQ(f.Stored("AUTO-2")[0].config_version, 2);
  EXPECT_EQ(f.Stored("AUTO-2")[0].answers_alert, 20);
}

// A reconfiguration cancels a waiting automatic diagnosis of that spacecraft (its span and
// configuration are stale); another spacecraft's is not touched.
TEST(AutoDiagnosis, AReconfigurationCancelsItsSpacecraftsDiagnosis) {
  server::ServerOptions options;
  options.auto_diagnosis.slot_retry = absl::Milliseconds(100);
  Flight f("AUTO-3", 6.0, options);
  CallLimiter& limiter = f.server.get()->service().diagnosis_limiter();
  std::vector<CallLimiter::Permit> held;
  for (const char* caller : {"ops-a", "ops-b"}) {
    absl::StatusOr<CallLimiter::Permit> p = limiter.Acquire(caller);
    ASSERT_TRUE(p.ok()) << p.status();
    held.push_back(std::move(*p));
  }
  f.server.get()->service().auto_diagnosis().OnModelAlert(
      Inconsistent("AUTO-3", 2, f.last_time()));
  absl::SleepFor(absl::Milliseconds(300));
  {
    grpc::ClientContext context;
    estimator::SpacecraftConfig changed = f.run.config;
    changed.readout_noise *= 1.5;  // a new configuration version
    esg::v1::ConfigureRequest request = ConfigureRequestFor(changed);
    request.set_replace(true);
    esg::v1::ConfigureResponse configured;
    ASSERT_TRUE(f.stub->ConfigureSpacecraft(&context, request, &configured).ok());
  }
  held.clear();
  absl::SleepFor(absl::Seconds(1));
  EXPECT_TRUE(f.Stored("AUTO-3").empty());
  esg::v1::CancelAutoDiagnosisResponse response;
  ASSERT_TRUE(CancelAuto(*f.stub, "AUTO-3", &response).ok());
  EXPECT_FALSE(response.cancelled());
}

TEST(AutoDiagnosis, CancelIsRefusedForAnUnknownOrEmptySpacecraft) {
  LoopbackServer server;
  auto stub = server.Stub();
  esg::v1::CancelAutoDiagnosisResponse response;
  grpc::Status status = CancelAuto(*stub, "NOPE", &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_THAT(status.error_message(), HasSubstr("spacecraft_id"));
  status = CancelAuto(*stub, "", &response);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), HasSubstr("spacecraft_id: required"));
}

// --auto-diagnosis-hours 0: no scheduler; an alert given to it does nothing.
TEST(AutoDiagnosis, ZeroHoursRunsNone) {
  server::ServerOptions options;
  options.auto_diagnosis.span = absl::ZeroDuration();
  Flight f("AUTO-4", 3.0, options);
  f.server.get()->service().auto_diagnosis().OnModelAlert(
      Inconsistent("AUTO-4", 1, f.last_time()));
  absl::SleepFor(absl::Seconds(1));
  EXPECT_TRUE(f.Stored("AUTO-4").empty());
}

// An operator's cancel is stored with the configuration version: after a restart of the server
// on the same SQLite file, an alert under that version queues a job that the debounce drops at
// once (with every diagnosis slot taken, a job not dropped would wait for one, and a cancel
// would find it).
TEST(AutoDiagnosis, AnOperatorsCancelHoldsAcrossARestart) {
  esg::testing::TempDir dir;
  const std::string db = dir.File("esg.db");
  server::ServerOptions options;
  options.auto_diagnosis.slot_retry = absl::Milliseconds(100);
  const SimulatedRun run = SimulateRun("AUTO-6", 3.0, 11);
  const absl::Time last = *proto_convert::TimeFromProto(run.frames.back().time());
  const auto hold_slots = [](LoopbackServer& server) {
    CallLimiter& limiter = server.get()->service().diagnosis_limiter();
    std::vector<CallLimiter::Permit> held;
    for (const char* caller : {"ops-a", "ops-b"}) {
      absl::StatusOr<CallLimiter::Permit> p = limiter.Acquire(caller);
      EXPECT_TRUE(p.ok()) << p.status();
      if (p.ok()) held.push_back(std::move(*p));
    }
    return held;
  };
  esg::v1::CancelAutoDiagnosisResponse cancelled;
  {
    LoopbackServer server(options, db);
    auto stub = server.Stub();
    grpc::ClientContext context;
    esg::v1::ConfigureResponse configured;
    ASSERT_TRUE(
        stub->ConfigureSpacecraft(&context, ConfigureRequestFor(run.config), &configured).ok());
    ASSERT_TRUE(StreamFrames(*stub, run.frames).status.ok());
    ASSERT_TRUE(server.core().WaitApplied("AUTO-6", absl::Minutes(2)).ok());
    std::vector<CallLimiter::Permit> held = hold_slots(server);
    server.get()->service().auto_diagnosis().OnModelAlert(Inconsistent("AUTO-6", 3, last));
    absl::SleepFor(absl::Milliseconds(300));
    ASSERT_TRUE(CancelAuto(*stub, "AUTO-6", &cancelled).ok());
    ASSERT_TRUE(cancelled.cancelled());
    absl::StatusOr<bool> marker = server.core().storage().diagnoses().AutoCancelled("AUTO-6", 1);
    ASSERT_TRUE(marker.ok()) << marker.status();
    EXPECT_TRUE(*marker);
  }
  LoopbackServer server(options, db);
  auto stub = server.Stub();
  std::vector<CallLimiter::Permit> held = hold_slots(server);
  server.get()->service().auto_diagnosis().OnModelAlert(Inconsistent("AUTO-6", 9, last));
  absl::SleepFor(absl::Seconds(1));
  ASSERT_TRUE(CancelAuto(*stub, "AUTO-6", &cancelled).ok());
  EXPECT_FALSE(cancelled.cancelled()) << "a job waited under the cancelled configuration version";
  held.clear();
  absl::SleepFor(absl::Milliseconds(300));
  absl::StatusOr<std::vector<storage::DiagnosisRecord>> stored =
      server.core().storage().diagnoses().List("AUTO-6");
  ASSERT_TRUE(stored.ok()) << stored.status();
  EXPECT_TRUE(stored->empty());
}

// An operator's diagnosis of the whole archive through the Diagnose rpc; its stored id.
int64_t OperatorDiagnosis(esg::v1::EstimationService::Stub& stub, const std::string& id) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(300));
  esg::v1::DiagnoseRequest request;
  request.set_spacecraft_id(id);
  auto reader = stub.Diagnose(&context, request);
  esg::v1::DiagnoseUpdate update;
  int64_t stored = 0;
  while (reader->Read(&update)) {
    if (update.has_result()) stored = update.result().id();
  }
  const grpc::Status status = reader->Finish();
  EXPECT_TRUE(status.ok()) << status.error_message();
  return stored;
}

// Under the per-spacecraft bound (esgd --max-stored-diagnoses 2; docs/service.md "Limits"), the
// service's own diagnoses are dropped before any an operator asked for: an operator's, then an
// automatic one, then an operator's again leave the two operators' (dropping the oldest, as
// before, would have dropped the first operator's and kept the automatic one). The one just
// stored is never the one dropped: an automatic diagnosis stored beside two operators' stays,
// and the older operator's goes.
TEST(AutoDiagnosis, UnderTheStorageBoundTheServicesDiagnosesGoBeforeTheOperators) {
  server::ServerOptions options;
  options.max_stored_diagnoses = 2;
  Flight f("AUTO-5", 6.0, options);
  AutoDiagnosis& scheduler = f.server.get()->service().auto_diagnosis();
  const auto ids = [&] {
    std::vector<int64_t> out;
    for (const storage::DiagnosisRecord& d : f.Stored("AUTO-5")) out.push_back(d.id);
    return out;
  };
  const int64_t operator1 = OperatorDiagnosis(*f.stub, "AUTO-5");
  ASSERT_GT(operator1, 0);
  scheduler.OnModelAlert(Inconsistent("AUTO-5", 2, f.last_time()));
  ASSERT_TRUE(WaitFor([&] { return f.Diagnosed("AUTO-5").size() == 1; }, absl::Minutes(3)));
  const int64_t automatic1 = static_cast<int64_t>(f.Diagnosed("AUTO-5")[0].value);
  EXPECT_EQ(ids(), (std::vector<int64_t>{operator1, automatic1}));
  const int64_t operator2 = OperatorDiagnosis(*f.stub, "AUTO-5");
  ASSERT_GT(operator2, 0);
  EXPECT_EQ(ids(), (std::vector<int64_t>{operator1, operator2}));
  for (const storage::DiagnosisRecord& d : f.Stored("AUTO-5")) EXPECT_EQ(d.requested_by, "");

  // A new configuration version lifts the debounce; its automatic diagnosis is stored and kept.
  {
    grpc::ClientContext context;
    estimator::SpacecraftConfig changed = f.run.config;
    changed.readout_noise *= 1.5;
    esg::v1::ConfigureRequest request = ConfigureRequestFor(changed);
    request.set_replace(true);
    esg::v1::ConfigureResponse configured;
    ASSERT_TRUE(f.stub->ConfigureSpacecraft(&context, request, &configured).ok());
  }
  ASSERT_TRUE(f.server.core().WaitApplied("AUTO-5", absl::Minutes(2)).ok());
  scheduler.OnModelAlert(Inconsistent("AUTO-5", 30, f.last_time()));
  int64_t automatic2 = 0;
  ASSERT_TRUE(WaitFor(
      [&] {
        for (const storage::DiagnosisRecord& d : f.Stored("AUTO-5")) {
          if (d.requested_by == storage::kRequestedByService && d.answers_alert == 30) {
            automatic2 = d.id;
          }
        }
        return automatic2 > 0;
      },
      absl::Minutes(3)));
  EXPECT_EQ(ids(), (std::vector<int64_t>{operator2, automatic2}));
}

}  // namespace
}  // namespace esg::server
