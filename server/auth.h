// Bearer-token authorisation of the service (docs/service.md "Security"): a token file maps each
// token to its roles, `read` (queries, predictions, alerts, history) and `write` (ingest,
// configuration, alert acknowledgement); each rpc checks the `authorization: Bearer <token>`
// metadata of the call before doing anything else.
#ifndef ESG_SERVER_AUTH_H_
#define ESG_SERVER_AUTH_H_

#include <string>
#include "absl/strings/string_view.h"

#include "absl/container/flat_hash_map.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "grpcpp/server_context.h"

namespace esg::server {

enum class Role { kRead = 1, kWrite = 2 };
const char* RoleName(Role role);

class TokenAuthorizer {
 public:
  // Parses a token file: one `TOKEN ROLE[,ROLE]` per line (roles `read`, `write`), blank lines and
  // lines starting with `#` ignored. InvalidArgument "<source>:<line>: <reason>" for a malformed
  // line, an unknown role, a repeated token, or a file without tokens.
  static absl::StatusOr<TokenAuthorizer> Parse(absl::string_view text, absl::string_view source);
  // NotFound if the file cannot be read; otherwise as Parse.
  static absl::StatusOr<TokenAuthorizer> FromFile(const std::string& path);

  // OK when the call carries `authorization: Bearer <token>` with a known token holding `role`.
  // Unauthenticated when the metadata is absent, malformed or names an unknown token;
  // PermissionDenied when the token lacks the role.
  absl::Status Check(const grpc::ServerContextBase& context, Role role) const;
  absl::Status CheckHeader(absl::string_view authorization, bool present, Role role) const;

  int size() const { return static_cast<int>(roles_.size()); }

 private:
  absl::flat_hash_map<std::string, int> roles_;  // token -> bit set of Role
};

}  // namespace esg::server

#endif  // ESG_SERVER_AUTH_H_
