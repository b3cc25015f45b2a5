// The gRPC metadata that routes a call by spacecraft (docs/service.md "Routing by spacecraft",
// docs/deploy.md): a call about one spacecraft carries `x-esg-spacecraft: <spacecraft id>`, the
// router (nginx, deploy/nginx/esg.conf) hashes on it, and esgd refuses what the call carries about
// another spacecraft. Client and server share this one spelling.
#ifndef ESG_PROTO_ROUTING_METADATA_H_
#define ESG_PROTO_ROUTING_METADATA_H_

namespace esg::proto_convert {

// gRPC metadata keys are lower case; nginx sees it as the HTTP/2 header `x-esg-spacecraft`,
// i.e. the variable $http_x_esg_spacecraft.
inline constexpr char kSpacecraftMetadataKey[] = "x-esg-spacecraft";

}  // namespace esg::proto_convert

#endif  // ESG_PROTO_ROUTING_METADATA_H_
