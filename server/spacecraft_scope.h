// The spacecraft a call is scoped to by its `x-esg-spacecraft` metadata (docs/service.md
// "Routing by spacecraft"). A router in front of several esgd (nginx, deploy/nginx/esg.conf)
// sends every call with that metadata to the node that owns the spacecraft, so a call that names
// another spacecraft in its request, or a telemetry stream that carries another spacecraft's
// frame, would reach the wrong node: esgd refuses it instead of serving it there.
//
// Calls without the metadata are not scoped and behave as before routing existed.
#ifndef ESG_SERVER_SPACECRAFT_SCOPE_H_
#define ESG_SERVER_SPACECRAFT_SCOPE_H_

#include <map>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "grpcpp/server_context.h"
#include "grpcpp/support/string_ref.h"

namespace esg::server {

// The spacecraft the call's metadata names; empty when the call carries no x-esg-spacecraft.
// InvalidArgument "x-esg-spacecraft: ..." when the value is not a spacecraft identifier
// (estimator::ValidateIdentifier, empty included) or the key is repeated with different values.
absl::StatusOr<std::string> SpacecraftScope(
    const std::multimap<grpc::string_ref, grpc::string_ref>& client_metadata);

// OK when `scope` is empty (the call is not scoped) or equals `spacecraft_id`. Otherwise
// InvalidArgument "spacecraft_id: ..." naming both ids; an empty `spacecraft_id` (a request about
// every spacecraft, such as SubscribeAlerts for all) is outside every scope.
absl::Status CheckInScope(absl::string_view scope, absl::string_view spacecraft_id);

// Both steps for a call that names `spacecraft_id` in its request.
absl::Status CheckCallScope(const grpc::ServerContextBase& context,
                            absl::string_view spacecraft_id);

}  // namespace esg::server

#endif  // ESG_SERVER_SPACECRAFT_SCOPE_H_
