// The real esgd as a child process (ESGD_PATH names the binary, $ESGD_BINARY overrides it): started on 127.0.0.1:0 (or the
// `listen` address given) over a database file, its port read from its "esgd listening on port N" line, stopped with a signal
// (SIGTERM for a graceful stop, SIGKILL for a crash). With `--metrics-listen` among the extra
// arguments, the metrics port is read from the "esgd metrics on port N" line written with it.
#ifndef ESG_TESTS_TESTING_DAEMON_H_
#define ESG_TESTS_TESTING_DAEMON_H_

#include <fcntl.h>
#include <poll.h>
#include <signal.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <memory>
#include <string>
#include <vector>

#include "esg/v1/estimation_service.grpc.pb.h"
#include "grpcpp/create_channel.h"
#include "grpcpp/security/credentials.h"
#include "gtest/gtest.h"

#ifndef ESGD_PATH
#error "ESGD_PATH must name the esgd binary"
#endif

namespace esg::testing {

// Limits the child runs under (0: inherited).
struct DaemonLimits {
  rlim_t soft_fds = 0;
  rlim_t hard_fds = 0;
};

class Daemon {
 public:
  Daemon(const std::string& db, const std::string& log, DaemonLimits limits = {},
         const std::vector<std::string>& extra_args = {},
         const std::string& listen = "127.0.0.1:0")
      : host_(listen.substr(0, listen.rfind(':'))) {
    std::vector<std::string> args = {"esgd", "--listen", listen, "--db", db, "--workers", "2"};
    bool metrics = false;
    for (const std::string& a : extra_args) {
      args.push_back(a);
      metrics = metrics || a == "--metrics-listen";
    }
    std::vector<char*> argv;
    for (std::string& a : args) argv.push_back(a.data());
    argv.push_back(nullptr);
    rlimit fds{};
    getrlimit(RLIMIT_NOFILE, &fds);
    if (limits.soft_fds != 0) fds.rlim_cur = limits.soft_fds;
    if (limits.hard_fds != 0) fds.rlim_max = limits.hard_fds;
    // $ESGD_BINARY, when set, runs another build (a before/after comparison); else ESGD_PATH.
    const char* other = std::getenv("ESGD_BINARY");
    const char* binary = other != nullptr && other[0] != '\0' ? other : ESGD_PATH;
    int out[2];
    EXPECT_EQ(pipe(out), 0);
    pid_ = fork();
    if (pid_ == 0) {  // only async-signal-safe calls until exec
      setrlimit(RLIMIT_NOFILE, &fds);
      dup2(out[1], STDOUT_FILENO);
      const int err = open(log.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      if (err >= 0) dup2(err, STDERR_FILENO);
      close(out[0]);
      execv(binary, argv.data());
      _exit(127);
    }
    close(out[1]);
    // Read "esgd listening on port N" (and "esgd metrics on port M").
    std::string line;
    pollfd p{out[0], POLLIN, 0};
    auto complete = [&] {
      const size_t metrics_at = line.find("metrics on port ");
      return line.find('\n') != std::string::npos &&
             (!metrics ||
              (metrics_at != std::string::npos && line.find('\n', metrics_at) != std::string::npos));
    };
    while (!complete() && poll(&p, 1, 30000) > 0) {
      char buffer[256];
      const ssize_t n = read(out[0], buffer, sizeof buffer);
      if (n <= 0) break;
      line.append(buffer, n);
    }
    close(out[0]);
    const size_t at = line.find("port ");
    EXPECT_NE(at, std::string::npos) << "esgd did not start: " << line;
    if (at != std::string::npos) port_ = std::stoi(line.substr(at + 5));
    if (const size_t m = line.find("metrics on port "); m != std::string::npos) {
      metrics_port_ = std::stoi(line.substr(m + 16));
    }
  }
  ~Daemon() { Stop(SIGTERM); }
  void Stop(int signal) {
    if (pid_ <= 0) return;
    kill(pid_, signal);
    int status = 0;
    waitpid(pid_, &status, 0);
    pid_ = -1;
  }
  std::unique_ptr<esg::v1::EstimationService::Stub> Stub() const {
    return esg::v1::EstimationService::NewStub(grpc::CreateChannel(
        address(), grpc::InsecureChannelCredentials()));
  }
  int port() const { return port_; }
  int metrics_port() const { return metrics_port_; }
  // The child's pid while it runs (for its CPU time in /proc), -1 once stopped.
  pid_t pid() const { return pid_; }
  std::string address() const { return host_ + ":" + std::to_string(port_); }

 private:
  std::string host_;
  pid_t pid_ = -1;
  int port_ = 0;
  int metrics_port_ = 0;
};

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_DAEMON_H_
