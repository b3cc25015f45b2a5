// esgd: the ESG attitude estimation service (docs/service.md). Parses flags, starts EsgServer,
// waits for SIGTERM/SIGINT and shuts down gracefully (running calls get a deadline, the durable
// backlog is applied, checkpoints are committed).
#include <csignal>
#include <cstdint>
#include <cstdio>
#include <string>
#include <thread>

#include "CLI/CLI.hpp"
#include "grpc/support/log.h"
#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "server/log.h"
#include "server/memory_release.h"
#include "server/server.h"

namespace {

// gRPC's own log lines (its warnings and errors) through the server's logger, so that with
// --log-format json every line of stderr is one JSON object.
void GrpcLog(gpr_log_func_args* args) {
  const char* level = args->severity == GPR_LOG_SEVERITY_ERROR ? "ERROR"
                      : args->severity == GPR_LOG_SEVERITY_INFO ? "INFO"
                                                                : "WARN";
  esg::server::LogEvent(level, "grpc", args->message != nullptr ? args->message : "",
                        {{"file", args->file != nullptr ? args->file : ""}, {"line", args->line}});
}

// The flags esgd takes as text or in other units than ServerOptions (turned into options by
// ApplyFlags), with their defaults.
struct Flags {
  std::string sync = "full";
  double shutdown_deadline_s = 5.0;
  std::string log_format = "text";
  std::string reorder_window = "2h";
  std::string max_clock_lead = "5m";
  std::string estimate_retention = "720h";
  std::string lease_duration = "15s";
  std::string filter_commit_window = "25ms";
  int64_t queued_mb_per_caller = 0;
  int64_t queued_mb = 0;
  double auto_diagnosis_hours = 0.0;
  int64_t grpc_memory_mb = 0;
};

// Defines the serving flags (address, database, TLS, tokens, metrics, logs, storage, filter,
// sessions, shutdown) into options and flags.
void AddServingFlags(CLI::App& app, esg::server::ServerOptions& options, Flags& flags) {
  app.add_option("--listen", options.listen, "Address to serve on, host:port")
      ->capture_default_str();
  app.add_option("--db", options.db_path,
                 "SQLite database file (directories are created), or a PostgreSQL connection URI "
                 "postgresql://user@host:port/database (docs/service.md \"Storage backends\")")
      ->capture_default_str();
  app.add_option("--tls-cert", options.tls_cert_file, "Server certificate chain (PEM)");
  app.add_option("--tls-key", options.tls_key_file, "Server private key (PEM)");
  app.add_option("--tls-client-ca", options.tls_client_ca_file,
                 "CA bundle (PEM) for client certificates: enables mutual TLS");
  app.add_option("--tokens", options.tokens_file,
                 "Bearer-token file, lines `TOKEN ROLE[,ROLE]` (roles read, write)");
  app.add_option("--metrics-listen", options.metrics_listen,
                 "Serve Prometheus metrics over HTTP at host:port (GET /metrics); off by default");
  app.add_option("--log-format", flags.log_format,
                 "Log lines on stderr: text or json (one object a line)")
      ->check(CLI::IsMember({"text", "json"}))
      ->capture_default_str();
  app.add_option("--sync", flags.sync,
                 "SQLite synchronous mode: full (power-loss safe acks) or normal")
      ->check(CLI::IsMember({"full", "normal"}))
      ->capture_default_str();
  app.add_option("--workers", options.core.worker_threads,
                 "Filter worker threads (0: one per core, at least 2)")
      ->capture_default_str();
  app.add_option("--filter-commit-group", options.core.filter_commit_group,
                 "PostgreSQL: filter jobs of different spacecraft committed in one transaction, "
                 "each in its own savepoint, at most this many (above --workers; 0: each job "
                 "alone; docs/deploy.md \"Capacity\")")
      ->capture_default_str();
  app.add_option("--filter-commit-window", flags.filter_commit_window,
                 "With --filter-commit-group: how long the first job of a group waits for others "
                 "to join it, e.g. 25ms, 0 (delays the estimates, never an ack)")
      ->capture_default_str();
  app.add_option("--reorder-window", flags.reorder_window,
                 "How late a frame may arrive (before the last accepted one) and still be applied "
                 "in time order by a re-run, e.g. 2h, 90m, 0 (refuse late frames)")
      ->capture_default_str();
  app.add_option("--max-clock-lead", flags.max_clock_lead,
                 "How far ahead of this server's clock a frame's time may be (further: refused "
                 "OUT_OF_RANGE), e.g. 5m, 30s")
      ->capture_default_str();
  app.add_option("--estimate-retention", flags.estimate_retention,
                 "How long per-step estimates are kept, in measurement time before the newest "
                 "estimate of their spacecraft, e.g. 720h (30 days), 48h, 0 (keep everything)")
      ->capture_default_str();
  app.add_option("--node-id", options.core.node_id,
                 "This server's name among several sharing one PostgreSQL database (session "
                 "leases, docs/service.md \"Several servers\"); default <hostname>:<listen port>");
  app.add_option("--lease-duration", flags.lease_duration,
                 "How long a session lease lasts without renewal (PostgreSQL): how long the "
                 "sessions of a server that died wait before another server takes them, e.g. 15s")
      ->capture_default_str();
  app.add_option("--shutdown-deadline", flags.shutdown_deadline_s,
                 "Seconds running calls get to finish at shutdown")
      ->capture_default_str();
}

// Defines the limit flags into options and flags, their defaults those of options.
void AddLimitFlags(CLI::App& app, esg::server::ServerOptions& options, Flags& flags) {
  // Limits (docs/service.md "Limits"); EsgServer::Start checks the values.
  app.add_option("--max-predictions-per-caller", options.calls.max_predictions_per_caller,
                 "Concurrent predictions (PredictAttitude, PredictAttitudeStream) of one "
                 "caller (token name, else peer address)")
      ->capture_default_str();
  app.add_option("--max-predictions", options.calls.max_predictions,
                 "Concurrent predictions (PredictAttitude, PredictAttitudeStream) in total "
                 "(also the prediction threads)")
      ->capture_default_str();
  app.add_option("--max-diagnoses-per-caller", options.calls.max_diagnoses_per_caller,
                 "Concurrent Diagnose calls of one caller")
      ->capture_default_str();
  app.add_option("--max-diagnoses", options.calls.max_diagnoses,
                 "Concurrent Diagnose calls in total")
      ->capture_default_str();
  app.add_option("--max-subscriptions-per-caller", options.calls.max_subscriptions_per_caller,
                 "Concurrent SubscribeAlerts and SubscribeEstimates streams of one caller")
      ->capture_default_str();
  app.add_option("--max-subscriptions", options.calls.max_subscriptions,
                 "Concurrent SubscribeAlerts and SubscribeEstimates streams in total")
      ->capture_default_str();
  app.add_option("--max-exports-per-caller", options.calls.max_exports_per_caller,
                 "Concurrent ExportCoefficientHistory and ExportTelemetry streams of one caller")
      ->capture_default_str();
  app.add_option("--max-exports", options.calls.max_exports,
                 "Concurrent ExportCoefficientHistory and ExportTelemetry streams in total")
      ->capture_default_str();
  flags.queued_mb_per_caller = options.calls.max_queued_bytes_per_caller >> 20;
  app.add_option("--max-queued-mb-per-caller", flags.queued_mb_per_caller,
                 "Unread subscription messages one caller's streams hold, MiB (beyond: its "
                 "slowest stream is dropped)")
      ->check(CLI::Range(int64_t{1}, int64_t{1} << 30))
      ->capture_default_str();
  flags.queued_mb = options.calls.max_queued_bytes >> 20;
  app.add_option("--max-queued-mb", flags.queued_mb,
                 "Unread subscription messages all streams hold together, MiB (beyond: the "
                 "slowest streams are dropped)")
      ->check(CLI::Range(int64_t{1}, int64_t{1} << 30))
      ->capture_default_str();
  app.add_option("--max-stored-diagnoses", options.max_stored_diagnoses,
                 "Diagnoses kept per spacecraft (beyond: the oldest are deleted, the "
                 "service's own before the operators')")
      ->capture_default_str();
  app.add_option("--max-stored-orbits", options.max_stored_orbits,
                 "Orbit deliveries kept per spacecraft (beyond: the oldest uploads are deleted)")
      ->capture_default_str();
  flags.auto_diagnosis_hours = absl::ToDoubleHours(options.auto_diagnosis.span);
  app.add_option("--auto-diagnosis-hours", flags.auto_diagnosis_hours,
                 "Span of the service's own diagnosis of a MODEL_INCONSISTENT alert, hours of "
                 "telemetry up to the last frame (and the least telemetry between two of one "
                 "spacecraft under one configuration); 0: no automatic diagnosis")
      ->check(CLI::Range(0.0, 24.0 * 366))
      ->capture_default_str();
  app.add_option("--max-message-bytes", options.max_message_bytes,
                 "Largest request message in bytes (larger: RESOURCE_EXHAUSTED)")
      ->capture_default_str();
  app.add_option("--max-streams-per-connection", options.max_streams_per_connection,
                 "Concurrent calls per client connection (HTTP/2 max concurrent streams)")
      ->capture_default_str();
  flags.grpc_memory_mb = options.grpc_memory_bytes >> 20;
  app.add_option("--grpc-memory-mb", flags.grpc_memory_mb,
                 "Memory gRPC may use for connections and calls, MiB (grpc::ResourceQuota)")
      ->check(CLI::Range(int64_t{1}, int64_t{1} << 30))
      ->capture_default_str();
}

// The duration flags parsed into options (false, with a message on stderr, for one that is not a
// duration in its range), then the other flags turned into options.
bool ApplyFlags(const Flags& flags, esg::server::ServerOptions& options) {
  if (!absl::ParseDuration(flags.reorder_window, &options.core.reorder_window) ||
      options.core.reorder_window < absl::ZeroDuration()) {
    std::fprintf(stderr, "--reorder-window: '%s' is not a duration >= 0 (e.g. 2h, 90m, 0)\n",
                 flags.reorder_window.c_str());
    return false;
  }
  if (!absl::ParseDuration(flags.max_clock_lead, &options.core.max_clock_lead) ||
      options.core.max_clock_lead < absl::ZeroDuration()) {
    std::fprintf(stderr, "--max-clock-lead: '%s' is not a duration >= 0 (e.g. 5m, 30s)\n",
                 flags.max_clock_lead.c_str());
    return false;
  }
  if (!absl::ParseDuration(flags.estimate_retention, &options.core.estimate_retention) ||
      options.core.estimate_retention < absl::ZeroDuration()) {
    std::fprintf(stderr,
                 "--estimate-retention: '%s' is not a duration >= 0 (e.g. 720h, 48h, 0)\n",
                 flags.estimate_retention.c_str());
    return false;
  }
  if (!absl::ParseDuration(flags.lease_duration, &options.core.lease_duration) ||
      options.core.lease_duration < absl::Seconds(1)) {
    std::fprintf(stderr, "--lease-duration: '%s' is not a duration >= 1s (e.g. 15s, 1m)\n",
                 flags.lease_duration.c_str());
    return false;
  }
  if (!absl::ParseDuration(flags.filter_commit_window, &options.core.filter_commit_window) ||
      options.core.filter_commit_window < absl::ZeroDuration() ||
      options.core.filter_commit_window > absl::Seconds(1)) {
    std::fprintf(stderr,
                 "--filter-commit-window: '%s' is not a duration from 0 to 1s (e.g. 25ms, 0)\n",
                 flags.filter_commit_window.c_str());
    return false;
  }
  if (options.core.filter_commit_group < 0 || options.core.filter_commit_group > 256) {
    std::fprintf(stderr, "--filter-commit-group: %d is not from 0 to 256\n",
                 options.core.filter_commit_group);
    return false;
  }
  options.synchronous = flags.sync == "normal" ? esg::storage::Synchronous::kNormal
                                               : esg::storage::Synchronous::kFull;
  options.grpc_memory_bytes = flags.grpc_memory_mb << 20;
  options.auto_diagnosis.span = absl::Hours(flags.auto_diagnosis_hours);
  options.calls.max_queued_bytes_per_caller = flags.queued_mb_per_caller << 20;
  options.calls.max_queued_bytes = flags.queued_mb << 20;
  return true;
}

// Prints the bound port (and the metrics port) on stdout in one write.
void PrintPorts(const esg::server::EsgServer& server) {
  // Tests and scripts read the bound port from this line (and the metrics port from the next,
  // written with it).
  std::string ports = absl::StrCat("esgd listening on port ", server.port(), "\n");
  if (server.metrics_port() != 0) {
    absl::StrAppend(&ports, "esgd metrics on port ", server.metrics_port(), "\n");
  }
  std::fputs(ports.c_str(), stdout);
  std::fflush(stdout);
}

// Shuts the server down within the calls' deadline and the drain; a watchdog ends the process
// (exit 3, "shutdown_timeout") 15 s after both.
void ShutDownBounded(esg::server::EsgServer& server, double shutdown_deadline_s) {
  // Shutdown is bounded whatever storage does (a hung disk, a full one): running calls get
  // --shutdown-deadline, the filter's backlog 30 s; a watchdog ends the process 15 s after
  // both. Nothing acknowledged is lost by that: acks follow durable commits only.
  const absl::Duration calls = absl::Seconds(shutdown_deadline_s);
  const absl::Duration drain = absl::Seconds(30);
  std::thread([limit = calls + drain + absl::Seconds(15)] {
    absl::SleepFor(limit);
    esg::server::LogEvent("ERROR", "shutdown_timeout",
                          absl::StrCat("shutdown did not finish within ",
                                       absl::FormatDuration(limit),
                                       "; exiting without waiting for storage"));
    std::_Exit(3);
  }).detach();
  server.Shutdown(calls, drain);
}

}  // namespace

int main(int argc, char** argv) {
  esg::server::ConfigureMalloc();  // before the first large block (server/memory_release.h)
  esg::server::ServerOptions options;
  Flags flags;
  CLI::App app{"esgd: ESG attitude estimation service (gRPC esg.v1.EstimationService)"};
  AddServingFlags(app, options, flags);
  AddLimitFlags(app, options, flags);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  // Deadlock detection of absl::Mutex (on in Debian's build) costs a graph update per lock; the
  // lock order is documented in estimation_core.h and exercised by the tests.
  absl::SetMutexDeadlockDetectionMode(absl::OnDeadlockCycle::kIgnore);
  if (flags.log_format == "json") {
    esg::server::SetLogFormat(esg::server::LogFormat::kJson);
    gpr_set_log_function(GrpcLog);
  }
  if (!ApplyFlags(flags, options)) return 2;

  // Block the stop signals in every thread (gRPC's included), then wait for them here.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  absl::StatusOr<std::unique_ptr<esg::server::EsgServer>> server =
      esg::server::EsgServer::Start(options);
  if (!server.ok()) {
    esg::server::LogEvent("ERROR", "start_failed",
                          absl::StrCat("cannot start: ", server.status().ToString()));
    return 1;
  }
  PrintPorts(**server);

  int signal_number = 0;
  sigwait(&signals, &signal_number);
  esg::server::LogEvent("INFO", "stopping", absl::StrCat("signal ", signal_number, ": shutting down"),
                        {{"signal", signal_number}});
  ShutDownBounded(**server, flags.shutdown_deadline_s);
  return 0;
}
