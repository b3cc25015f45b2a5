// Authentication and transport security of esgd (server/auth.h, docs/service.md "Security"):
// bearer tokens with read/write roles and caller names (scheme, token prefixes, file permissions,
// refusal logs without the token), and mutual TLS with certificates generated at test time by
// openssl.
#include "server/auth.h"

#include <sys/stat.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "grpcpp/security/credentials.h"
#include "grpcpp/test/server_context_test_spouse.h"
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
using ::esg::testing::WriteTokens;
using ::testing::HasSubstr;
using ::testing::Not;

// Writes a token file the way an operator must: mode 0600 (FromFile refuses anything looser).
// Runs Authenticate on a server context whose client metadata holds `authorization: <header>`
// (no such metadata when `header` is nullopt).
absl::StatusOr<std::string> AuthenticateWith(const TokenAuthorizer& auth,
                                             const std::optional<std::string>& header,
                                             Role role) {
  grpc::ServerContext context;
  grpc::testing::ServerContextTestSpouse spouse(&context);
  if (header.has_value()) spouse.AddClientMetadata("authorization", *header);
  return auth.Authenticate(context, role);
}

absl::Status CheckWith(const TokenAuthorizer& auth, const std::optional<std::string>& header,
                       Role role) {
  grpc::ServerContext context;
  grpc::testing::ServerContextTestSpouse spouse(&context);
  if (header.has_value()) spouse.AddClientMetadata("authorization", *header);
  return auth.Check(context, role);
}

TEST(TokenAuthorizer, ParsesRolesAndRejectsMalformedLines) {
  auto auth = TokenAuthorizer::Parse("# comment\nabc-0123456789abc read\n\nxyz-0123456789xyz read,write\n", "tokens");
  ASSERT_TRUE(auth.ok()) << auth.status();
  EXPECT_EQ(auth->size(), 2);
  EXPECT_TRUE(CheckWith(*auth, "Bearer abc-0123456789abc", Role::kRead).ok());
  EXPECT_THAT(CheckWith(*auth, "Bearer abc-0123456789abc", Role::kWrite),
              StatusIs(absl::StatusCode::kPermissionDenied, HasSubstr("write")));
  EXPECT_TRUE(CheckWith(*auth, "Bearer xyz-0123456789xyz", Role::kWrite).ok());
  EXPECT_THAT(CheckWith(*auth, std::nullopt, Role::kRead),
              StatusIs(absl::StatusCode::kUnauthenticated, HasSubstr("authorization")));
  EXPECT_THAT(CheckWith(*auth, "Bearer nope", Role::kRead),
              StatusIs(absl::StatusCode::kUnauthenticated, HasSubstr("unknown token")));
  EXPECT_THAT(TokenAuthorizer::Parse("abc admin\n", "f"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("f:1: unknown role of 5 bytes")));
  EXPECT_THAT(TokenAuthorizer::Parse("abc\n", "f"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("f:1")));
  EXPECT_THAT(TokenAuthorizer::Parse("a read x y\n", "f"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("f:1: expected")));
  EXPECT_THAT(TokenAuthorizer::Parse("aaaaaaaaaaaaaaaa read\naaaaaaaaaaaaaaaa write\n", "f"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("f:2: token repeated")));
  EXPECT_THAT(TokenAuthorizer::Parse("# only a comment\n", "f"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("f: no tokens")));
}

// Found by fuzz/fuzz_token_file.cc (docs/fuzzing.md, finding 1): an unknown role was quoted in
// the message, so a token written in the role's column ("read <token>", columns swapped) reached
// the error and the daemon's log. The fuzzer's input first, then the swapped columns.
// A 1-character token was accepted: a token is at least 16 characters, and the message says how
// to make one without quoting the short token.
TEST(TokenAuthorizer, ShortTokenIsRefusedWithTheLineNamed) {
  EXPECT_THAT(TokenAuthorizer::Parse("# ops\nx read,write ops\n", "tokens"),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("tokens:2: token of 1 characters, at least 16 needed")));
  const auto refused = TokenAuthorizer::Parse("ops-0123456789a read ops\n", "tokens");
  EXPECT_THAT(refused, StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("15 characters")));
  EXPECT_THAT(std::string(refused.status().message()), Not(HasSubstr("ops-0123456789a")));
  EXPECT_TRUE(TokenAuthorizer::Parse("ops-0123456789ab read ops\n", "tokens").ok());
}

TEST(TokenAuthorizer, UnknownRoleIsNotQuotedItMayBeAToken) {
  const std::string fuzzer_input("tok-a read[T\x01\x00@`\x00\x00riad\nGoke\n#f842*\x96", 35);
  const absl::StatusOr<TokenAuthorizer> fuzzed = TokenAuthorizer::Parse(fuzzer_input, "f");
  EXPECT_THAT(fuzzed, StatusIs(absl::StatusCode::kInvalidArgument,
                               HasSubstr("f:1: unknown role of 16 bytes")));
  EXPECT_THAT(std::string(fuzzed.status().message()), Not(HasSubstr("riad")));

  const absl::StatusOr<TokenAuthorizer> swapped =
      TokenAuthorizer::Parse("read 9f86d081884c7d659a2feaa0c55ad015 ops\n", "tokens");
  EXPECT_THAT(swapped, StatusIs(absl::StatusCode::kInvalidArgument,
                                HasSubstr("tokens:1: unknown role of 32 bytes")));
  EXPECT_THAT(std::string(swapped.status().message()), Not(HasSubstr("9f86d081")));
}

TEST(TokenAuthorizer, SchemeIsCaseInsensitiveWithOneOrMoreSpaces) {
  auto auth = TokenAuthorizer::Parse("abc-0123456789abc read\n", "tokens");
  ASSERT_TRUE(auth.ok()) << auth.status();
  for (const std::string header :
       {"Bearer abc-0123456789abc", "bearer abc-0123456789abc", "BEARER abc-0123456789abc",
        "bEaReR abc-0123456789abc", "Bearer   abc-0123456789abc"}) {
    EXPECT_TRUE(CheckWith(*auth, header, Role::kRead).ok()) << header;
  }
  for (const std::string header :
       {"Basic abc-0123456789abc", "Bearerabc-0123456789abc", "Bearer", "Bearer ",
        "Bearer\tabc-0123456789abc", "Token abc-0123456789abc", "abc-0123456789abc"}) {
    EXPECT_THAT(CheckWith(*auth, header, Role::kRead),
                StatusIs(absl::StatusCode::kUnauthenticated, HasSubstr("expected `Bearer")))
        << header;
  }
}

TEST(TokenAuthorizer, PrefixOrExtensionOfARealTokenIsRefused) {
  auto auth = TokenAuthorizer::Parse("3f9c0a77ab21d4e8 read,write\n", "tokens");
  ASSERT_TRUE(auth.ok()) << auth.status();
  EXPECT_TRUE(CheckWith(*auth, "Bearer 3f9c0a77ab21d4e8", Role::kWrite).ok());
  for (const std::string token :
       {"3f9c0a77ab21d4e", "3f9c0a", "3", "3f9c0a77ab21d4e8x", "3F9C0A77AB21D4E8"}) {
    EXPECT_THAT(CheckWith(*auth, "Bearer " + token, Role::kRead),
                StatusIs(absl::StatusCode::kUnauthenticated, HasSubstr("unknown token")))
        << token;
  }
}

TEST(TokenAuthorizer, AuthenticateReturnsTheNameFromTheFileOrTheLineNumber) {
  const std::string name64(64, 'n');
  auto auth = TokenAuthorizer::Parse(
      "token-1-0123456789 read ops-console\n# comment\ntoken-2-0123456789\tread,write\n"
      "token-3-0123456789 write " +
          name64 + "\n",
      "tokens");
  ASSERT_TRUE(auth.ok()) << auth.status();
  EXPECT_EQ(auth->size(), 3);
  auto name = AuthenticateWith(*auth, "Bearer token-1-0123456789", Role::kRead);
  ASSERT_TRUE(name.ok()) << name.status();
  EXPECT_EQ(*name, "ops-console");
  name = AuthenticateWith(*auth, "bearer token-2-0123456789", Role::kWrite);
  ASSERT_TRUE(name.ok()) << name.status();
  EXPECT_EQ(*name, "token-3");  // no name on line 3
  name = AuthenticateWith(*auth, "Bearer token-3-0123456789", Role::kWrite);
  ASSERT_TRUE(name.ok()) << name.status();
  EXPECT_EQ(*name, name64);
  // Failures are the same as Check's, and the missing-role message names the caller.
  EXPECT_THAT(AuthenticateWith(*auth, "Bearer token-1-0123456789", Role::kWrite),
              StatusIs(absl::StatusCode::kPermissionDenied,
                       HasSubstr("token 'ops-console' lacks the 'write' role")));
  EXPECT_THAT(AuthenticateWith(*auth, "Bearer token-4-0123456789", Role::kRead),
              StatusIs(absl::StatusCode::kUnauthenticated, HasSubstr("unknown token")));
  EXPECT_THAT(AuthenticateWith(*auth, std::nullopt, Role::kRead),
              StatusIs(absl::StatusCode::kUnauthenticated, HasSubstr("missing")));

  // Names: at most 64 printable ASCII characters.
  EXPECT_THAT(TokenAuthorizer::Parse("aaaaaaaaaaaaaaaa read\nbbbbbbbbbbbbbbbb read " + name64 + "x\n", "f"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("f:2: name must be")));
  EXPECT_THAT(TokenAuthorizer::Parse("a read bad\x01name\n", "f"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("f:1: name must be")));
  EXPECT_THAT(TokenAuthorizer::Parse("a read caf\xc3\xa9\n", "f"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("f:1: name must be")));
  // Two tokens of one caller (rotation) may share a name.
  auto rotated = TokenAuthorizer::Parse("old-token-0123456 read ingest\nnew-token-0123456 read ingest\n", "f");
  ASSERT_TRUE(rotated.ok()) << rotated.status();
  EXPECT_EQ(*AuthenticateWith(*rotated, "Bearer old-token-0123456", Role::kRead), "ingest");
  EXPECT_EQ(*AuthenticateWith(*rotated, "Bearer new-token-0123456", Role::kRead), "ingest");
}

TEST(TokenAuthorizer, FromFileRefusesAFileGroupOrOthersCanUse) {
  namespace fs = std::filesystem;
  TempDir dir;
  const std::string path = dir.File("tokens");
  std::ofstream(path) << "abc-0123456789abc read ops\n";
  for (fs::perms mode : {fs::perms(0644), fs::perms(0640), fs::perms(0604), fs::perms(0620),
                         fs::perms(0602), fs::perms(0610), fs::perms(0601)}) {
    fs::permissions(path, mode, fs::perm_options::replace);
    char octal[8];
    std::snprintf(octal, sizeof(octal), "%04o", static_cast<unsigned>(mode));
    EXPECT_THAT(TokenAuthorizer::FromFile(path),
                StatusIs(absl::StatusCode::kFailedPrecondition,
                         HasSubstr("tokens: " + path +
                                   " is readable or writable by group/others (mode " + octal +
                                   "); chmod 600 it")))
        << octal;
  }
  for (fs::perms mode : {fs::perms(0600), fs::perms(0400)}) {
    fs::permissions(path, mode, fs::perm_options::replace);
    auto auth = TokenAuthorizer::FromFile(path);
    ASSERT_TRUE(auth.ok()) << auth.status();
    EXPECT_EQ(*AuthenticateWith(*auth, "Bearer abc-0123456789abc", Role::kRead), "ops");
  }

  // Not a regular file: a directory, a FIFO (refused without blocking on the open).
  const std::string subdir = dir.File("tokens.d");
  fs::create_directory(subdir);
  fs::permissions(subdir, fs::perms(0700), fs::perm_options::replace);
  EXPECT_THAT(TokenAuthorizer::FromFile(subdir),
              StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("not a regular file")));
  const std::string fifo = dir.File("tokens.fifo");
  ASSERT_EQ(::mkfifo(fifo.c_str(), 0600), 0);
  EXPECT_THAT(TokenAuthorizer::FromFile(fifo),
              StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("not a regular file")));
  EXPECT_THAT(TokenAuthorizer::FromFile(dir.File("absent")),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("cannot be read")));

  // The daemon refuses to start on such a file.
  fs::permissions(path, fs::perms(0644), fs::perm_options::replace);
  TempDir db_dir;
  ServerOptions options;
  options.listen = "127.0.0.1:0";
  options.db_path = db_dir.File("esg.db");
  options.tokens_file = path;
  EXPECT_THAT(EsgServer::Start(options).status(),
              StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("chmod 600")));
}

TEST(TokenAuthorizer, RefusalsAreLoggedWithTheReasonButNeverTheToken) {
  auto auth = TokenAuthorizer::Parse("reader-Qx7w9Kp2Lm read alice\n", "tokens");
  ASSERT_TRUE(auth.ok()) << auth.status();
  struct Case {
    std::optional<std::string> header;
    Role role;
    std::string reason;  // expected in the log line
    std::string secret;  // must not appear in it, nor its first 6 characters
  };
  const std::vector<Case> cases = {
      {std::nullopt, Role::kRead, "missing authorization metadata", ""},
      {"Basic Zm9vOmJhclNlY3JldA==", Role::kRead, "malformed scheme", "Zm9vOmJhclNlY3JldA=="},
      {"Bearer guess-Vr8sT3nB", Role::kRead, "unknown token", "guess-Vr8sT3nB"},
      {"Bearer reader-Qx7w9Kp2L", Role::kRead, "unknown token", "reader-Qx7w9Kp2L"},
      {"Bearer reader-Qx7w9Kp2Lm", Role::kWrite, "token 'alice' lacks the 'write' role",
       "reader-Qx7w9Kp2Lm"},
  };
  for (const Case& c : cases) {
    ::testing::internal::CaptureStderr();
    const absl::Status status = CheckWith(*auth, c.header, c.role);
    const std::string log = ::testing::internal::GetCapturedStderr();
    EXPECT_FALSE(status.ok()) << c.reason;
    EXPECT_THAT(log, HasSubstr("WARN"));
    EXPECT_THAT(log, HasSubstr("authorization refused"));
    EXPECT_THAT(log, HasSubstr(c.reason));
    EXPECT_EQ(std::count(log.begin(), log.end(), '\n'), 1) << log;  // one line per refusal
    if (!c.secret.empty()) {
      EXPECT_THAT(log, Not(HasSubstr(c.secret.substr(0, 6)))) << log;
      EXPECT_THAT(std::string(status.message()), Not(HasSubstr(c.secret.substr(0, 6))));
    }
  }
  // A granted call logs nothing.
  ::testing::internal::CaptureStderr();
  EXPECT_TRUE(CheckWith(*auth, "Bearer reader-Qx7w9Kp2Lm", Role::kRead).ok());
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "");
}

TEST(Auth, BearerTokensGuardEveryRpcByRole) {
  TempDir dir;
  WriteTokens(dir.File("tokens"), "reader-token-0123 read\nwriter-token-0123 read,write\n");
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
  EXPECT_EQ(configure("reader-token-0123").error_code(), grpc::StatusCode::PERMISSION_DENIED);
  ASSERT_TRUE(configure("writer-token-0123").ok());

  // Ingest with a read token: PERMISSION_DENIED; no token: UNAUTHENTICATED.
  esg::v1::TelemetryFrame frame;
  frame.set_spacecraft_id("AUTH-1");
  frame.set_sequence(1);
  auto denied = StreamFrames(*stub, {frame}, "reader-token-0123");
  EXPECT_EQ(denied.status.error_code(), grpc::StatusCode::PERMISSION_DENIED);
  EXPECT_TRUE(denied.acks.empty());
  EXPECT_EQ(StreamFrames(*stub, {frame}).status.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  auto allowed = StreamFrames(*stub, {frame}, "writer-token-0123");
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
  EXPECT_TRUE(get("reader-token-0123").ok());
  grpc::ClientContext ctx;
  ctx.AddMetadata("authorization", "Bearer reader-token-0123");
  esg::v1::AcknowledgeRequest ack;
  ack.set_spacecraft_id("AUTH-1");
  ack.set_sequence(1);
  ack.set_operator_name("x");
  esg::v1::Alert alert;
  EXPECT_EQ(stub->AcknowledgeAlert(&ctx, ack, &alert).error_code(),
            grpc::StatusCode::PERMISSION_DENIED);

  // The per-step estimates: read role, the unary call and the stream alike.
  auto history = [&](const std::string& token) {
    grpc::ClientContext c;
    if (!token.empty()) c.AddMetadata("authorization", "Bearer " + token);
    esg::v1::EstimateHistoryRequest request;
    request.set_spacecraft_id("AUTH-1");
    esg::v1::EstimateHistoryResponse response;
    return stub->GetEstimateHistory(&c, request, &response);
  };
  EXPECT_EQ(history("").error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(history("wrong").error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(history("reader-token-0123").ok());
  auto subscribe = [&](const std::string& token) {
    grpc::ClientContext c;
    if (!token.empty()) c.AddMetadata("authorization", "Bearer " + token);
    esg::v1::EstimateSubscription request;
    request.set_spacecraft_id("AUTH-1");
    request.set_replay_marker(true);
    auto reader = stub->SubscribeEstimates(&c, request);
    esg::v1::EstimateRecord first;
    if (!reader->Read(&first)) return reader->Finish();  // refused: the call's status
    c.TryCancel();
    reader->Finish();
    return first.replay_complete() ? grpc::Status::OK
                                   : grpc::Status(grpc::StatusCode::INTERNAL, "no marker");
  };
  EXPECT_EQ(subscribe("").error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(subscribe("reader-token-0123").ok());
}

// A console signs each operator in with their own token and acknowledges without a name: the
// alert is acknowledged under the token's name. Another operator's token (or a different name
// given explicitly) is refused by the first-acknowledgement rule.
TEST(Auth, AcknowledgementWithoutANameTakesTheCallersTokenName) {
  TempDir dir;
  WriteTokens(dir.File("tokens"),
              "alice-Tk3vR8zQ9x2b read,write alice\nbob-Wq9xL2mP7c4dz read,write bob\n"
              "view-Jd5nC1kS3p8q read viewer\n");
  ServerOptions options;
  options.tokens_file = dir.File("tokens");
  LoopbackServer server(options);
  auto stub = server.Stub();
  {
    grpc::ClientContext ctx;
    ctx.AddMetadata("authorization", "Bearer alice-Tk3vR8zQ9x2b");
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(
                        &ctx, ConfigureRequestFor(::esg::testing::ServerTestConfig("AUTH-ACK")), &r)
                    .ok());
  }
  storage::AlertRecord record;
  record.spacecraft_id = "AUTH-ACK";
  record.severity = "WARNING";
  record.reason = "INNOVATION_TEST";
  record.subsystem = "star_tracker";
  record.message = "a stored alert to acknowledge";
  absl::StatusOr<int64_t> sequence = server.core().storage().alerts().Append(record);
  ASSERT_TRUE(sequence.ok()) << sequence.status();

  auto acknowledge = [&](const std::string& token, const std::string& name, esg::v1::Alert* out) {
    grpc::ClientContext ctx;
    ctx.AddMetadata("authorization", "Bearer " + token);
    esg::v1::AcknowledgeRequest request;
    request.set_spacecraft_id("AUTH-ACK");
    request.set_sequence(*sequence);
    request.set_operator_name(name);
    return stub->AcknowledgeAlert(&ctx, request, out);
  };
  esg::v1::Alert alert;
  EXPECT_EQ(acknowledge("view-Jd5nC1kS3p8q", "", &alert).error_code(),
            grpc::StatusCode::PERMISSION_DENIED);
  ASSERT_TRUE(acknowledge("alice-Tk3vR8zQ9x2b", "", &alert).ok());
  EXPECT_EQ(alert.acknowledged_by(), "alice");
  // Alice again (by token or by her name): unchanged; Bob's token: refused naming alice.
  EXPECT_TRUE(acknowledge("alice-Tk3vR8zQ9x2b", "alice", &alert).ok());
  const grpc::Status by_bob = acknowledge("bob-Wq9xL2mP7c4dz", "", &alert);
  EXPECT_EQ(by_bob.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_THAT(by_bob.error_message(), HasSubstr("already acknowledged by 'alice'"));
  auto stored = server.core().storage().alerts().Get("AUTH-ACK", *sequence);
  ASSERT_TRUE(stored.ok()) << stored.status();
  EXPECT_EQ(stored->acknowledged_by, "alice");
}

TEST(Auth, RefusedCallIsLoggedWithThePeerAndTheCallerName) {
  TempDir dir;
  WriteTokens(dir.File("tokens"), "dash-Hk4vR8zQ6w1e read dashboard\n");
  ServerOptions options;
  options.tokens_file = dir.File("tokens");
  LoopbackServer server(options);
  ASSERT_NE(server.get(), nullptr);
  auto stub = server.Stub();
  auto configure = [&](const std::string& header) {
    grpc::ClientContext ctx;
    ctx.AddMetadata("authorization", header);
    esg::v1::ConfigureResponse r;
    return stub->ConfigureSpacecraft(
        &ctx, ConfigureRequestFor(::esg::testing::ServerTestConfig("AUTH-LOG")), &r);
  };
  // The server logs before it answers, so the line is in stderr when the call returns.
  ::testing::internal::CaptureStderr();
  const grpc::Status unknown = configure("Bearer dash-Hk4vR8zX");
  const grpc::Status denied = configure("bearer dash-Hk4vR8zQ6w1e");
  const std::string log = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(unknown.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(denied.error_code(), grpc::StatusCode::PERMISSION_DENIED);
  EXPECT_THAT(log, HasSubstr("authorization refused: peer ipv4:127.0.0.1:"));
  EXPECT_THAT(log, HasSubstr("unknown token"));
  EXPECT_THAT(log, HasSubstr("token 'dashboard' lacks the 'write' role"));
  EXPECT_THAT(log, Not(HasSubstr("Hk4vR8z"))) << log;
  EXPECT_THAT(denied.error_message(), Not(HasSubstr("Hk4vR8z")));
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
