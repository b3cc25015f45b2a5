// Configuration versions (docs/service.md, ConfigureSpacecraft, "Configuration versions"): esgd stores a new version of a
// spacecraft's configuration when its values change, not when the same values come again in
// another form: a drift coefficient by its field or keyed (GyroDriftModel.coefficients, docs/
// decisions.md D107), other key order or whitespace, the text an older esgd stored. Real esgd on
// 127.0.0.1 over a real SQLite file, restarted on it; the same on PostgreSQL (the fixture's
// shared test server).
#include <string>
#include <vector>

#include "esg/v1/spacecraft_config.pb.h"
#include "estimator/model_terms.h"
#include "gmock/gmock.h"
#include "google/protobuf/util/json_util.h"
#include "gtest/gtest.h"
#include "proto/convert.h"
#include "storage/storage.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/postgres_server.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::LoopbackServer;
using ::esg::testing::ServerTestConfig;
using ::esg::testing::TempDir;
using ::testing::SizeIs;

// Every coefficient of `model` by its field (the form of the release before the keyed list),
// through the descriptors' JSON keys, so this names no field. A term added to the table after
// that release has no field; the release could not hold it, so it must be 0 here.
void AllByField(esg::v1::GyroDriftModel* model) {
  std::vector<double> deg_h;
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    deg_h.push_back(proto_convert::DriftModelTermDegH(*model, term));
  }
  model->Clear();
  const google::protobuf::Reflection* reflection = model->GetReflection();
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    const google::protobuf::FieldDescriptor* field =
        model->GetDescriptor()->FindFieldByCamelcaseName(std::string(term.json_key));
    if (field == nullptr) {
      EXPECT_EQ(deg_h[term.theta_index], 0.0) << term.json_key << " has no field to be written in";
      continue;
    }
    if (field->is_repeated()) {
      reflection->AddDouble(model, field, deg_h[term.theta_index]);
    } else {
      reflection->SetDouble(model, field, deg_h[term.theta_index]);
    }
  }
}

// Every coefficient of `model` keyed, in the reverse of the table's order.
void AllKeyed(esg::v1::GyroDriftModel* model) {
  std::vector<double> deg_h;
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    deg_h.push_back(proto_convert::DriftModelTermDegH(*model, term));
  }
  model->Clear();
  for (int i = estimator::kNumDriftCoefficients - 1; i >= 0; --i) {
    esg::v1::DriftCoefficient* c = model->add_coefficients();
    c->set_term(std::string(estimator::kFixedTerms[i].storage_key));
    c->set_value_deg_h(deg_h[i]);
  }
}

template <typename Rewrite>
esg::v1::SpacecraftConfig Rewritten(const estimator::SpacecraftConfig& config, Rewrite rewrite) {
  esg::v1::SpacecraftConfig proto = proto_convert::ConfigToProto(config);
  for (esg::v1::GyroConfig& g : *proto.mutable_gyros()) {
    rewrite(g.mutable_model());
    rewrite(g.mutable_model_sigma());
  }
  return proto;
}

// The configuration's text as an older esgd could have stored it: every coefficient by its
// field, laid out by protobuf's own printer (other whitespace than esgd's JSON).
std::string OlderStoredText(const estimator::SpacecraftConfig& config) {
  google::protobuf::util::JsonPrintOptions options;
  options.add_whitespace = true;
  options.always_print_primitive_fields = true;
  std::string json;
  EXPECT_TRUE(google::protobuf::util::MessageToJsonString(Rewritten(config, AllByField), &json,
                                                          options)
                  .ok());
  return json;
}

// Replaces the text of the spacecraft's latest stored configuration (the server stopped).
void StoreTextAsLatest(const std::string& db, const std::string& id, const std::string& json) {
  absl::StatusOr<std::unique_ptr<storage::Storage>> storage = storage::Storage::Open(db);
  ASSERT_TRUE(storage.ok()) << storage.status();
  absl::StatusOr<storage::Transaction> txn =
      (*storage)->database().Begin(storage::TransactionMode::kImmediate);
  ASSERT_TRUE(txn.ok()) << txn.status();
  absl::StatusOr<storage::Statement*> update = txn->Prepare(
      "UPDATE spacecraft_configs SET config_json = ?1 WHERE spacecraft_id = ?2 AND version = "
      "(SELECT MAX(version) FROM spacecraft_configs WHERE spacecraft_id = ?2)");
  ASSERT_TRUE(update.ok()) << update.status();
  (*update)->BindText(1, json).BindText(2, id);
  ASSERT_TRUE((*update)->Run().ok());
  ASSERT_TRUE(txn->Commit().ok());
}

grpc::Status Configure(LoopbackServer& server, const esg::v1::SpacecraftConfig& config,
                       const std::string& model, bool replace) {
  esg::v1::ConfigureRequest request;
  *request.mutable_config() = config;
  request.set_model(model);
  request.set_replace(replace);
  grpc::ClientContext context;
  esg::v1::ConfigureResponse response;
  return server.Stub()->ConfigureSpacecraft(&context, request, &response);
}

std::vector<storage::ConfigRecord> History(LoopbackServer& server, const std::string& id) {
  absl::StatusOr<std::vector<storage::ConfigRecord>> history =
      server.core().storage().configs().History(id);
  EXPECT_TRUE(history.ok()) << history.status();
  return history.ok() ? *history : std::vector<storage::ConfigRecord>{};
}

// `db`: an SQLite file's path or a PostgreSQL URI (LoopbackServer and Storage::Open take both).
void SameValuesInAnotherFormAreNoNewVersion(const std::string& db) {
  const std::string id = "CFGV-1";
  const estimator::SpacecraftConfig config = ServerTestConfig(id);
  {
    LoopbackServer server({}, db);
    ASSERT_TRUE(Configure(server, Rewritten(config, AllByField), "", false).ok());
    // The same values keyed, the keys in reverse order: no new version.
    ASSERT_TRUE(Configure(server, Rewritten(config, AllKeyed), "", false).ok());
    ASSERT_THAT(History(server, id), SizeIs(1));
  }
  // The text an older esgd stored: the same values in another layout and form.
  const std::string older = OlderStoredText(config);
  ASSERT_NE(older, proto_convert::ConfigToJson(config));
  StoreTextAsLatest(db, id, older);

  LoopbackServer server({}, db);
  // Keyed, with another model and replace (a new session, whose configuration is stored): still
  // version 1, its stored text as it was.
  ASSERT_TRUE(Configure(server, Rewritten(config, AllKeyed), "1+11", true).ok());
  std::vector<storage::ConfigRecord> history = History(server, id);
  ASSERT_THAT(history, SizeIs(1));
  EXPECT_EQ(history[0].config_json, older);
  // By field, the model back: still version 1.
  ASSERT_TRUE(Configure(server, Rewritten(config, AllByField), "", true).ok());
  ASSERT_THAT(History(server, id), SizeIs(1));

  // A real change, one coefficient's prior (keyed): version 2, in the JSON esgd writes.
  estimator::SpacecraftConfig changed = config;
  changed.gyros[0].model.k0 += estimator::DegPerHourToRadPerSec(0.01);
  ASSERT_TRUE(Configure(server, Rewritten(changed, AllKeyed), "", true).ok());
  history = History(server, id);
  ASSERT_THAT(history, SizeIs(2));
  EXPECT_EQ(history[1].version, 2);
  EXPECT_EQ(history[1].config_json, proto_convert::ConfigToJson(changed));
  // Back to the first values: a change again, version 3.
  ASSERT_TRUE(Configure(server, Rewritten(config, AllByField), "", true).ok());
  EXPECT_THAT(History(server, id), SizeIs(3));
}

TEST(ConfigVersion, TheSameValuesInAnotherFormAreNoNewVersionAndAChangeIs) {
  TempDir dir;
  SameValuesInAnotherFormAreNoNewVersion(dir.File("esg.db"));
}

TEST(ConfigVersionPostgres, TheSameValuesInAnotherFormAreNoNewVersionAndAChangeIs) {
  std::string error;
  esg::testing::PostgresServer* pg = esg::testing::PostgresServer::Shared(&error);
  ASSERT_NE(pg, nullptr) << "the PostgreSQL test server cannot start: " << error;
  absl::StatusOr<std::string> uri = pg->CreateDatabase();
  ASSERT_TRUE(uri.ok()) << uri.status();
  SameValuesInAnotherFormAreNoNewVersion(*uri);
}

// A database written before the keyed form (its configuration stored with every coefficient by
// field) opens, and esgd reports the same values: the session's configuration (written keyed, no
// field) and the coefficient history, as before the restart.
void DatabaseWrittenBeforeOpensWithTheSameValues(const std::string& db) {
  const esg::testing::SimulatedRun run = esg::testing::SimulateRun("CFGV-2", 1.0, 5);
  esg::v1::HistoryResponse before;
  {
    LoopbackServer server({}, db);
    ASSERT_TRUE(Configure(server, Rewritten(run.config, AllByField), "", false).ok());
    ASSERT_EQ(esg::testing::StreamFrames(*server.Stub(), run.frames).acks.size(),
              run.frames.size());
    ASSERT_TRUE(server.core().WaitApplied("CFGV-2", absl::Seconds(60)).ok());
    grpc::ClientContext context;
    esg::v1::HistoryRequest request;
    request.set_spacecraft_id("CFGV-2");
    ASSERT_TRUE(server.Stub()->GetCoefficientHistory(&context, request, &before).ok());
    ASSERT_GT(before.snapshots_size(), 0);
  }
  StoreTextAsLatest(db, "CFGV-2", OlderStoredText(run.config));

  LoopbackServer server({}, db);
  const esg::v1::SessionInfo info = esg::testing::Session(*server.Stub(), "CFGV-2");
  EXPECT_TRUE(info.quarantine_reason().empty()) << info.quarantine_reason();
  absl::StatusOr<estimator::SpacecraftConfig> reported =
      proto_convert::ConfigFromProto(info.config());
  ASSERT_TRUE(reported.ok()) << reported.status();
  EXPECT_EQ(proto_convert::ConfigToJson(*reported), proto_convert::ConfigToJson(run.config));
  ASSERT_EQ(info.config().gyros_size(), static_cast<int>(run.config.gyros.size()));
  for (const esg::v1::GyroConfig& g : info.config().gyros()) {
    for (const esg::v1::GyroDriftModel* m : {&g.model(), &g.model_sigma()}) {
      ASSERT_EQ(m->coefficients_size(), estimator::kNumDriftCoefficients) << "gyro " << g.id();
      esg::v1::GyroDriftModel keyed_only;
      *keyed_only.mutable_coefficients() = m->coefficients();
      EXPECT_EQ(m->SerializeAsString(), keyed_only.SerializeAsString()) << "gyro " << g.id();
    }
  }
  grpc::ClientContext context;
  esg::v1::HistoryRequest request;
  request.set_spacecraft_id("CFGV-2");
  esg::v1::HistoryResponse after;
  ASSERT_TRUE(server.Stub()->GetCoefficientHistory(&context, request, &after).ok());
  ASSERT_EQ(after.snapshots_size(), before.snapshots_size());
  for (int i = 0; i < after.snapshots_size(); ++i) {
    for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
      EXPECT_EQ(proto_convert::DriftModelTermDegH(after.snapshots(i).model(), term),
                proto_convert::DriftModelTermDegH(before.snapshots(i).model(), term))
          << "snapshot " << i << " " << term.label;
      EXPECT_EQ(proto_convert::DriftModelTermDegH(after.snapshots(i).sigma(), term),
                proto_convert::DriftModelTermDegH(before.snapshots(i).sigma(), term))
          << "snapshot " << i << " " << term.label;
    }
  }
  // The configuration sent again as the release before wrote it is the same version.
  ASSERT_TRUE(Configure(server, Rewritten(run.config, AllByField), "", false).ok());
  EXPECT_THAT(History(server, "CFGV-2"), SizeIs(1));
}

TEST(ConfigVersion, ADatabaseWrittenBeforeTheKeyedFormOpensWithTheSameValues) {
  TempDir dir;
  DatabaseWrittenBeforeOpensWithTheSameValues(dir.File("esg.db"));
}

TEST(ConfigVersionPostgres, ADatabaseWrittenBeforeTheKeyedFormOpensWithTheSameValues) {
  std::string error;
  esg::testing::PostgresServer* pg = esg::testing::PostgresServer::Shared(&error);
  ASSERT_NE(pg, nullptr) << "the PostgreSQL test server cannot start: " << error;
  absl::StatusOr<std::string> uri = pg->CreateDatabase();
  ASSERT_TRUE(uri.ok()) << uri.status();
  DatabaseWrittenBeforeOpensWithTheSameValues(*uri);
}

}  // namespace
}  // namespace esg::server
