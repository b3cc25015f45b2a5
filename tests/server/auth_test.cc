// Authentication and transport security of esgd (server/auth.h, docs/service.md "Security"):
// bearer tokens with read/write roles, and mutual TLS with certificates generated at test time
// by openssl.
#include "server/auth.h"

#include <cstdlib>
#include <fstream>

#include "gmock/gmock.h"
#include "grpcpp/security/credentials.h"
#include "gtest/gtest.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/status_matchers.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::LoopbackServer;
using ::esg::testing::StatusIs;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;

TEST(TokenAuthorizer, ParsesRolesAndRejectsMalformedLines) {
  auto auth = TokenAuthorizer::Parse("# comment\nabc read\n\nxyz read,write\n", "tokens");
  ASSERT_TRUE(auth.ok()) << auth.status();
  EXPECT_EQ(auth->size(), 2);
  EXPECT_TRUE(auth->CheckHeader("Bearer abc", true, Role::kRead).ok());
  EXPECT_THAT(auth->CheckHeader("Bearer abc", true, Role::kWrite),
              StatusIs(absl::StatusCode::kPermissionDenied, HasSubstr("write")));
  EXPECT_TRUE(auth->CheckHeader("Bearer xyz", true, Role::kWrite).ok());
  EXPECT_THAT(auth->CheckHeader("", false, Role::kRead),
              StatusIs(absl::StatusCode::kUnauthenticated, HasSubstr("authorization")));
  EXPECT_THAT(auth->CheckHeader("Bearer nope", true, Role::kRead),
              StatusIs(absl::StatusCode::kUnauthenticated, HasSubstr("unknown token")));
  EXPECT_THAT(auth->CheckHeader("Basic abc", true, Role::kRead),
              StatusIs(absl::StatusCode::kUnauthenticated, HasSubstr("Bearer")));
  EXPECT_THAT(TokenAuthorizer::Parse("abc admin\n", "f"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("f:1: unknown role 'admin'")));
  EXPECT_THAT(TokenAuthorizer::Parse("abc\n", "f"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("f:1")));
  EXPECT_THAT(TokenAuthorizer::Parse("a read\na write\n", "f"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("f:2: token repeated")));
}

TEST(Auth, BearerTokensGuardEveryRpcByRole) {
  TempDir dir;
  std::ofstream(dir.File("tokens")) << "reader-token read\nwriter-token read,write\n";
  ServerOptions options;
  options.tokens_file = dir.File("tokens");
  LoopbackServer server(options);
  auto stub = server.Stub();
  const auto config = ::esg::testing::ServerTestConfig("AUTH-1");

  auto configure = [&](const std::string& token) {
    grpc::ClientContext ctx;
    if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
    esg::v1::ConfigureResponse r;
    return stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(config), &r);
  };
  EXPECT_EQ(configure("").error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(configure("wrong").error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(configure("reader-token").error_code(), grpc::StatusCode::PERMISSION_DENIED);
  ASSERT_TRUE(configure("writer-token").ok());

  // Ingest with a read token: PERMISSION_DENIED; no token: UNAUTHENTICATED.
  esg::v1::TelemetryFrame frame;
  frame.set_spacecraft_id("AUTH-1");
  frame.set_sequence(1);
  auto denied = StreamFrames(*stub, {frame}, "reader-token");
  EXPECT_EQ(denied.status.error_code(), grpc::StatusCode::PERMISSION_DENIED);
  EXPECT_TRUE(denied.acks.empty());
  EXPECT_EQ(StreamFrames(*stub, {frame}).status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  auto allowed = StreamFrames(*stub, {frame}, "writer-token");
  EXPECT_TRUE(allowed.status.ok());
  EXPECT_EQ(allowed.acks.size(), 1u);

  // Queries need the read role.
  auto get = [&](const std::string& token) {
    grpc::ClientContext ctx;
    if (!token.empty()) ctx.AddMetadata("authorization", "Bearer " + token);
    esg::v1::GetSessionRequest request;
    request.set_spacecraft_id("AUTH-1");
    esg::v1::SessionInfo info;
    return stub->GetSession(&ctx, request, &info);
  };
  EXPECT_EQ(get("").error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(get("reader-token").ok());
  grpc::ClientContext ctx;
  ctx.AddMetadata("authorization", "Bearer reader-token");
  esg::v1::AcknowledgeRequest ack;
  ack.set_spacecraft_id("AUTH-1");
  ack.set_sequence(1);
  ack.set_operator_name("x");
  esg::v1::Alert alert;
  EXPECT_EQ(stub->AcknowledgeAlert(&ctx, ack, &alert).error_code(),
            grpc::StatusCode::PERMISSION_DENIED);
}

std::string ReadAll(const std::string& path) {
  std::ifstream in(path);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

// Generates a CA and a certificate signed by it (CN given, SAN IP 127.0.0.1) with openssl.
bool MakeCa(const TempDir& dir, const std::string& name) {
  const std::string p = dir.File(name);
  const std::string cmd = "openssl req -x509 -newkey rsa:2048 -nodes -days 2 -subj /CN=" + name +
                          " -keyout " + p + ".key -out " + p + ".crt >/dev/null 2>&1";
  return std::system(cmd.c_str()) == 0;
}
bool MakeCert(const TempDir& dir, const std::string& ca, const std::string& name) {
  const std::string p = dir.File(name);
  const std::string c = dir.File(ca);
  std::ofstream(p + ".ext") << "subjectAltName=IP:127.0.0.1,DNS:localhost\n";
  const std::string cmd =
      "openssl req -newkey rsa:2048 -nodes -subj /CN=" + name + " -keyout " + p + ".key -out " +
      p + ".csr >/dev/null 2>&1 && openssl x509 -req -in " + p + ".csr -CA " + c + ".crt -CAkey " +
      c + ".key -CAcreateserial -days 2 -extfile " + p + ".ext -out " + p + ".crt >/dev/null 2>&1";
  return std::system(cmd.c_str()) == 0;
}

TEST(Auth, MutualTlsAcceptsClientsOfTheConfiguredCaOnly) {
  if (std::system("openssl version >/dev/null 2>&1") != 0) GTEST_SKIP() << "openssl missing";
  TempDir dir;
  ASSERT_TRUE(MakeCa(dir, "ca") && MakeCa(dir, "rogue_ca"));
  ASSERT_TRUE(MakeCert(dir, "ca", "server") && MakeCert(dir, "ca", "client") &&
              MakeCert(dir, "rogue_ca", "rogue"));
  ServerOptions options;
  options.tls_cert_file = dir.File("server.crt");
  options.tls_key_file = dir.File("server.key");
  options.tls_client_ca_file = dir.File("ca.crt");
  LoopbackServer server(options);
  ASSERT_NE(server.get(), nullptr);

  auto call = [&](const std::string& client) {
    grpc::SslCredentialsOptions ssl;
    ssl.pem_root_certs = ReadAll(dir.File("ca.crt"));
    if (!client.empty()) {
      ssl.pem_cert_chain = ReadAll(dir.File(client + ".crt"));
      ssl.pem_private_key = ReadAll(dir.File(client + ".key"));
    }
    auto stub = esg::v1::EstimationService::NewStub(
        grpc::CreateChannel(server.address(), grpc::SslCredentials(ssl)));
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
    esg::v1::ListSessionsRequest request;
    esg::v1::ListSessionsResponse response;
    return stub->ListSessions(&ctx, request, &response);
  };
  EXPECT_TRUE(call("client").ok());
  EXPECT_EQ(call("rogue").error_code(), grpc::StatusCode::UNAVAILABLE);  // handshake refused
  EXPECT_EQ(call("").error_code(), grpc::StatusCode::UNAVAILABLE);       // no client cert
  // A plaintext client cannot talk to the TLS port either.
  auto plain = esg::v1::EstimationService::NewStub(
      grpc::CreateChannel(server.address(), grpc::InsecureChannelCredentials()));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  esg::v1::ListSessionsResponse response;
  EXPECT_FALSE(plain->ListSessions(&ctx, {}, &response).ok());
}

}  // namespace
}  // namespace esg::server
