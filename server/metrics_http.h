// The HTTP endpoint of `esgd --metrics-listen ADDR` (docs/service.md "Metrics"): GET /metrics
// answers the registry's Prometheus text exposition; every other path 404. cpp-httplib serves it
// on two threads of its own, apart from gRPC's.
#ifndef ESG_SERVER_METRICS_HTTP_H_
#define ESG_SERVER_METRICS_HTTP_H_

#include <memory>
#include <string>
#include <thread>

#include "absl/status/statusor.h"
#include "server/metrics.h"

namespace httplib {
class Server;
}

namespace esg::server {

class MetricsHttpServer {
 public:
  // Binds `listen` ("host:port" or "[v6]:port"; port 0 picks a free one) and starts serving
  // `registry` (not owned; it must outlive the server). InvalidArgument "metrics-listen: ..." for
  // an address without a port; Unavailable "metrics-listen: cannot serve on ADDR" when it cannot
  // be bound (in use, no such interface).
  static absl::StatusOr<std::unique_ptr<MetricsHttpServer>> Start(const std::string& listen,
                                                                  MetricsRegistry* registry);
  // Stops and joins the server thread.
  ~MetricsHttpServer();
  void Stop();

  int port() const { return port_; }

 private:
  MetricsHttpServer() = default;

  std::unique_ptr<httplib::Server> http_;
  std::thread thread_;
  int port_ = 0;
};

}  // namespace esg::server

#endif  // ESG_SERVER_METRICS_HTTP_H_
