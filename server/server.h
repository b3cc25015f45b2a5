// esgd as a library: opens the database, starts the EstimationCore and the gRPC server with the
// options of `esgd` (docs/service.md): listen address, TLS / mTLS, bearer tokens, SQLite
// synchronous mode, health checking, reflection, keepalive. main.cc and the tests use it.
#ifndef ESG_SERVER_SERVER_H_
#define ESG_SERVER_SERVER_H_

#include <memory>
#include <optional>
#include <string>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "grpcpp/server.h"
#include "server/auth.h"
#include "server/estimation_core.h"
#include "server/estimation_service.h"
#include "storage/storage.h"

namespace esg::server {

struct ServerOptions {
  std::string listen = "127.0.0.1:50051";  // host:port; port 0 picks a free one
  std::string db_path = "./var/esg.db";    // parent directories are created
  storage::Synchronous synchronous = storage::Synchronous::kFull;
  // PEM files. With cert and key the server speaks TLS; with a client CA as well it requires and
  // verifies client certificates (mTLS).
  std::string tls_cert_file;
  std::string tls_key_file;
  std::string tls_client_ca_file;
  // Bearer tokens (server/auth.h); empty: no authentication.
  std::string tokens_file;
  CoreOptions core;
};

class EsgServer {
 public:
  // InvalidArgument for inconsistent TLS options or a bad tokens file; NotFound for unreadable
  // PEM files; storage errors of opening the database; Unavailable if the port cannot be bound.
  static absl::StatusOr<std::unique_ptr<EsgServer>> Start(const ServerOptions& options);
  ~EsgServer();

  int port() const { return port_; }
  EstimationCore& core() { return *core_; }

  // Graceful stop: alert streams are closed, the gRPC server stops accepting and waits for the
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
  int port_ = 0;
  bool shut_down_ = false;
};

}  // namespace esg::server

#endif  // ESG_SERVER_SERVER_H_
