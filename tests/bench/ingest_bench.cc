// Service benchmarks (docs/service.md "Performance"): telemetry frames per second ingested
// through gRPC into live sessions with durable acks (SQLite synchronous FULL and NORMAL, and
// PostgreSQL on loopback with session leases: argument 2, with the server's write transactions
// per second as a counter), next to
// a bare gRPC streaming echo of the same messages in the same process (streams of 5761 frames,
// 4 simulated days); and the latency of a 6 h
// prediction at 60 s steps through PredictAttitude (p50/p99 as counters).
//   cmake --build <dir> --target esg_bench
//   <dir>/tests/bench/esg_bench --benchmark_filter='Ingest|Echo|Predict'
#include <libpq-fe.h>

#include <algorithm>
#include <chrono>
#include <cstdlib>
#include <deque>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/synchronization/mutex.h"
#include "benchmark/benchmark.h"
#include "echo_bench.grpc.pb.h"
#include "grpcpp/create_channel.h"
#include "grpcpp/server_builder.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/postgres_server.h"

namespace esg {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::SimulateRun;
using ::esg::testing::SimulatedRun;

const SimulatedRun& Run24h() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("BENCH", 24.0, 9));
  return *run;
}

// 4 days (5761 frames): long enough streams that the last commit's latency does not dominate.
const SimulatedRun& Run4d() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("BENCH", 96.0, 9));
  return *run;
}

// Streams frames and reads acks concurrently over one call; returns the number of acks.
template <typename Stub>
size_t StreamAll(Stub& stub, const std::vector<esg::v1::TelemetryFrame>& frames) {
  grpc::ClientContext context;
  auto stream = stub.Stream(&context);
  size_t acks = 0;
  std::thread reader([&] {
    esg::v1::TelemetryAck ack;
    while (stream->Read(&ack)) ++acks;
  });
  for (const auto& f : frames) stream->Write(f);
  stream->WritesDone();
  reader.join();
  stream->Finish();
  return acks;
}

// Adapts the EstimationService stub to StreamAll.
struct IngestStub {
  esg::v1::EstimationService::Stub* stub;
  auto Stream(grpc::ClientContext* c) { return stub->StreamTelemetry(c); }
};

// The next transaction id of the PostgreSQL server at `uri`: write transactions get ids in
// order, read-only ones none, so the difference over a run counts the writes (this query takes
// one id itself). Exact and immediate, unlike pg_stat_database, whose counters lag.
int64_t NextTransactionId(const std::string& uri) {
  PGconn* conn = PQconnectdb(uri.c_str());
  int64_t commits = -1;
  if (PQstatus(conn) == CONNECTION_OK) {
    PGresult* r = PQexec(conn, "SELECT pg_current_xact_id()::text::bigint");
    if (PQresultStatus(r) == PGRES_TUPLES_OK && PQntuples(r) == 1) {
      commits = std::strtoll(PQgetvalue(r, 0, 0), nullptr, 10);
    }
    PQclear(r);
  }
  PQfinish(conn);
  return commits;
}

void BM_IngestThroughGrpc(benchmark::State& state) {
  const SimulatedRun& run = Run4d();
  server::ServerOptions options;
  options.synchronous = state.range(0) == 1 ? storage::Synchronous::kFull
                                            : storage::Synchronous::kNormal;
  std::string db;
  const bool postgres = state.range(0) == 2;
  if (postgres) {
    std::string error;
    testing::PostgresServer* pg = testing::PostgresServer::Shared(&error);
    absl::StatusOr<std::string> uri =
        pg != nullptr ? pg->CreateDatabase() : absl::UnavailableError(error);
    if (!uri.ok()) {
      state.SkipWithError(std::string(uri.status().message()).c_str());
      return;
    }
    db = *uri;
    options.core.node_id = "bench";
  }
  testing::LoopbackServer server(options, db);
  const int64_t xid_before = postgres ? NextTransactionId(db) : 0;
  const auto wall_start = std::chrono::steady_clock::now();
  auto stub = server.Stub();
  int index = 0;
  size_t frames = 0;
  for (auto _ : state) {
    state.PauseTiming();
    const std::string id = "BENCH-" + std::to_string(index++);
    estimator::SpacecraftConfig config = run.config;
    config.spacecraft_id = id;
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(config), &r);
    std::vector<esg::v1::TelemetryFrame> batch = run.frames;
    for (auto& f : batch) f.set_spacecraft_id(id);
    state.ResumeTiming();
    IngestStub ingest{stub.get()};
    const size_t acks = StreamAll(ingest, batch);
    if (acks != batch.size()) state.SkipWithError("missing acks");
    frames += acks;
  }
  state.SetItemsProcessed(static_cast<int64_t>(frames));
  state.SetLabel(postgres ? "postgresql" : state.range(0) == 1 ? "sync=full" : "sync=normal");
  if (postgres) {
    // Ingest, filter, lease and configuration writes together, over the whole run (the
    // iterations' configuration included).
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - wall_start).count();
    state.counters["pg_write_txns_per_s"] =
        static_cast<double>(NextTransactionId(db) - xid_before - 1) / seconds;
  }
}
BENCHMARK(BM_IngestThroughGrpc)
    ->Arg(1)
    ->Arg(0)
    ->Arg(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// The baseline: a callback echo service answering each frame with an ack, pipelined like ingest.
class EchoService final : public esg::bench::EchoBench::CallbackService {
  grpc::ServerBidiReactor<esg::v1::TelemetryFrame, esg::v1::TelemetryAck>* Stream(
      grpc::CallbackServerContext*) override {
    class Reactor : public grpc::ServerBidiReactor<esg::v1::TelemetryFrame, esg::v1::TelemetryAck> {
     public:
      Reactor() { StartRead(&frame_); }
      void OnReadDone(bool ok) override {
        absl::MutexLock lock(&mu_);
        if (!ok) {
          reads_done_ = true;
          Next();
          return;
        }
        esg::v1::TelemetryAck ack;
        ack.set_spacecraft_id(frame_.spacecraft_id());
        ack.set_sequence(frame_.sequence());
        ack.set_highest_durable_sequence(frame_.sequence());
        ack.set_accepted(true);
        acks_.push_back(std::move(ack));
        Next();
        StartRead(&frame_);
      }
      void OnWriteDone(bool) override {
        absl::MutexLock lock(&mu_);
        writing_ = false;
        acks_.pop_front();
        Next();
      }
      void OnDone() override { delete this; }

     private:
      void Next() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
        if (writing_ || finished_) return;
        if (!acks_.empty()) {
          writing_ = true;
          StartWrite(&acks_.front());
        } else if (reads_done_) {
          finished_ = true;
          Finish(grpc::Status::OK);
        }
      }
      absl::Mutex mu_;
      esg::v1::TelemetryFrame frame_;
      std::deque<esg::v1::TelemetryAck> acks_;
      bool writing_ = false, reads_done_ = false, finished_ = false;
    };
    return new Reactor();
  }
};

void BM_EchoStream(benchmark::State& state) {
  const SimulatedRun& run = Run4d();
  EchoService service;
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
  builder.RegisterService(&service);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  auto stub = esg::bench::EchoBench::NewStub(grpc::CreateChannel(
      "127.0.0.1:" + std::to_string(port), grpc::InsecureChannelCredentials()));
  size_t frames = 0;
  for (auto _ : state) {
    const size_t acks = StreamAll(*stub, run.frames);
    if (acks != run.frames.size()) state.SkipWithError("missing acks");
    frames += acks;
  }
  state.SetItemsProcessed(static_cast<int64_t>(frames));
  server->Shutdown();
}
BENCHMARK(BM_EchoStream)->Unit(benchmark::kMillisecond)->UseRealTime();

// PredictAttitude for 6 h at 60 s (361 samples) after 6 h of calibration telemetry.
void BM_PredictSixHoursAt60s(benchmark::State& state) {
  const SimulatedRun& run = Run24h();
  testing::LoopbackServer server;
  auto stub = server.Stub();
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r);
  const std::vector<esg::v1::TelemetryFrame> frames(run.frames.begin(), run.frames.begin() + 361);
  IngestStub ingest{stub.get()};
  StreamAll(ingest, frames);
  if (!server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(120)).ok()) {
    state.SkipWithError("frames not applied");
    return;
  }
  esg::v1::PredictRequest request;
  request.set_spacecraft_id(run.config.spacecraft_id);
  const int64_t last_s = frames.back().time().seconds();
  request.mutable_from()->set_seconds(last_s + 60);
  request.mutable_to()->set_seconds(last_s + 6 * 3600);
  request.set_step_s(60);
  request.set_aem(state.range(0) == 1);
  std::vector<double> latencies_ms;
  for (auto _ : state) {
    grpc::ClientContext context;
    esg::v1::PredictResponse response;
    const absl::Time start = absl::Now();
    const grpc::Status status = stub->PredictAttitude(&context, request, &response);
    latencies_ms.push_back(absl::ToDoubleMilliseconds(absl::Now() - start));
    if (!status.ok() || response.samples_size() != 360) {
      state.SkipWithError(status.ok() ? "wrong sample count" : status.error_message().c_str());
      break;
    }
  }
  std::sort(latencies_ms.begin(), latencies_ms.end());
  if (!latencies_ms.empty()) {
    auto at = [&](double p) {
      return latencies_ms[std::min(latencies_ms.size() - 1,
                                   static_cast<size_t>(p * static_cast<double>(latencies_ms.size())))];
    };
    state.counters["p50_ms"] = at(0.50);
    state.counters["p99_ms"] = at(0.99);
  }
  state.SetLabel(state.range(0) == 1 ? "with AEM" : "samples only");
}
BENCHMARK(BM_PredictSixHoursAt60s)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond)
    ->UseRealTime()->Iterations(200);

}  // namespace
}  // namespace esg
