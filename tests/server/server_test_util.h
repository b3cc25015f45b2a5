// Helpers for the server and end-to-end tests: a real esgd (EsgServer) on 127.0.0.1:0 over a real
// SQLite file in a TempDir, a simulated paper-setup recording as esg.v1 frames, and a streaming
// client that sends frames and collects their acks over one StreamTelemetry call.
#ifndef ESG_TESTS_SERVER_SERVER_TEST_UTIL_H_
#define ESG_TESTS_SERVER_SERVER_TEST_UTIL_H_

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <memory>
#include <utility>
#include <string>
#include <thread>
#include <vector>

#include "esg/v1/estimation_service.grpc.pb.h"
#include "estimator/attitude_profile.h"
#include "estimator/simulator.h"
#include "grpcpp/create_channel.h"
#include "grpcpp/security/credentials.h"
#include "gtest/gtest.h"
#include "proto/convert.h"
#include "server/checkpoint_codec.h"
#include "server/server.h"
#include "storage/coefficient_store.h"
#include "storage/storage.h"
#include "tests/testing/paper_setup.h"
#include "tests/testing/temp_dir.h"

namespace esg::testing {

// The paper configuration with id `id`, C1/C2 held (k0 and misalignment estimated), as the proto.
inline estimator::SpacecraftConfig ServerTestConfig(const std::string& id) {
  estimator::SpacecraftConfig c = PaperConfig(/*estimate_c=*/true);
  c.spacecraft_id = id;
  return c;
}

struct SimulatedRun {
  estimator::SpacecraftConfig config;
  std::vector<esg::v1::TelemetryFrame> frames;  // sequences 1..n
};

// Simulates `spec` (its config, duration, seed and truths) over the paper's calibration profile
// as frames of spacecraft `id`, sequences 1..n.
inline SimulatedRun SimulateCalibrationRun(const std::string& id, estimator::SimulationSpec spec) {
  SimulatedRun run;
  run.config = spec.config;
  auto profile = estimator::MakeNamedProfile("calibration", spec.duration);
  EXPECT_TRUE(profile.ok()) << profile.status();
  spec.profile = *profile;
  auto result = estimator::Simulate(spec);
  EXPECT_TRUE(result.ok()) << result.status();
  int64_t sequence = 0;
  for (const estimator::TelemetryFrame& f : result->recording.frames) {
    run.frames.push_back(proto_convert::FrameToProto(f, id, ++sequence));
  }
  return run;
}

// Simulates `hours` of the paper's calibration profile (60 s frames, seeded) for spacecraft `id`
// with optional star-tracker outliers (probability per sample; 300-900 arcsec).
inline SimulatedRun SimulateRun(const std::string& id, double hours, uint64_t seed = 7,
                                double outlier_probability = 0.0) {
  estimator::SimulationSpec spec;
  spec.config = ServerTestConfig(id);
  spec.duration = estimator::HoursToSeconds(hours);
  spec.seed = seed;
  spec.star_tracker.outlier_probability = outlier_probability;
  spec.star_tracker.outlier_size = estimator::ArcsecToRad(300);
  return SimulateCalibrationRun(id, spec);
}

// One coefficient of a drift model as esgd sends it, by its index in theta (drift_model.h).
inline double TermDegH(const esg::v1::GyroDriftModel& model, int theta_index) {
  return proto_convert::DriftModelTermDegH(model, estimator::kFixedTerms[theta_index]);
}

inline esg::v1::ConfigureRequest ConfigureRequestFor(const estimator::SpacecraftConfig& config,
                                                     const std::string& model = "") {
  esg::v1::ConfigureRequest request;
  *request.mutable_config() = proto_convert::ConfigToProto(config);
  request.set_model(model);
  return request;
}

// Writes a tokens file (docs/service.md "Security") that only its owner can use, as esgd
// requires (mode 0600).
inline void WriteTokens(const std::string& path, const std::string& text) {
  std::ofstream(path) << text;
  std::filesystem::permissions(
      path, std::filesystem::perms::owner_read | std::filesystem::perms::owner_write,
      std::filesystem::perm_options::replace);
}

// An in-process server over a database in its own TempDir.
class LoopbackServer {
 public:
  explicit LoopbackServer(server::ServerOptions options = {}, std::string db_path = "") {
    options.listen = "127.0.0.1:0";
    options.db_path = db_path.empty() ? dir_.File("var/esg.db") : db_path;
    if (options.core.worker_threads <= 0) options.core.worker_threads = 2;
    auto started = server::EsgServer::Start(options);
    EXPECT_TRUE(started.ok()) << started.status();
    if (started.ok()) server_ = std::move(*started);
  }
  ~LoopbackServer() {
    if (server_) server_->Shutdown(absl::Seconds(1), absl::Seconds(1));
  }
  server::EsgServer* get() { return server_.get(); }
  server::EstimationCore& core() { return server_->core(); }
  std::string address() const { return "127.0.0.1:" + std::to_string(server_->port()); }
  std::unique_ptr<esg::v1::EstimationService::Stub> Stub() const {
    return esg::v1::EstimationService::NewStub(
        grpc::CreateChannel(address(), grpc::InsecureChannelCredentials()));
  }
  const TempDir& dir() const { return dir_; }

 private:
  TempDir dir_;
  std::unique_ptr<server::EsgServer> server_;
};

// Sends `frames` on one StreamTelemetry call while a second thread reads the acks; returns the
// acks and the final status. `token`: bearer token metadata when non-empty. `routed_by`: the
// x-esg-spacecraft routing metadata when non-empty (docs/service.md "Routing by spacecraft").
struct StreamResult {
  std::vector<esg::v1::TelemetryAck> acks;
  grpc::Status status;
};
inline StreamResult StreamFrames(esg::v1::EstimationService::Stub& stub,
                                 const std::vector<esg::v1::TelemetryFrame>& frames,
                                 const std::string& token = "",
                                 const std::string& routed_by = "") {
  grpc::ClientContext context;
  if (!token.empty()) context.AddMetadata("authorization", "Bearer " + token);
  if (!routed_by.empty()) context.AddMetadata("x-esg-spacecraft", routed_by);
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
  auto stream = stub.StreamTelemetry(&context);
  StreamResult result;
  std::thread reader([&] {
    esg::v1::TelemetryAck ack;
    while (stream->Read(&ack)) result.acks.push_back(ack);
  });
  for (const esg::v1::TelemetryFrame& f : frames) {
    if (!stream->Write(f)) break;
  }
  stream->WritesDone();
  reader.join();
  result.status = stream->Finish();
  return result;
}

// GetSession of `id` (expected to succeed).
inline esg::v1::SessionInfo Session(esg::v1::EstimationService::Stub& stub,
                                    const std::string& id) {
  grpc::ClientContext ctx;
  esg::v1::GetSessionRequest get;
  get.set_spacecraft_id(id);
  esg::v1::SessionInfo info;
  EXPECT_TRUE(stub.GetSession(&ctx, get, &info).ok());
  return info;
}

// The session values an uninterrupted offline run of `frames` under `model` ends with
// (EstimationSession::ExportCheckpoint), to compare with what the service stored.
inline std::vector<double> OfflineSessionValues(const estimator::SpacecraftConfig& config,
                                                const std::string& model,
                                                const std::vector<esg::v1::TelemetryFrame>& frames) {
  auto spec = estimator::ParseModel(model);
  EXPECT_TRUE(spec.ok()) << spec.status();
  auto session = estimator::EstimationSession::Create(config, estimator::SessionOptions{*spec});
  EXPECT_TRUE(session.ok()) << session.status();
  for (const esg::v1::TelemetryFrame& proto : frames) {
    auto frame = proto_convert::FrameFromProto(proto);
    EXPECT_TRUE(frame.ok()) << frame.status();
    EXPECT_TRUE(session->AddFrame(*frame).ok());
  }
  return session->ExportCheckpoint().values;
}

// One coefficient estimate of an offline run: after a measurement step, per gyro.
struct OfflineSnapshot {
  absl::Time time;
  int gyro_id = 0;
  std::vector<double> values;  // storage::ToCoefficientValues layout, SI
};

// The coefficient history an uninterrupted offline run of `frames` (in the order given) under
// `model` produces: what the service stores at each measurement step.
inline std::vector<OfflineSnapshot> OfflineCoefficientHistory(
    const estimator::SpacecraftConfig& config, const std::string& model,
    const std::vector<esg::v1::TelemetryFrame>& frames) {
  auto spec = estimator::ParseModel(model);
  EXPECT_TRUE(spec.ok()) << spec.status();
  auto session = estimator::EstimationSession::Create(config, estimator::SessionOptions{*spec});
  EXPECT_TRUE(session.ok()) << session.status();
  std::vector<OfflineSnapshot> out;
  for (const esg::v1::TelemetryFrame& proto : frames) {
    auto frame = proto_convert::FrameFromProto(proto);
    EXPECT_TRUE(frame.ok()) << frame.status();
    auto report = session->AddFrame(*frame);
    EXPECT_TRUE(report.ok()) << report.status();
    if (!report.ok() || !report->measurement_step) continue;
    for (const estimator::GyroEstimate& g : session->Gyros()) {
      out.push_back({frame->time, g.id, storage::ToCoefficientValues(g.coefficients,
                                                                     g.misalignment_b)});
    }
  }
  return out;
}

// The frames sorted by measurement time (the merged recording of several stations).
inline std::vector<esg::v1::TelemetryFrame> InTimeOrder(std::vector<esg::v1::TelemetryFrame> f) {
  std::stable_sort(f.begin(), f.end(), [](const auto& a, const auto& b) {
    return std::make_pair(a.time().seconds(), a.time().nanos()) <
           std::make_pair(b.time().seconds(), b.time().nanos());
  });
  return f;
}

// The session values of the checkpoint stored for `spacecraft_id` in the database at `db`
// (opened after the server stopped).
inline std::vector<double> StoredSessionValues(const std::string& db,
                                               const std::string& spacecraft_id) {
  auto storage = storage::Storage::Open(db);
  EXPECT_TRUE(storage.ok()) << storage.status();
  if (!storage.ok()) return {};
  auto record = (*storage)->sessions().GetCheckpoint(spacecraft_id);
  EXPECT_TRUE(record.ok()) << record.status();
  if (!record.ok()) return {};
  auto checkpoint = server::DecodeCheckpoint(record->state_blob);
  EXPECT_TRUE(checkpoint.ok()) << checkpoint.status();
  if (!checkpoint.ok() || !checkpoint->session.has_value()) return {};
  return checkpoint->session->values;
}

}  // namespace esg::testing

#endif  // ESG_TESTS_SERVER_SERVER_TEST_UTIL_H_
