// Bearer-token file parsing and the per-call role check (docs/service.md "Security").
#include "server/auth.h"

#include <fcntl.h>
#include <openssl/crypto.h>
#include <openssl/sha.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <set>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/time/clock.h"
#include "server/log.h"

namespace esg::server {
namespace {

// A caller name goes into log lines and per-caller keys: printable ASCII only, so it cannot
// forge a log line or hide characters.
bool IsValidName(absl::string_view name) {
  if (name.empty() || name.size() > static_cast<size_t>(TokenAuthorizer::kMaxNameLength)) {
    return false;
  }
  for (char c : name) {
    if (!absl::ascii_isgraph(static_cast<unsigned char>(c))) return false;
  }
  return true;
}

// The token of `Bearer <token>` (RFC 6750 section 2.1): the scheme compared case-insensitively
// (RFC 7235 section 2.1), then one or more spaces, then a non-empty token. nullopt if malformed.
std::optional<absl::string_view> BearerToken(absl::string_view header) {
  constexpr absl::string_view kScheme = "bearer";
  if (header.size() <= kScheme.size() ||
      !absl::EqualsIgnoreCase(header.substr(0, kScheme.size()), kScheme) ||
      header[kScheme.size()] != ' ') {
    return std::nullopt;
  }
  absl::string_view token = header.substr(kScheme.size());
  while (!token.empty() && token.front() == ' ') token.remove_prefix(1);
  token = absl::StripTrailingAsciiWhitespace(token);
  if (token.empty()) return std::nullopt;
  return token;
}

}  // namespace

static_assert(SHA256_DIGEST_LENGTH == 32, "TokenAuthorizer::Digest holds a SHA-256 digest");

const char* RoleName(Role role) { return role == Role::kRead ? "read" : "write"; }

TokenAuthorizer::Digest TokenAuthorizer::DigestOf(absl::string_view token) {
  Digest digest;
  SHA256(reinterpret_cast<const unsigned char*>(token.data()), token.size(), digest.data());
  return digest;
}

absl::StatusOr<TokenAuthorizer> TokenAuthorizer::Parse(absl::string_view text,
                                                       absl::string_view source) {
  TokenAuthorizer auth;
  std::set<Digest> seen;  // to refuse a repeated token
  int line_number = 0;
  for (absl::string_view raw : absl::StrSplit(text, '\n')) {
    ++line_number;
    const absl::string_view line = absl::StripAsciiWhitespace(raw);
    if (line.empty() || line.front() == '#') continue;
    const std::vector<absl::string_view> parts =
        absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty());
    if (parts.size() != 2 && parts.size() != 3) {
      return absl::InvalidArgumentError(absl::StrCat(source, ":", line_number,
                                                     ": expected `TOKEN ROLE[,ROLE] [NAME]`, got ",
                                                     parts.size(), " words"));
    }
    Entry entry;
    for (absl::string_view role : absl::StrSplit(parts[1], ',')) {
      if (role == "read") {
        entry.roles |= static_cast<int>(Role::kRead);
      } else if (role == "write") {
        entry.roles |= static_cast<int>(Role::kWrite);
      } else {
        // The word is not echoed: it may be a token written in the wrong column.
        return absl::InvalidArgumentError(absl::StrCat(
            source, ":", line_number, ": unknown role of ", role.size(),
            " bytes in the second word (use read, write; not shown, it may be a token)"));
      }
    }
    if (parts.size() == 3) {
      if (!IsValidName(parts[2])) {
        // The name is not echoed: it may hold characters unfit for a terminal or a log.
        return absl::InvalidArgumentError(absl::StrCat(
            source, ":", line_number, ": name must be 1 to ", kMaxNameLength,
            " printable ASCII characters without spaces (got ", parts[2].size(), " bytes)"));
      }
      entry.name = std::string(parts[2]);
    } else {
      entry.name = absl::StrCat("token-", line_number);
    }
    if (parts[0].size() < static_cast<size_t>(kMinTokenLength)) {
      return absl::InvalidArgumentError(absl::StrCat(
          source, ":", line_number, ": token of ", parts[0].size(), " characters, at least ",
          kMinTokenLength, " needed (make one with `openssl rand -hex 32`)"));
    }
    entry.digest = DigestOf(parts[0]);
    if (!seen.insert(entry.digest).second) {
      return absl::InvalidArgumentError(
          absl::StrCat(source, ":", line_number, ": token repeated"));
    }
    auth.tokens_.push_back(std::move(entry));
  }
  if (auth.tokens_.empty()) {
    return absl::InvalidArgumentError(absl::StrCat(source, ": no tokens"));
  }
  return auth;
}

absl::StatusOr<TokenAuthorizer> TokenAuthorizer::FromFile(const std::string& path) {
  // O_NONBLOCK: opening a FIFO must not hang the daemon before fstat refuses it. The checks run
  // on the open descriptor, so the file cannot be swapped between the check and the read.
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOCTTY | O_NONBLOCK);
  if (fd < 0) {
    return absl::NotFoundError(
        absl::StrCat("tokens file ", path, ": cannot be read (", std::strerror(errno), ")"));
  }
  struct FdCloser {
    int fd;
    ~FdCloser() { ::close(fd); }
  } closer{fd};
  struct stat st;
  if (::fstat(fd, &st) != 0) {
    return absl::NotFoundError(
        absl::StrCat("tokens file ", path, ": cannot be read (", std::strerror(errno), ")"));
  }
  if (!S_ISREG(st.st_mode)) {
    return absl::FailedPreconditionError(
        absl::StrCat("tokens: ", path, " is not a regular file"));
  }
  if ((st.st_mode & 077) != 0) {
    char mode[8];
    std::snprintf(mode, sizeof(mode), "%04o", static_cast<unsigned>(st.st_mode & 07777));
    return absl::FailedPreconditionError(absl::StrCat(
        "tokens: ", path, " is readable or writable by group/others (mode ", mode,
        "); chmod 600 it"));
  }
  std::string text;
  char buffer[4096];
  for (;;) {
    const ssize_t n = ::read(fd, buffer, sizeof(buffer));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      return absl::NotFoundError(
          absl::StrCat("tokens file ", path, ": cannot be read (", std::strerror(errno), ")"));
    }
    if (n == 0) break;
    text.append(buffer, static_cast<size_t>(n));
  }
  return Parse(text, path);
}

absl::StatusOr<std::string> TokenAuthorizer::AuthenticateHeader(
    std::optional<absl::string_view> authorization, Role role, absl::string_view peer) const {
  // One WARN line per refusal, throttled per address (server/auth_throttle.h). `reason` never
  // holds the presented header or token.
  auto refuse = [&](absl::Status status, absl::string_view reason) {
    const absl::Time now = absl::Now();
    const FailedAuthThrottle::Verdict verdict = throttle_->Refused(peer, now);
    throttle_->Log(peer, verdict,
                   absl::StrCat("authorization refused: peer ", peer.empty() ? "unknown" : peer,
                                ", ", RoleName(role), " call: ", reason),
                   {{"peer", peer}, {"role", RoleName(role)}}, now);
    if (verdict == FailedAuthThrottle::Verdict::kThrottled) {
      return absl::ResourceExhaustedError(absl::StrCat(
          "authorization: too many refused calls from this address (", reason,
          "); retry in a few seconds with a valid token"));
    }
    return status;
  };
  if (!authorization.has_value()) {
    return refuse(absl::UnauthenticatedError("authorization: missing `Bearer <token>` metadata"),
                  "missing authorization metadata");
  }
  const std::optional<absl::string_view> token = BearerToken(*authorization);
  if (!token.has_value()) {
    return refuse(absl::UnauthenticatedError("authorization: expected `Bearer <token>`"),
                  "malformed scheme (expected `Bearer <token>`)");
  }

  // Constant-time lookup. A hash map keyed by the token would compare the presented token with
  // a stored one by memcmp, which stops at the first differing byte, so a caller timing many
  // guesses could learn a real token byte by byte. Instead only SHA-256 digests are stored (the
  // tokens are not in memory after Parse), and the presented token's digest is compared with
  // every stored digest by CRYPTO_memcmp, whose time does not depend on the bytes, without
  // stopping at a match: the loop does the same work whatever the token, and its time depends on
  // the number of tokens only.
  const Digest digest = DigestOf(*token);
  const Entry* match = nullptr;
  for (const Entry& entry : tokens_) {
    const bool equal = CRYPTO_memcmp(digest.data(), entry.digest.data(), digest.size()) == 0;
    match = equal ? &entry : match;
  }
  if (match == nullptr) {
    return refuse(absl::UnauthenticatedError("authorization: unknown token"), "unknown token");
  }
  if ((match->roles & static_cast<int>(role)) == 0) {
    const std::string reason =
        absl::StrCat("token '", match->name, "' lacks the '", RoleName(role), "' role");
    return refuse(absl::PermissionDeniedError(absl::StrCat("authorization: ", reason)), reason);
  }
  return match->name;
}

absl::StatusOr<std::string> TokenAuthorizer::Authenticate(const grpc::ServerContextBase& context,
                                                          Role role) const {
  // grpc::ServerContextBase does not expose the rpc method on gRPC 1.51 (only the generic
  // contexts do), so the log line names the peer and the role asked for.
  const auto& metadata = context.client_metadata();
  auto it = metadata.find("authorization");
  std::optional<absl::string_view> header;
  if (it != metadata.end()) header = absl::string_view(it->second.data(), it->second.size());
  return AuthenticateHeader(header, role, context.peer());
}

absl::Status TokenAuthorizer::Check(const grpc::ServerContextBase& context, Role role) const {
  return Authenticate(context, role).status();
}

}  // namespace esg::server
