// Scoping a call to the spacecraft of its x-esg-spacecraft metadata (see spacecraft_scope.h).
#include "server/spacecraft_scope.h"

#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "estimator/spacecraft_config.h"
#include "proto/routing_metadata.h"

namespace esg::server {
namespace {

// A request's id is client input that may be no identifier at all: quoted short and escaped,
// like ValidateIdentifier does, so no control character or huge value reaches a message or log.
std::string Quoted(absl::string_view value) {
  const size_t limit = static_cast<size_t>(estimator::kIdentifierQuoteLength);
  return absl::StrCat("'", absl::CHexEscape(value.substr(0, limit)),
                      value.size() > limit ? "'..." : "'");
}

}  // namespace

absl::StatusOr<std::string> SpacecraftScope(
    const std::multimap<grpc::string_ref, grpc::string_ref>& client_metadata) {
  const auto [first, last] = client_metadata.equal_range(proto_convert::kSpacecraftMetadataKey);
  if (first == last) return std::string();
  const std::string scope(first->second.data(), first->second.size());
  if (absl::Status valid =
          estimator::ValidateIdentifier(scope, proto_convert::kSpacecraftMetadataKey);
      !valid.ok()) {
    return valid;
  }
  for (auto it = std::next(first); it != last; ++it) {
    const absl::string_view other(it->second.data(), it->second.size());
    if (other != scope) {
      // The router hashed on one of them: serving the call would guess which.
      return absl::InvalidArgumentError(
          absl::StrCat(proto_convert::kSpacecraftMetadataKey, ": given twice, ", Quoted(scope),
                       " and ", Quoted(other), "; a call is about one spacecraft"));
    }
  }
  return scope;
}

absl::Status CheckInScope(absl::string_view scope, absl::string_view spacecraft_id) {
  if (scope.empty() || spacecraft_id == scope) return absl::OkStatus();
  const std::string routed_by =
      absl::StrCat("'", scope, "', the spacecraft this call is routed by (metadata ",
                   proto_convert::kSpacecraftMetadataKey, ")");
  if (spacecraft_id.empty()) {
    return absl::InvalidArgumentError(
        absl::StrCat("spacecraft_id: empty (every spacecraft) in a call scoped to ", routed_by,
                     "; a call about every spacecraft carries no such metadata"));
  }
  return absl::InvalidArgumentError(absl::StrCat(
      "spacecraft_id: ", Quoted(spacecraft_id), " is not ", routed_by,
      "; a call with that metadata is about '", scope, "' only: send ", Quoted(spacecraft_id),
      " on a call of its own"));
}

absl::Status CheckCallScope(const grpc::ServerContextBase& context,
                            absl::string_view spacecraft_id) {
  absl::StatusOr<std::string> scope = SpacecraftScope(context.client_metadata());
  if (!scope.ok()) return scope.status();
  return CheckInScope(*scope, spacecraft_id);
}

}  // namespace esg::server
