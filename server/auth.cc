// Bearer-token file parsing and the per-call role check (docs/service.md "Security").
#include "server/auth.h"

#include <fstream>
#include <sstream>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"

namespace esg::server {

const char* RoleName(Role role) { return role == Role::kRead ? "read" : "write"; }

absl::StatusOr<TokenAuthorizer> TokenAuthorizer::Parse(absl::string_view text,
                                                       absl::string_view source) {
  TokenAuthorizer auth;
  int line_number = 0;
  for (absl::string_view raw : absl::StrSplit(text, '\n')) {
    ++line_number;
    const absl::string_view line = absl::StripAsciiWhitespace(raw);
    if (line.empty() || line.front() == '#') continue;
    const std::vector<absl::string_view> parts =
        absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty());
    if (parts.size() != 2) {
      return absl::InvalidArgumentError(absl::StrCat(
          source, ":", line_number, ": expected `TOKEN ROLE[,ROLE]`, got ", parts.size(),
          " words"));
    }
    int roles = 0;
    for (absl::string_view role : absl::StrSplit(parts[1], ',')) {
      if (role == "read") {
        roles |= static_cast<int>(Role::kRead);
      } else if (role == "write") {
        roles |= static_cast<int>(Role::kWrite);
      } else {
        return absl::InvalidArgumentError(absl::StrCat(source, ":", line_number,
                                                       ": unknown role '", role,
                                                       "' (use read, write)"));
      }
    }
    if (!auth.roles_.emplace(std::string(parts[0]), roles).second) {
      return absl::InvalidArgumentError(
          absl::StrCat(source, ":", line_number, ": token repeated"));
    }
  }
  if (auth.roles_.empty()) {
    return absl::InvalidArgumentError(absl::StrCat(source, ": no tokens"));
  }
  return auth;
}

absl::StatusOr<TokenAuthorizer> TokenAuthorizer::FromFile(const std::string& path) {
  std::ifstream in(path);
  if (!in) return absl::NotFoundError(absl::StrCat("tokens file ", path, ": cannot be read"));
  std::stringstream buffer;
  buffer << in.rdbuf();
  return Parse(buffer.str(), path);
}

absl::Status TokenAuthorizer::CheckHeader(absl::string_view authorization, bool present,
                                          Role role) const {
  if (!present) {
    return absl::UnauthenticatedError("authorization: missing `Bearer <token>` metadata");
  }
  constexpr absl::string_view kPrefix = "Bearer ";
  if (!absl::StartsWith(authorization, kPrefix)) {
    return absl::UnauthenticatedError("authorization: expected `Bearer <token>`");
  }
  const std::string token(absl::StripAsciiWhitespace(authorization.substr(kPrefix.size())));
  auto it = roles_.find(token);
  if (it == roles_.end()) return absl::UnauthenticatedError("authorization: unknown token");
  if ((it->second & static_cast<int>(role)) == 0) {
    return absl::PermissionDeniedError(
        absl::StrCat("authorization: the token lacks the '", RoleName(role), "' role"));
  }
  return absl::OkStatus();
}

absl::Status TokenAuthorizer::Check(const grpc::ServerContextBase& context, Role role) const {
  const auto& metadata = context.client_metadata();
  auto it = metadata.find("authorization");
  if (it == metadata.end()) return CheckHeader("", false, role);
  return CheckHeader(absl::string_view(it->second.data(), it->second.size()), true, role);
}

}  // namespace esg::server
