// Server assembly (see server.h, docs/service.md).
#include "server/server.h"

#include <netdb.h>
#include <sys/resource.h>
#include <sys/socket.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <climits>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include "absl/strings/str_cat.h"
#include "absl/synchronization/notification.h"
#include "estimator/status_macros.h"
#include "grpc/grpc.h"
#include "grpcpp/ext/proto_server_reflection_plugin.h"
#include "grpcpp/health_check_service_interface.h"
#include "grpcpp/resource_quota.h"
#include "grpcpp/security/server_credentials.h"
#include "grpcpp/server_builder.h"
#include "server/log.h"
#include "server/queue_budget.h"

namespace esg::server {
namespace {

absl::StatusOr<std::string> ReadFile(const std::string& path, absl::string_view what) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat(what, ": cannot read ", path));
  std::stringstream buffer;
  buffer << in.rdbuf();
  return buffer.str();
}

absl::StatusOr<std::shared_ptr<grpc::ServerCredentials>> Credentials(const ServerOptions& o) {
  if (o.tls_cert_file.empty() && o.tls_key_file.empty()) {
    if (!o.tls_client_ca_file.empty()) {
      return absl::InvalidArgumentError("tls-client-ca: needs --tls-cert and --tls-key");
    }
    return grpc::InsecureServerCredentials();
  }
  if (o.tls_cert_file.empty() || o.tls_key_file.empty()) {
    return absl::InvalidArgumentError("tls-cert/tls-key: give both or neither");
  }
  grpc::SslServerCredentialsOptions ssl;
  ASSIGN_OR_RETURN(std::string cert, ReadFile(o.tls_cert_file, "tls-cert"));
  ASSIGN_OR_RETURN(std::string key, ReadFile(o.tls_key_file, "tls-key"));
  ssl.pem_key_cert_pairs.push_back({key, cert});
  if (!o.tls_client_ca_file.empty()) {
    ASSIGN_OR_RETURN(ssl.pem_root_certs, ReadFile(o.tls_client_ca_file, "tls-client-ca"));
    ssl.client_certificate_request = GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY;
  }
  return grpc::SslServerCredentials(ssl);
}

absl::Status CheckLimits(const ServerOptions& o) {
  const std::pair<const char*, int64_t> at_least_one[] = {
      {"max_predictions_per_caller", o.calls.max_predictions_per_caller},
      {"max_predictions", o.calls.max_predictions},
      {"max_diagnoses_per_caller", o.calls.max_diagnoses_per_caller},
      {"max_diagnoses", o.calls.max_diagnoses},
      {"max_subscriptions_per_caller", o.calls.max_subscriptions_per_caller},
      {"max_subscriptions", o.calls.max_subscriptions},
      {"max_exports_per_caller", o.calls.max_exports_per_caller},
      {"max_exports", o.calls.max_exports},
      {"max_queued_bytes_per_caller", o.calls.max_queued_bytes_per_caller},
      {"max_queued_bytes", o.calls.max_queued_bytes},
      {"max_stored_diagnoses", o.max_stored_diagnoses},
      {"max_stored_orbits", o.max_stored_orbits},
      {"max_streams_per_connection", o.max_streams_per_connection},
      {"max_sync_threads", o.max_sync_threads},
  };
  for (const auto& [name, value] : at_least_one) {
    if (value < 1)
      return absl::InvalidArgumentError(absl::StrCat(name, ": must be >= 1, got ", value));
  }
  // Enough for the largest frame and any query; at most what gRPC's int takes.
  if (o.max_message_bytes < 64 * 1024 || o.max_message_bytes > INT_MAX) {
    return absl::InvalidArgumentError(absl::StrCat("max_message_bytes: must be in [65536, ",
                                                   INT_MAX, "], got ", o.max_message_bytes));
  }
  if (o.grpc_memory_bytes < 4 * o.max_message_bytes) {
    return absl::InvalidArgumentError(
        absl::StrCat("grpc_memory_bytes: must be at least 4 x max_message_bytes (",
                     4 * o.max_message_bytes, "), got ", o.grpc_memory_bytes));
  }
  if (o.auto_diagnosis.span < absl::ZeroDuration()) {
    return absl::InvalidArgumentError(
        absl::StrCat("auto_diagnosis_hours: must be >= 0, got ",
                     absl::ToDoubleHours(o.auto_diagnosis.span)));
  }
  if (o.handshake_timeout <= absl::ZeroDuration()) {
    return absl::InvalidArgumentError(absl::StrCat("handshake_timeout: must be > 0, got ",
                                                   absl::FormatDuration(o.handshake_timeout)));
  }
  return absl::OkStatus();
}

std::string LimitText(rlim_t value) {
  return value == RLIM_INFINITY ? std::string("unlimited") : absl::StrCat(value);
}

// Raises the soft RLIMIT_NOFILE to the hard limit and logs both: every connection holds a file
// descriptor, and gRPC 1.51 stops accepting for good once accept() fails with EMFILE
// (grpc/grpc#20418; docs/service.md "Limits").
void RaiseFileLimit() {
  rlimit limit{};
  if (getrlimit(RLIMIT_NOFILE, &limit) != 0) {
    LogEvent("WARN", "file_limit",
             absl::StrCat("file descriptors: getrlimit failed: ", std::strerror(errno)));
    return;
  }
  const rlim_t before = limit.rlim_cur;
  if (limit.rlim_cur != limit.rlim_max) {
    rlimit raised = limit;
    raised.rlim_cur = limit.rlim_max;
    if (raised.rlim_cur == RLIM_INFINITY) {
      // An unlimited hard limit: Linux takes at most fs.nr_open descriptors.
      std::ifstream nr_open("/proc/sys/fs/nr_open");
      rlim_t most = 0;
      if (nr_open >> most && most > limit.rlim_cur) raised.rlim_cur = most;
    }
    if (setrlimit(RLIMIT_NOFILE, &raised) == 0) {
      limit = raised;
    } else {
      LogEvent("WARN", "file_limit", absl::StrCat("file descriptors: cannot raise the soft limit from ",
                               LimitText(before), " to the hard limit ", LimitText(limit.rlim_max),
                               ": ", std::strerror(errno)));
    }
  }
  LogEvent("INFO", "file_limit",
      absl::StrCat("file descriptors: soft limit ", LimitText(limit.rlim_cur),
                   limit.rlim_cur != before ? absl::StrCat(" (raised from ", LimitText(before), ")")
                                            : std::string(),
                   ", hard limit ", LimitText(limit.rlim_max)));
}

// Why gRPC could not bind `listen` ("host:port", "[v6]:port"), found by binding a socket the way
// gRPC does (SO_REUSEADDR, no SO_REUSEPORT): "address already in use (is another esgd serving
// it?)" or the errno text; a generic text when the address does not resolve or binds now.
std::string BindFailure(const std::string& listen) {
  const size_t colon = listen.rfind(':');
  if (colon == std::string::npos) return "not a host:port address";
  std::string host = listen.substr(0, colon);
  const std::string port = listen.substr(colon + 1);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') {
    host = host.substr(1, host.size() - 2);
  }
  addrinfo hints{};
  hints.ai_socktype = SOCK_STREAM;
  hints.ai_flags = AI_PASSIVE;
  addrinfo* found = nullptr;
  if (getaddrinfo(host.empty() ? nullptr : host.c_str(), port.c_str(), &hints, &found) != 0) {
    return "the address does not resolve";
  }
  std::string reason = "gRPC could not bind it";
  for (addrinfo* a = found; a != nullptr; a = a->ai_next) {
    const int fd = socket(a->ai_family, a->ai_socktype | SOCK_CLOEXEC, a->ai_protocol);
    if (fd < 0) continue;
    const int one = 1;
    setsockopt(fd, SOL_SOCKET, SO_REUSEADDR, &one, sizeof one);
    const int bound = bind(fd, a->ai_addr, a->ai_addrlen);
    const int error = errno;
    close(fd);
    if (bound != 0) {
      reason = error == EADDRINUSE ? "address already in use (is another esgd serving it?)"
                                   : std::strerror(error);
      break;
    }
  }
  freeaddrinfo(found);
  return reason;
}

// Creates the directory of an SQLite database file (none for PostgreSQL); FailedPrecondition
// "db: cannot create directory ..." when that fails.
absl::Status CreateDatabaseDirectory(const std::string& db_path, bool postgres) {
  const std::filesystem::path parent =
      postgres ? std::filesystem::path() : std::filesystem::path(db_path).parent_path();
  if (!parent.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(parent, ec);
    if (ec) {
      return absl::FailedPreconditionError(
          absl::StrCat("db: cannot create directory ", parent.string(), ": ", ec.message()));
    }
  }
  return absl::OkStatus();
}

// The core's options: a node id only with PostgreSQL (InvalidArgument for an SQLite file), there
// <hostname>:<listen port> by default; worker threads one per core (at least 2) when 0.
absl::StatusOr<CoreOptions> CoreOptionsFor(const ServerOptions& options, bool postgres) {
  CoreOptions core_options = options.core;
  if (!postgres && !core_options.node_id.empty()) {
    return absl::InvalidArgumentError(
        "--node-id: session leases need a PostgreSQL --db (an SQLite file has one server)");
  }
  if (postgres && core_options.node_id.empty()) {
    // Stable across restarts of the same server, so a restart takes its own leases back at once.
    char host[256] = {};
    if (::gethostname(host, sizeof host - 1) != 0) std::snprintf(host, sizeof host, "esgd");
    const size_t colon = options.listen.rfind(':');
    core_options.node_id = absl::StrCat(
        host, ":", colon == std::string::npos ? options.listen : options.listen.substr(colon + 1));
  }
  if (core_options.worker_threads <= 0) {
    core_options.worker_threads = std::max(2u, std::thread::hardware_concurrency());
  }
  return core_options;
}

// The gRPC server's channel arguments (exclusive address, keepalive) and limits, with `quota`
// sized and set as its resource quota.
void ConfigureBuilder(const ServerOptions& options, grpc::ResourceQuota& quota,
                      grpc::ServerBuilder& builder) {
  // Exclusive ownership of the address: gRPC sets SO_REUSEPORT on Linux by default, which lets a
  // second esgd bind the same address and the kernel spread connections between the two.
  builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
  // Keep idle alert streams open for hours: ping every 60 s, accept client pings without data as
  // often as every 30 s, allow pings with no call in flight; no max_connection_idle.
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS, 60000);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, 20000);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS, 1);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MIN_RECV_PING_INTERVAL_WITHOUT_DATA_MS, 30000);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MAX_PINGS_WITHOUT_DATA, 0);
  // Limits (docs/service.md "Limits").
  builder.SetMaxReceiveMessageSize(static_cast<int>(options.max_message_bytes));
  builder.AddChannelArgument(GRPC_ARG_MAX_CONCURRENT_STREAMS, options.max_streams_per_connection);
  builder.AddChannelArgument(GRPC_ARG_SERVER_HANDSHAKE_TIMEOUT_MS,
                             static_cast<int>(std::min<int64_t>(
                                 absl::ToInt64Milliseconds(options.handshake_timeout), INT_MAX)));
  quota.Resize(static_cast<size_t>(options.grpc_memory_bytes));
  quota.SetMaxThreads(options.max_sync_threads);
  builder.SetResourceQuota(quota);
}

// The health service reports the estimation service SERVING, and NOT_SERVING while storage
// cannot commit (docs/service.md "Storage faults").
void ServeHealth(grpc::Server& server, EstimationCore& core) {
  if (grpc::HealthCheckServiceInterface* health = server.GetHealthCheckService()) {
    health->SetServingStatus("esg.v1.EstimationService", true);
    core.SetStorageHealthListener([health](bool ok, const std::string&) {
      health->SetServingStatus("esg.v1.EstimationService", ok);
      health->SetServingStatus("", ok);
    });
  }
}

// Logs the server's start ("started": port, database, authentication, transport) and its limits
// ("limits").
void LogStarted(const ServerOptions& options, int port, const std::string& database, bool tokens) {
  LogEvent("INFO", "started",
           absl::StrCat("serving esg.v1.EstimationService on port ", port, ", database ",
                        database,
                        tokens ? ", bearer tokens required" : "",
                        options.tls_cert_file.empty()        ? ", plaintext"
                        : options.tls_client_ca_file.empty() ? ", TLS"
                                                             : ", mutual TLS"),
           {{"port", port}, {"database", database}});
  LogEvent("INFO", "limits", absl::StrCat("limits: predictions ", options.calls.max_predictions_per_caller,
                           " per caller, ", options.calls.max_predictions, " in total; diagnoses ",
                           options.calls.max_diagnoses_per_caller, " per caller, ",
                           options.calls.max_diagnoses, " in total; subscriptions ",
                           options.calls.max_subscriptions_per_caller, " per caller, ",
                           options.calls.max_subscriptions, " in total; export streams ",
                           options.calls.max_exports_per_caller, " per caller, ",
                           options.calls.max_exports, " in total; unread subscription messages ",
                           ByteText(options.calls.max_queued_bytes_per_caller), " per caller, ",
                           ByteText(options.calls.max_queued_bytes), " in total; ",
                           options.max_stored_diagnoses, " stored diagnoses and ",
                           options.max_stored_orbits, " orbit deliveries per spacecraft; "
                           "automatic diagnosis ", options.auto_diagnosis.span > absl::ZeroDuration()
                               ? absl::StrCat("over ", absl::FormatDuration(options.auto_diagnosis.span))
                               : std::string("off"), "; "
                           "messages up to ",
                           options.max_message_bytes, " bytes; ",
                           options.max_streams_per_connection, " streams per connection"));
}

}  // namespace

absl::StatusOr<std::unique_ptr<EsgServer>> EsgServer::Start(const ServerOptions& options) {
  std::unique_ptr<EsgServer> s(new EsgServer());
  RETURN_IF_ERROR(CheckLimits(options));
  RaiseFileLimit();
  ASSIGN_OR_RETURN(std::shared_ptr<grpc::ServerCredentials> credentials, Credentials(options));
  if (!options.tokens_file.empty()) {
    ASSIGN_OR_RETURN(s->auth_, TokenAuthorizer::FromFile(options.tokens_file));
  }
  const bool postgres = storage::IsPostgresUri(options.db_path);
  RETURN_IF_ERROR(CreateDatabaseDirectory(options.db_path, postgres));
  storage::DatabaseOptions db_options;
  db_options.synchronous = options.synchronous;
  db_options.vfs = options.db_vfs;
  ASSIGN_OR_RETURN(s->storage_, storage::Storage::Open(options.db_path, db_options));
  s->storage_->diagnoses().set_max_per_spacecraft(options.max_stored_diagnoses);
  s->storage_->orbits().set_max_per_spacecraft(options.max_stored_orbits);
  ASSIGN_OR_RETURN(const CoreOptions core_options, CoreOptionsFor(options, postgres));
  ASSIGN_OR_RETURN(s->core_, EstimationCore::Start(s->storage_.get(), core_options));
  s->service_ = std::make_unique<EstimationServiceImpl>(
      s->core_.get(), s->auth_ ? &*s->auth_ : nullptr, options.calls, options.auto_diagnosis);

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(options.listen, credentials, &s->port_);
  builder.RegisterService(s->service_.get());
  grpc::ResourceQuota quota("esgd");
  ConfigureBuilder(options, quota, builder);
  s->server_ = builder.BuildAndStart();
  if (s->server_ == nullptr || s->port_ == 0) {
    s->core_->Stop(absl::ZeroDuration());
    return absl::UnavailableError(absl::StrCat("listen: cannot serve on ", options.listen, ": ",
                                               BindFailure(options.listen)));
  }
  if (!options.metrics_listen.empty()) {
    absl::StatusOr<std::unique_ptr<MetricsHttpServer>> metrics =
        MetricsHttpServer::Start(options.metrics_listen, &s->core_->metrics().registry);
    if (!metrics.ok()) {
      s->server_->Shutdown(absl::ToChronoTime(absl::Now()));
      s->core_->Stop(absl::ZeroDuration());
      return metrics.status();
    }
    s->metrics_ = std::move(*metrics);
    LogEvent("INFO", "metrics_serving",
             absl::StrCat("serving Prometheus metrics on http://", options.metrics_listen.substr(
                 0, options.metrics_listen.rfind(':')), ":", s->metrics_->port(), "/metrics"),
             {{"metricsPort", s->metrics_->port()}});
  }
  ServeHealth(*s->server_, *s->core_);
  s->log_flusher_ = std::make_unique<ThrottledLogFlusher>();
  LogStarted(options, s->port_, s->storage_->database().path(), s->auth_.has_value());
  return s;
}

void EsgServer::Shutdown(absl::Duration deadline, absl::Duration drain) {
  if (shut_down_) return;
  shut_down_ = true;
  if (grpc::HealthCheckServiceInterface* health = server_->GetHealthCheckService()) {
    health->Shutdown();
  }
  // A running automatic diagnosis stops at its next check and stores nothing.
  service_->auto_diagnosis().Stop();
  core_->alert_hub().CloseAll();
  core_->estimate_hub().CloseAll();
  // Ingest stops first, on every open stream: each sends the acks of what it queued once
  // committed (the committer runs until core_->Stop) and ends UNAVAILABLE with a retry delay, so
  // a station that streams continuously does not hold the shutdown for the whole deadline.
  core_->CloseIngest();
  if (metrics_ != nullptr) metrics_->Stop();
  // gRPC's shutdown also waits for every client connection to close, idle ones included: a
  // client that merely keeps its channel open would hold it for the whole deadline. Once none of
  // the service's calls is running, the remaining connections are closed (with gRPC's own
  // streams on them: health watches, reflection) instead; calls still running keep the deadline.
  const absl::Time calls_deadline = absl::Now() + deadline;
  absl::Notification shut_down;
  std::thread closer([this, calls_deadline, &shut_down] {
    while (!shut_down.HasBeenNotified()) {
      if (service_->calls().WaitIdle(calls_deadline)) {
        grpc_server_cancel_all_calls(server_->c_server());
      }
      // Again while Shutdown has not returned: a connection accepted meanwhile, or calls
      // finishing later.
      shut_down.WaitForNotificationWithTimeout(absl::Milliseconds(50));
      if (absl::Now() >= calls_deadline) break;
    }
  });
  server_->Shutdown(absl::ToChronoTime(calls_deadline));
  shut_down.Notify();
  closer.join();
  core_->Stop(drain);
  server_->Wait();
  if (log_flusher_ != nullptr) log_flusher_->Stop();  // the last counts of suppressed lines
  LogEvent("INFO", "stopped", "stopped");
}

EsgServer::~EsgServer() {
  if (server_ != nullptr) Shutdown(absl::ZeroDuration(), absl::ZeroDuration());
}

}  // namespace esg::server
