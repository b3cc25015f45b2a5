// The metrics endpoint (see metrics_http.h).
#include "server/metrics_http.h"

#include <charconv>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "httplib.h"

namespace esg::server {

absl::StatusOr<std::unique_ptr<MetricsHttpServer>> MetricsHttpServer::Start(
    const std::string& listen, MetricsRegistry* registry) {
  const size_t colon = listen.rfind(':');
  if (colon == std::string::npos || colon + 1 == listen.size()) {
    return absl::InvalidArgumentError(
        absl::StrCat("metrics-listen: '", listen, "' is not a host:port address"));
  }
  std::string host = listen.substr(0, colon);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') {
    host = host.substr(1, host.size() - 2);
  }
  if (host.empty()) host = "0.0.0.0";
  const std::string port_text = listen.substr(colon + 1);
  int port = -1;
  const auto [end, error] =
      std::from_chars(port_text.data(), port_text.data() + port_text.size(), port);
  if (error != std::errc() || end != port_text.data() + port_text.size() || port < 0 ||
      port > 65535) {
    return absl::InvalidArgumentError(
        absl::StrCat("metrics-listen: port '", port_text, "' is not in 0..65535"));
  }

  std::unique_ptr<MetricsHttpServer> s(new MetricsHttpServer());
  s->http_ = std::make_unique<httplib::Server>();
  // Scrapes are rare and small: two threads, short timeouts.
  s->http_->new_task_queue = [] { return new httplib::ThreadPool(2); };
  s->http_->set_read_timeout(5, 0);
  s->http_->set_write_timeout(5, 0);
  s->http_->Get("/metrics", [registry](const httplib::Request&, httplib::Response& response) {
    response.set_content(registry->Render(), "text/plain; version=0.0.4; charset=utf-8");
  });
  s->port_ = port == 0 ? s->http_->bind_to_any_port(host) : port;
  if (s->port_ <= 0 || (port != 0 && !s->http_->bind_to_port(host, port))) {
    return absl::UnavailableError(absl::StrCat("metrics-listen: cannot serve on ", listen));
  }
  httplib::Server* http = s->http_.get();
  s->thread_ = std::thread([http] { http->listen_after_bind(); });
  // stop() only ends a server that is running: wait until it is (milliseconds).
  const absl::Time deadline = absl::Now() + absl::Seconds(10);
  while (!http->is_running() && absl::Now() < deadline) absl::SleepFor(absl::Milliseconds(1));
  return s;
}

void MetricsHttpServer::Stop() {
  if (!thread_.joinable()) return;
  http_->stop();
  thread_.join();
}

MetricsHttpServer::~MetricsHttpServer() { Stop(); }

}  // namespace esg::server
