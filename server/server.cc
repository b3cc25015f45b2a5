// Server assembly (see server.h, docs/service.md).
#include "server/server.h"

#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "grpcpp/ext/proto_server_reflection_plugin.h"
#include "grpcpp/health_check_service_interface.h"
#include "grpcpp/security/server_credentials.h"
#include "grpcpp/server_builder.h"
#include "server/log.h"

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

}  // namespace

absl::StatusOr<std::unique_ptr<EsgServer>> EsgServer::Start(const ServerOptions& options) {
  std::unique_ptr<EsgServer> s(new EsgServer());
  ASSIGN_OR_RETURN(std::shared_ptr<grpc::ServerCredentials> credentials, Credentials(options));
  if (!options.tokens_file.empty()) {
    ASSIGN_OR_RETURN(s->auth_, TokenAuthorizer::FromFile(options.tokens_file));
  }
  const std::filesystem::path parent = std::filesystem::path(options.db_path).parent_path();
  if (!parent.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(parent, ec);
    if (ec) {
      return absl::FailedPreconditionError(
          absl::StrCat("db: cannot create directory ", parent.string(), ": ", ec.message()));
    }
  }
  storage::DatabaseOptions db_options;
  db_options.synchronous = options.synchronous;
  ASSIGN_OR_RETURN(s->storage_, storage::Storage::Open(options.db_path, db_options));
  CoreOptions core_options = options.core;
  if (core_options.worker_threads <= 0) {
    core_options.worker_threads = std::max(2u, std::thread::hardware_concurrency());
  }
  ASSIGN_OR_RETURN(s->core_, EstimationCore::Start(s->storage_.get(), core_options));
  s->service_ = std::make_unique<EstimationServiceImpl>(s->core_.get(),
                                                        s->auth_ ? &*s->auth_ : nullptr);

  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(options.listen, credentials, &s->port_);
  builder.RegisterService(s->service_.get());
  // Keep idle alert streams open for hours: ping every 60 s, accept client pings without data as
  // often as every 30 s, allow pings with no call in flight; no max_connection_idle.
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS, 60000);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, 20000);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_PERMIT_WITHOUT_CALLS, 1);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MIN_RECV_PING_INTERVAL_WITHOUT_DATA_MS, 30000);
  builder.AddChannelArgument(GRPC_ARG_HTTP2_MAX_PINGS_WITHOUT_DATA, 0);
  builder.SetMaxReceiveMessageSize(64 * 1024 * 1024);
  s->server_ = builder.BuildAndStart();
  if (s->server_ == nullptr || s->port_ == 0) {
    s->core_->Stop(absl::ZeroDuration());
    return absl::UnavailableError(absl::StrCat("listen: cannot serve on ", options.listen));
  }
  if (grpc::HealthCheckServiceInterface* health = s->server_->GetHealthCheckService()) {
    health->SetServingStatus("esg.v1.EstimationService", true);
    // NOT_SERVING while storage cannot commit (docs/service.md "Storage faults").
    s->core_->SetStorageHealthListener([health](bool ok, const std::string&) {
      health->SetServingStatus("esg.v1.EstimationService", ok);
      health->SetServingStatus("", ok);
    });
  }
  Log("INFO", absl::StrCat("serving esg.v1.EstimationService on port ", s->port_, ", database ",
                           options.db_path, s->auth_ ? ", bearer tokens required" : "",
                           options.tls_cert_file.empty() ? ", plaintext"
                           : options.tls_client_ca_file.empty() ? ", TLS"
                                                                : ", mutual TLS"));
  return s;
}

void EsgServer::Shutdown(absl::Duration deadline, absl::Duration drain) {
  if (shut_down_) return;
  shut_down_ = true;
  if (grpc::HealthCheckServiceInterface* health = server_->GetHealthCheckService()) {
    health->Shutdown();
  }
  core_->alert_hub().CloseAll();
  server_->Shutdown(absl::ToChronoTime(absl::Now() + deadline));
  core_->Stop(drain);
  server_->Wait();
  Log("INFO", "stopped");
}

EsgServer::~EsgServer() {
  if (server_ != nullptr) Shutdown(absl::ZeroDuration(), absl::ZeroDuration());
}

}  // namespace esg::server
