// Bearer-token authorisation of the service (docs/service.md "Security"): a token file maps each
// token to its roles, `read` (queries, predictions, alerts, history) and `write` (ingest,
// configuration, alert acknowledgement), and to the caller's name; each rpc checks the
// `authorization: Bearer <token>` metadata of the call before doing anything else.
//
// Secrets: only SHA-256 digests of the tokens are kept, a presented token is compared in constant
// time against every known digest, and no token (or part of one) is ever logged or returned in a
// status message.
#ifndef ESG_SERVER_AUTH_H_
#define ESG_SERVER_AUTH_H_

#include <array>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "grpcpp/server_context.h"
#include "server/auth_throttle.h"

namespace esg::server {

enum class Role { kRead = 1, kWrite = 2 };
const char* RoleName(Role role);

class TokenAuthorizer {
 public:
  // Longest caller name a token file may give [characters].
  static constexpr int kMaxNameLength = 64;
  // Shortest token a token file may hold [characters]: 16 random hexadecimal digits are 64 bits,
  // beyond guessing at any rate a network allows; docs/service.md asks for 32 random bytes
  // (`openssl rand -hex 32`). A 1-character token was accepted.
  static constexpr int kMinTokenLength = 16;

  // Parses a token file: one `TOKEN ROLE[,ROLE] [NAME]` per line, words separated by spaces or
  // tabs; TOKEN at least kMinTokenLength characters; roles `read`, `write`; NAME is the caller's name (1 to 64 printable ASCII characters
  // without spaces, default `token-<line number>`; two tokens may share a name, e.g. while a
  // caller's token is rotated). Blank lines and lines starting with `#` are ignored.
  // InvalidArgument "<source>:<line>: <reason>" for a malformed line, an unknown role, a bad
  // name, a repeated token, or a file without tokens. No message contains a token.
  static absl::StatusOr<TokenAuthorizer> Parse(absl::string_view text, absl::string_view source);
  // NotFound if the file cannot be opened; FailedPrecondition "tokens: <path> ..." if it is not a
  // regular file or if group or others have any permission on it (mode & 077 != 0; the fix is
  // `chmod 600`); otherwise as Parse.
  static absl::StatusOr<TokenAuthorizer> FromFile(const std::string& path);

  // OK with the caller's name when the call carries a known token holding `role`; errors as Check.
  absl::StatusOr<std::string> Authenticate(const grpc::ServerContextBase& context,
                                           Role role) const;

  // OK when the call carries `authorization: Bearer <token>` (scheme case-insensitive, then one
  // or more spaces) with a known token holding `role`. Unauthenticated when the metadata is
  // absent, malformed or names an unknown token; PermissionDenied when the token lacks the role.
  // Every failure logs one WARN line naming the peer and the reason, never the token, within
  // the peer's budget of refusals (FailedAuthThrottle); beyond it the failure is
  // ResourceExhausted "authorization: too many refused ..." and logged in a summary line.
  absl::Status Check(const grpc::ServerContextBase& context, Role role) const;

  int size() const { return static_cast<int>(tokens_.size()); }

 private:
  using Digest = std::array<unsigned char, 32>;  // SHA-256
  struct Entry {
    Digest digest;     // SHA-256 of the token; the token itself is not kept
    int roles = 0;     // bit set of Role
    std::string name;  // the caller's name
  };

  static Digest DigestOf(absl::string_view token);

  // Authenticate on the value of the `authorization` metadata (nullopt when the call has none);
  // `peer` names the caller in the log line of a failure.
  absl::StatusOr<std::string> AuthenticateHeader(std::optional<absl::string_view> authorization,
                                                 Role role, absl::string_view peer) const;

  std::vector<Entry> tokens_;
  // Refusals per peer address; shared by the calls (the authorizer itself is const to them).
  std::unique_ptr<FailedAuthThrottle> throttle_ = std::make_unique<FailedAuthThrottle>();
};

}  // namespace esg::server

#endif  // ESG_SERVER_AUTH_H_
