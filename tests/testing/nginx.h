// A real nginx as a child process, in front of esgd nodes, with the shipped configuration
// deploy/nginx/esg.conf (docs/deploy.md "Routing by spacecraft"): the file is copied into a temp
// dir with only its listen address and its upstream server addresses replaced, wrapped in a
// minimal nginx.conf whose paths all lie in that dir, and run in the foreground as
//   nginx -p DIR -c DIR/nginx.conf -g 'daemon off; pid DIR/nginx.pid; error_log stderr;'
// so nothing under /etc or /var is read or written. stderr goes to DIR/nginx.log; the access log
// (DIR/access.log) has one line per call: the x-esg-spacecraft value, the node, the status.
//
// The binary: $ESG_NGINX, else /usr/sbin/nginx or /usr/bin/nginx (Debian's package `nginx`,
// installed by scripts/install-deps.sh). NginxBinary() is empty when none is found; the tests
// then fail with that message rather than skip, since CI installs nginx.
#ifndef ESG_TESTS_TESTING_NGINX_H_
#define ESG_TESTS_TESTING_NGINX_H_

#include <arpa/inet.h>
#include <fcntl.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "gtest/gtest.h"
#include "tests/testing/free_port.h"
#include "tests/testing/run_process.h"

#ifndef ESG_SOURCE_DIR
#error "ESG_SOURCE_DIR must name the repository (deploy/nginx/esg.conf)"
#endif

namespace esg::testing {

inline std::string NginxBinary() {
  if (const char* env = std::getenv("ESG_NGINX"); env != nullptr && *env != '\0') {
    return access(env, X_OK) == 0 ? std::string(env) : std::string();
  }
  for (const char* candidate : {"/usr/sbin/nginx", "/usr/bin/nginx"}) {
    if (access(candidate, X_OK) == 0) return candidate;
  }
  return "";
}


// True once something accepts TCP connections on 127.0.0.1:port.
inline bool Accepts(int port) {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  address.sin_port = htons(static_cast<uint16_t>(port));
  const bool ok = connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0;
  close(fd);
  return ok;
}

// deploy/nginx/esg.conf with its `listen` line set to 127.0.0.1:listen_port and its upstream
// `server` addresses replaced, in order, by `nodes` (host:port). Fails the test when the shipped
// file does not have exactly one listen line and as many server lines as nodes: the test then
// no longer runs what is shipped.
inline std::string RoutingConfig(int listen_port, const std::vector<std::string>& nodes) {
  std::istringstream shipped(ReadFile(std::string(ESG_SOURCE_DIR) + "/deploy/nginx/esg.conf"));
  const std::regex listen_line(R"(^(\s*)listen\s+\d+\s+http2;)");
  const std::regex server_line(R"(^(\s*)server\s+[0-9.]+:\d+(\s.*)$)");
  std::string out;
  std::string line;
  int listens = 0;
  size_t servers = 0;
  while (std::getline(shipped, line)) {
    std::smatch m;
    if (std::regex_search(line, m, listen_line)) {
      line = m[1].str() + "listen 127.0.0.1:" + std::to_string(listen_port) + " http2;";
      ++listens;
    } else if (std::regex_match(line, m, server_line)) {
      if (servers < nodes.size()) line = m[1].str() + "server " + nodes[servers] + m[2].str();
      ++servers;
    }
    out += line + "\n";
  }
  EXPECT_EQ(listens, 1) << "deploy/nginx/esg.conf: expected one 'listen PORT http2;' line";
  EXPECT_EQ(servers, nodes.size())
      << "deploy/nginx/esg.conf: expected one upstream 'server ADDRESS:PORT ...;' line per node";
  return out;
}

class Nginx {
 public:
  // Starts nginx with RoutingConfig(port, nodes) in `dir` and waits until it accepts
  // connections (10 s at most).
  Nginx(const std::string& dir, const std::vector<std::string>& nodes) : dir_(dir) {
    const std::string binary = NginxBinary();
    if (binary.empty()) {
      ADD_FAILURE() << "nginx not found ($ESG_NGINX, /usr/sbin/nginx, /usr/bin/nginx): install "
                       "Debian's package nginx (scripts/install-deps.sh does)";
      return;
    }
    port_ = FreeLoopbackPort();
    std::filesystem::create_directories(dir_ + "/temp");
    // The workers run as an unprivileged user when nginx starts as root: they must reach the
    // temp paths below (the master creates them).
    chmod(dir_.c_str(), 0755);
    WriteFile(dir_ + "/esg.conf", RoutingConfig(port_, nodes));
    WriteFile(dir_ + "/nginx.conf",
              "worker_processes 1;\n"
              "events { worker_connections 512; }\n"
              "http {\n"
              "  log_format routing '$http_x_esg_spacecraft $upstream_addr $status "
              "$request_uri';\n"
              "  access_log " + dir_ + "/access.log routing;\n"
              "  client_body_temp_path " + dir_ + "/temp/body;\n"
              "  proxy_temp_path " + dir_ + "/temp/proxy;\n"
              "  fastcgi_temp_path " + dir_ + "/temp/fastcgi;\n"
              "  uwsgi_temp_path " + dir_ + "/temp/uwsgi;\n"
              "  scgi_temp_path " + dir_ + "/temp/scgi;\n"
              "  include " + dir_ + "/esg.conf;\n"
              "}\n");
    const std::string conf = dir_ + "/nginx.conf";
    const std::string globals = "daemon off; pid " + dir_ + "/nginx.pid; error_log stderr;";
    const std::string log = dir_ + "/nginx.log";
    pid_ = fork();
    if (pid_ == 0) {  // only async-signal-safe calls until exec
      const int err = open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      if (err >= 0) {
        dup2(err, STDERR_FILENO);
        dup2(err, STDOUT_FILENO);
      }
      execl(binary.c_str(), "nginx", "-p", dir_.c_str(), "-c", conf.c_str(), "-g",
            globals.c_str(), static_cast<char*>(nullptr));
      _exit(127);
    }
    const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(10);
    while (!Accepts(port_)) {
      int status = 0;
      if (waitpid(pid_, &status, WNOHANG) == pid_) {
        pid_ = -1;
        ADD_FAILURE() << "nginx exited at start: " << ReadFile(log);
        return;
      }
      if (std::chrono::steady_clock::now() > deadline) {
        ADD_FAILURE() << "nginx does not accept on port " << port_ << ": " << ReadFile(log);
        return;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(20));
    }
  }
  ~Nginx() {
    if (pid_ <= 0) return;
    kill(pid_, SIGTERM);  // fast shutdown: the master stops its workers
    int status = 0;
    waitpid(pid_, &status, 0);
  }
  Nginx(const Nginx&) = delete;
  Nginx& operator=(const Nginx&) = delete;

  bool running() const { return pid_ > 0; }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }
  std::string log() const { return ReadFile(dir_ + "/nginx.log"); }
  std::string access_log() const { return ReadFile(dir_ + "/access.log"); }

 private:
  std::string dir_;
  int port_ = 0;
  pid_t pid_ = -1;
};

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_NGINX_H_
