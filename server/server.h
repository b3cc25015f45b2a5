// esgd as a library: opens the database, starts the EstimationCore and the gRPC server with the
// options of `esgd` (docs/service.md): listen address, TLS / mTLS, bearer tokens, SQLite
// synchronous mode, health checking, reflection, keepalive, and the resource limits
// (docs/service.md "Limits"). main.cc and the tests use it.
#ifndef ESG_SERVER_SERVER_H_
#define ESG_SERVER_SERVER_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "grpcpp/server.h"
#include "server/auth.h"
#include "server/estimation_core.h"
#include "server/estimation_service.h"
#include "server/log_throttle.h"
#include "server/metrics_http.h"
#include "storage/storage.h"

namespace esg::server {

struct ServerOptions {
  std::string listen = "127.0.0.1:50051";  // host:port; port 0 picks a free one
  std::string db_path = "./var/esg.db";    // parent directories are created
  storage::Synchronous synchronous = storage::Synchronous::kFull;
  // SQLite VFS to open the database through (empty: SQLite's default); tests inject storage
  // faults with one (tests/testing/fault_vfs.h).
  std::string db_vfs;
  // PEM files. With cert and key the server speaks TLS; with a client CA as well it requires and
  // verifies client certificates (mTLS).
  std::string tls_cert_file;
  std::string tls_key_file;
  std::string tls_client_ca_file;
  // Bearer tokens (server/auth.h); empty: no authentication.
  std::string tokens_file;
  // Prometheus metrics over HTTP, "host:port" (port 0 picks a free one); empty: not served
  // (docs/service.md "Metrics"). Plain HTTP without authentication: bind it to an address only
  // the monitoring system reaches.
  std::string metrics_listen;
  CoreOptions core;

  // ---- Limits (docs/service.md "Limits") ----
  // Concurrent calls (predictions, diagnoses, subscriptions, exports) per caller and in total,
  // and the unread subscription messages held.
  CallLimits calls;
  // Diagnoses stored per spacecraft (storage/diagnosis_store.h): beyond it the oldest are
  // deleted. About 9 KB each: 1000 hold some 9 MB per spacecraft.
  int64_t max_stored_diagnoses = 1000;
  // Orbit deliveries stored per spacecraft (storage/orbit_store.h): beyond it the oldest are
  // deleted. A day's OEM at 60 s is about 150 KB: 400 hold some 60 MB per spacecraft.
  int64_t max_stored_orbits = 400;
  // The service's own diagnosis of MODEL_INCONSISTENT alerts (server/auto_diagnosis.h): the span
  // it diagnoses (esgd --auto-diagnosis-hours; zero: none).
  AutoDiagnosisOptions auto_diagnosis;
  // Largest request message [bytes]; larger ones fail with RESOURCE_EXHAUSTED in gRPC before any
  // handler runs. 8 MiB holds a PredictRequest at the 100 000-sample limit with a planned
  // attitude (about 50 bytes a sample, 5 MB) and 100 000 explicit epochs (about 14 bytes each,
  // 1.4 MB). Telemetry frames have their own, much smaller bound (CoreOptions::max_frame_bytes).
  int64_t max_message_bytes = 8 << 20;
  // Concurrent streams (calls) per connection (HTTP/2 SETTINGS_MAX_CONCURRENT_STREAMS; RFC 9113
  // recommends no less than 100). Further calls wait in the client for a free stream.
  int max_streams_per_connection = 100;
  // Memory gRPC may take for its transports (buffers, call arenas) [bytes] (grpc::ResourceQuota).
  // Near it gRPC itself shrinks its flow-control windows and reclaims memory from connections
  // and calls (gRPC's behaviour; not exercised by our tests). It does not bound the number of
  // connections: gRPC 1.51 has no such option (docs/service.md "Limits").
  int64_t grpc_memory_bytes = int64_t{1} << 30;
  // Threads of the synchronous services (server reflection) at most (grpc::ResourceQuota).
  int max_sync_threads = 8;
  // A connection that does not complete its TLS and HTTP/2 handshake within this time is closed
  // (each open connection holds a file descriptor).
  absl::Duration handshake_timeout = absl::Seconds(20);
};

class EsgServer {
 public:
  // Raises the process's soft RLIMIT_NOFILE to its hard limit first (each connection holds a
  // file descriptor; see docs/service.md "Limits") and logs both. InvalidArgument for
  // inconsistent TLS options, a bad tokens file or a limit out of range (names the field);
  // NotFound for unreadable PEM files; storage errors of opening the database (Unavailable "db:
  // <path> is locked by another process (pid N ...)" when another esgd owns the file:
  // storage/sqlite_db.h "Owner lock"); Unavailable "listen: cannot serve on <address>: <why>"
  // if the address cannot be bound, also when another process serves it (SO_REUSEPORT is off);
  // the errors of MetricsHttpServer::Start for `metrics_listen`.
  static absl::StatusOr<std::unique_ptr<EsgServer>> Start(const ServerOptions& options);
  ~EsgServer();

  int port() const { return port_; }
  // The metrics endpoint's port; 0 without --metrics-listen.
  int metrics_port() const { return metrics_ != nullptr ? metrics_->port() : 0; }
  EstimationCore& core() { return *core_; }
  EstimationServiceImpl& service() { return *service_; }

  // Graceful stop: the automatic diagnosis is cancelled, alert streams are closed, the gRPC server stops accepting and waits for the
  // running calls up to `deadline` (then cancels them), the committer flushes, and the workers
  // apply the durable backlog for up to `drain` before they stop. Idempotent.
  void Shutdown(absl::Duration deadline = absl::Seconds(5), absl::Duration drain = absl::Seconds(10));

 private:
  EsgServer() = default;

  std::unique_ptr<storage::Storage> storage_;
  std::unique_ptr<EstimationCore> core_;
  std::optional<TokenAuthorizer> auth_;
  std::unique_ptr<EstimationServiceImpl> service_;
  std::unique_ptr<grpc::Server> server_;
  // Declared after core_: stopped (and destroyed) before the core whose metrics it serves.
  std::unique_ptr<MetricsHttpServer> metrics_;
  // Writes the summaries of throttled log lines (server/log_throttle.h) while the server runs.
  std::unique_ptr<ThrottledLogFlusher> log_flusher_;
  int port_ = 0;
  bool shut_down_ = false;
};

}  // namespace esg::server

#endif  // ESG_SERVER_SERVER_H_
