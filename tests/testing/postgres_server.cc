#include "tests/testing/postgres_server.h"

#include <arpa/inet.h>
#include <fcntl.h>
#include <libpq-fe.h>
#include <netinet/in.h>
#include <pwd.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>
#include <utility>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "tests/testing/free_port.h"

namespace esg::testing {
namespace {

constexpr int kStartAttempts = 3;
// Names the fixture's file (Publish) under ctest.
constexpr char kFixtureVariable[] = "ESG_TEST_POSTGRES";
// CREATE DATABASE of a name that exists.
constexpr char kDuplicateDatabase[] = "42P04";

absl::Status NotOwned() {
  return absl::FailedPreconditionError(
      "the server is shared with other tests (the ctest fixture's): a test that kills or "
      "restarts its server uses PostgresServer::Own()");
}
constexpr char kDefaultBinDir[] = "/usr/lib/postgresql/15/bin";

std::string BinDir() {
  if (const char* env = std::getenv("ESG_PG_BINDIR"); env != nullptr && *env != '\0') return env;
  return kDefaultBinDir;
}

std::string ReadText(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// The last max_bytes of a file, for error messages.
std::string Tail(const std::string& path, size_t max_bytes = 3000) {
  std::string text = ReadText(path);
  if (text.size() > max_bytes) text = "..." + text.substr(text.size() - max_bytes);
  return text;
}

// Whether initdb and pg_ctl must run as the user `postgres` (they refuse to run as root).
bool RunAsPostgres() { return geteuid() == 0; }

struct CommandResult {
  int exit_code = -1;  // -1 when it did not exit normally or could not be started
  std::string output;  // stdout and stderr together
};

// Runs argv (argv[0] a path; no shell) in `cwd`, as the user postgres when RunAsPostgres(), with
// stdout and stderr written to log_path, and waits for it.
CommandResult RunCommand(const std::string& cwd, std::vector<std::string> argv,
                         const std::string& log_path) {
  if (RunAsPostgres()) {
    const char* runuser =
        access("/usr/sbin/runuser", X_OK) == 0 ? "/usr/sbin/runuser" : "/sbin/runuser";
    argv.insert(argv.begin(), {runuser, "-u", "postgres", "--"});
  }
  std::vector<char*> args;
  for (std::string& a : argv) args.push_back(a.data());
  args.push_back(nullptr);
  CommandResult result;
  const pid_t pid = fork();
  if (pid < 0) {
    result.output = absl::StrCat("fork: ", std::strerror(errno));
    return result;
  }
  if (pid == 0) {  // only async-signal-safe calls until exec
    const int in = open("/dev/null", O_RDONLY);
    const int out = open(log_path.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
    if (in < 0 || out < 0 || chdir(cwd.c_str()) != 0) _exit(126);
    dup2(in, STDIN_FILENO);
    dup2(out, STDOUT_FILENO);
    dup2(out, STDERR_FILENO);
    execv(args[0], args.data());
    _exit(127);
  }
  int status = 0;
  while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  result.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  result.output = Tail(log_path);
  return result;
}

std::string Describe(const std::vector<std::string>& argv) {
  std::string s;
  for (const std::string& a : argv) absl::StrAppend(&s, s.empty() ? "" : " ", a);
  return s;
}

// The fields of /proc/<pid>/stat after the command name: [0] is field 3 (state), [1] field 4
// (parent), [19] field 22 (start time); empty if the process is gone.
std::vector<std::string> StatFields(pid_t pid) {
  const std::string stat = ReadText(absl::StrCat("/proc/", pid, "/stat"));
  const size_t close_paren = stat.rfind(')');  // the command name may hold spaces and ')'
  std::vector<std::string> fields;
  if (close_paren == std::string::npos) return fields;
  std::istringstream rest(stat.substr(close_paren + 1));
  for (std::string field; rest >> field;) fields.push_back(field);
  return fields;
}

// The state letter of /proc/<pid>/stat ('Z' for a zombie) and its parent; false if it is gone.
bool ProcessState(pid_t pid, char* state, pid_t* parent) {
  const std::vector<std::string> fields = StatFields(pid);
  long ppid = 0;
  if (fields.size() < 2 || fields[0].size() != 1 || !absl::SimpleAtoi(fields[1], &ppid)) {
    return false;
  }
  *state = fields[0][0];
  *parent = static_cast<pid_t>(ppid);
  return true;
}

// Gone, or a zombie nobody reaped: either way it holds no files, sockets or shared memory.
bool Dead(pid_t pid) {
  char state = 0;
  pid_t parent = 0;
  return !ProcessState(pid, &state, &parent) || state == 'Z' || state == 'X';
}

std::vector<pid_t> ChildrenOf(pid_t parent_pid) {
  std::vector<pid_t> children;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator("/proc", ec)) {
    const std::string name = entry.path().filename().string();
    if (name.empty() || name.find_first_not_of("0123456789") != std::string::npos) continue;
    const pid_t pid = static_cast<pid_t>(std::stol(name));
    char state = 0;
    pid_t parent = 0;
    if (ProcessState(pid, &state, &parent) && parent == parent_pid) children.push_back(pid);
  }
  return children;
}

// Waits until every pid is Dead; false after `timeout`.
bool WaitDead(const std::vector<pid_t>& pids, std::chrono::milliseconds timeout) {
  const auto deadline = std::chrono::steady_clock::now() + timeout;
  while (true) {
    bool all = true;
    for (pid_t pid : pids) all = all && Dead(pid);
    if (all) return true;
    if (std::chrono::steady_clock::now() > deadline) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
}

// The start time of a process in clock ticks since boot (/proc/<pid>/stat field 22), which
// tells a process from a later one that reuses its pid; empty if it is gone or a zombie.
std::string StartTime(pid_t pid) {
  if (Dead(pid)) return "";
  const std::vector<std::string> fields = StatFields(pid);
  return fields.size() > 19 ? fields[19] : "";
}

// The owner record of a server's temp dir, `<dir>/owner`: "pid P start S", the process whose
// exit ends the server's use (PostgresServer::ReapStale).
constexpr char kOwnerFile[] = "/owner";

bool WriteOwner(const std::string& dir, pid_t pid) {
  std::ofstream out(dir + kOwnerFile, std::ios::trunc);
  out << "pid " << pid << " start " << StartTime(pid) << "\n";
  out.close();
  return static_cast<bool>(out);
}

// Whether the owner recorded in `dir` is still running; true when there is no record (a dir
// being made, or made before owners were recorded: left alone).
bool OwnerAlive(const std::string& dir) {
  if (access((dir + kOwnerFile).c_str(), F_OK) != 0) return true;
  std::istringstream in(ReadText(dir + kOwnerFile));
  std::string pid_key, start_key, start;
  long pid = 0;
  if (!(in >> pid_key >> pid >> start_key) || pid_key != "pid" || start_key != "start" ||
      pid <= 0) {
    return false;  // a torn or foreign record: nobody can own it
  }
  in >> start;
  return !start.empty() && StartTime(static_cast<pid_t>(pid)) == start;
}

struct SharedState {
  std::unique_ptr<PostgresServer> server;
  std::string error;
  pid_t owner_pid = 0;
};

SharedState* shared_state = nullptr;

void StopShared() {
  // A forked child (a death test) that exits must not stop its parent's server.
  if (shared_state != nullptr && getpid() == shared_state->owner_pid) shared_state->server.reset();
}

}  // namespace

PostgresServer::PostgresServer(std::string dir, std::string bin_dir)
    : dir_(std::move(dir)),
      data_dir_(dir_ + "/data"),
      bin_dir_(std::move(bin_dir)),
      owner_pid_(getpid()) {}

absl::StatusOr<std::unique_ptr<PostgresServer>> PostgresServer::Start() {
  const std::string bin_dir = BinDir();
  for (const char* tool : {"initdb", "pg_ctl", "postgres"}) {
    if (access((bin_dir + "/" + tool).c_str(), X_OK) != 0) {
      return absl::NotFoundError(
          absl::StrCat(bin_dir, "/", tool,
                       " not found or not executable: install Debian's postgresql-15 "
                       "(scripts/install-deps.sh does) or set $ESG_PG_BINDIR"));
    }
  }
  ReapStale();
  std::string pattern = "/tmp/esg-pg-XXXXXX";
  if (mkdtemp(pattern.data()) == nullptr) {
    return absl::InternalError(absl::StrCat("mkdtemp ", pattern, ": ", std::strerror(errno)));
  }
  // From here on the destructor removes the dir (running_ is false: nothing to stop yet).
  std::unique_ptr<PostgresServer> server(new PostgresServer(pattern, bin_dir));
  if (!WriteOwner(server->dir_, getpid())) {
    return absl::InternalError(absl::StrCat("cannot write ", server->dir_, kOwnerFile));
  }
  if (RunAsPostgres()) {
    const passwd* user = getpwnam("postgres");
    if (user == nullptr) {
      return absl::NotFoundError(
          "running as root, and there is no user `postgres` to run initdb and pg_ctl as "
          "(Debian's postgresql-15 creates it)");
    }
    if (chown(server->dir_.c_str(), user->pw_uid, user->pw_gid) != 0) {
      return absl::InternalError(
          absl::StrCat("chown ", server->dir_, " to postgres: ", std::strerror(errno)));
    }
  }

  const std::vector<std::string> initdb = {
      bin_dir + "/initdb", "-D", server->data_dir_, "-E", "UTF8",
      "--locale=C",        "-A", "trust",           "-U", "esg"};
  const CommandResult made = RunCommand(server->dir_, initdb, server->dir_ + "/initdb.log");
  if (made.exit_code != 0) {
    return absl::InternalError(
        absl::StrCat(Describe(initdb), " failed (exit ", made.exit_code, "):\n", made.output));
  }
  // Appended after initdb's own settings, so these win. The port is given per start (-p).
  // After a crash the server makes the whole data dir durable before recovery: one syncfs()
  // instead of an fsync() per file (9.7 s against 0.6 s with ten databases on a busy disk).
  std::ofstream conf(server->data_dir_ + "/postgresql.conf", std::ios::app);
  conf << "\n# esg::testing::PostgresServer\n"
       << "listen_addresses = '127.0.0.1'\n"
       << "unix_socket_directories = '" << server->data_dir_ << "'\n"
       << "fsync = on\n"
       << "synchronous_commit = on\n"
       << "full_page_writes = on\n"
       << "recovery_init_sync_method = syncfs\n";
  conf.close();
  if (!conf) {
    return absl::InternalError(
        absl::StrCat("cannot append to ", server->data_dir_, "/postgresql.conf"));
  }

  absl::Status started;
  for (int attempt = 0; attempt < kStartAttempts; ++attempt) {
    server->port_ = FreeLoopbackPort();
    if (server->port_ == 0) return absl::InternalError("no free TCP port on 127.0.0.1");
    started = server->StartOnPort();
    if (started.ok()) return server;
  }
  return started;
}

PostgresServer* PostgresServer::Own(std::string* error) {
  static SharedState* const state = [] {
    auto* s = new SharedState;
    s->owner_pid = getpid();
    absl::StatusOr<std::unique_ptr<PostgresServer>> started = Start();
    if (started.ok()) {
      s->server = *std::move(started);
    } else {
      s->error = started.status().ToString();
    }
    shared_state = s;
    std::atexit(StopShared);
    return s;
  }();
  if (error != nullptr) *error = state->error;
  return state->server.get();
}

PostgresServer* PostgresServer::Shared(std::string* error) {
  // Attached, never stopped here: the fixture's cleanup stops it after every test.
  static PostgresServer* const fixture = []() -> PostgresServer* {
    const char* path = std::getenv(kFixtureVariable);
    if (path == nullptr || *path == '\0') return nullptr;
    absl::StatusOr<std::unique_ptr<PostgresServer>> attached = Attach(path, /*take_over=*/false);
    if (!attached.ok()) {
      std::fprintf(stderr, "%s=%s: %s; starting a PostgreSQL server of this process instead\n",
                   kFixtureVariable, path, attached.status().ToString().c_str());
      return nullptr;
    }
    return attached->release();
  }();
  if (fixture != nullptr) {
    if (error != nullptr) error->clear();
    return fixture;
  }
  return Own(error);
}

absl::Status PostgresServer::Publish(const std::string& path) {
  if (!running_ || !owned_) {
    return absl::FailedPreconditionError("only a running server of this object can be published");
  }
  std::ofstream out(path, std::ios::trunc);
  out << "port " << port_ << "\n"
      << "dir " << dir_ << "\n";
  out.close();
  if (!out) return absl::InternalError(absl::StrCat("cannot write ", path));
  // The server outlives this process: its use ends with the parent's (ctest's, under the
  // fixture), whose cleanup fixture stops it; if that never runs, ReapStale does.
  if (!WriteOwner(dir_, getppid())) {
    return absl::InternalError(absl::StrCat("cannot write ", dir_, kOwnerFile));
  }
  owned_ = false;
  return absl::OkStatus();
}

absl::StatusOr<std::unique_ptr<PostgresServer>> PostgresServer::Attach(const std::string& path,
                                                                       bool take_over) {
  if (access(path.c_str(), R_OK) != 0) {
    return absl::NotFoundError(absl::StrCat("no PostgreSQL fixture file ", path));
  }
  std::istringstream in(ReadText(path));
  std::string port_key;
  std::string dir_key;
  int port = 0;
  std::string dir;
  if (!(in >> port_key >> port >> dir_key >> dir) || port_key != "port" || dir_key != "dir" ||
      port <= 0 || dir.rfind("/tmp/esg-pg-", 0) != 0) {
    return absl::InvalidArgumentError(
        absl::StrCat(path, ": not a PostgreSQL fixture file (port N, dir /tmp/esg-pg-...)"));
  }
  std::unique_ptr<PostgresServer> server(new PostgresServer(dir, BinDir()));
  server->port_ = port;
  server->running_ = true;
  server->owned_ = take_over;
  if (PQping(server->ConnInfo("postgres").c_str()) != PQPING_OK) {
    // Taken over, the object still stops whatever runs there and removes the dir.
    return absl::UnavailableError(
        absl::StrCat(path, ": the server on port ", port, " does not answer"));
  }
  return server;
}

PostgresServer::~PostgresServer() {
  if (getpid() != owner_pid_ || !owned_) return;
  if (running_) {
    // Immediate: the directory is deleted next, so the shutdown checkpoint (which writes every
    // test database out) would be wasted time.
    const CommandResult stopped = RunCommand(
        dir_, {bin_dir_ + "/pg_ctl", "-D", data_dir_, "-m", "immediate", "-w", "-t", "60", "stop"},
        dir_ + "/pg_ctl-stop.log");
    if (stopped.exit_code != 0) (void)Kill();
  }
  std::error_code ec;
  std::filesystem::remove_all(dir_, ec);
}

std::string PostgresServer::Uri(const std::string& database) const {
  return absl::StrCat("postgresql://esg@127.0.0.1:", port_, "/", database);
}

std::string PostgresServer::LogPath() const { return dir_ + "/server.log"; }

std::string PostgresServer::ConnInfo(const std::string& database) const {
  return Uri(database) + "?connect_timeout=10";
}

absl::Status PostgresServer::StartOnPort() {
  const std::vector<std::string> argv = {
      bin_dir_ + "/pg_ctl",       "-D",   data_dir_, "-l", LogPath(), "-w", "-t", "60", "-o",
      absl::StrCat("-p ", port_), "start"};
  const CommandResult started = RunCommand(dir_, argv, dir_ + "/pg_ctl-start.log");
  if (started.exit_code != 0) {
    // A postmaster that came up after pg_ctl gave up must not linger.
    RunCommand(dir_, {bin_dir_ + "/pg_ctl", "-D", data_dir_, "-m", "immediate", "-w", "stop"},
               dir_ + "/pg_ctl-stop.log");
    return absl::InternalError(absl::StrCat(Describe(argv), " failed (exit ", started.exit_code,
                                            "):\n", started.output, "\n--- ", LogPath(),
                                            " (tail) ---\n", Tail(LogPath())));
  }
  // pg_ctl -w waited for the postmaster's "ready"; check that TCP connections work as user esg.
  const std::string conninfo = ConnInfo("postgres");
  const auto deadline = std::chrono::steady_clock::now() + std::chrono::seconds(30);
  while (PQping(conninfo.c_str()) != PQPING_OK) {
    if (std::chrono::steady_clock::now() > deadline) {
      return absl::InternalError(absl::StrCat("started, but ", Uri("postgres"),
                                              " accepts no connections within 30 s\n--- ",
                                              LogPath(), " (tail) ---\n", Tail(LogPath())));
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(20));
  }
  running_ = true;
  return absl::OkStatus();
}

absl::StatusOr<std::string> PostgresServer::CreateDatabase() {
  std::unique_ptr<PGconn, decltype(&PQfinish)> conn(PQconnectdb(ConnInfo("postgres").c_str()),
                                                    &PQfinish);
  if (PQstatus(conn.get()) != CONNECTION_OK) {
    return absl::UnavailableError(
        absl::StrCat("connect to ", Uri("postgres"), ": ", PQerrorMessage(conn.get())));
  }
  for (;;) {
    const std::string name = absl::StrCat("esg_test_", ++databases_, "_", getpid());
    // The name is made of [a-z0-9_] only: no quoting needed.
    std::unique_ptr<PGresult, decltype(&PQclear)> result(
        PQexec(conn.get(), ("CREATE DATABASE " + name).c_str()), &PQclear);
    if (PQresultStatus(result.get()) == PGRES_COMMAND_OK) return Uri(name);
    // On the fixture's server an earlier test process may have had this pid.
    const char* state = PQresultErrorField(result.get(), PG_DIAG_SQLSTATE);
    if (state != nullptr && std::strcmp(state, kDuplicateDatabase) == 0 && databases_ < 1000) {
      continue;
    }
    return absl::InternalError(
        absl::StrCat("CREATE DATABASE ", name, ": ", PQerrorMessage(conn.get())));
  }
}

pid_t PostgresServer::PostmasterPid() const {
  std::istringstream lock(ReadText(data_dir_ + "/postmaster.pid"));
  long pid = 0;
  return (lock >> pid) ? static_cast<pid_t>(pid) : 0;
}

absl::Status PostgresServer::Kill() {
  if (!owned_) return NotOwned();
  if (!running_) return absl::FailedPreconditionError("the server is not running");
  const pid_t postmaster = PostmasterPid();
  if (postmaster <= 0) {
    return absl::InternalError(absl::StrCat("no pid in ", data_dir_, "/postmaster.pid"));
  }
  std::vector<pid_t> processes = ChildrenOf(postmaster);
  if (::kill(postmaster, SIGKILL) != 0) {
    return absl::InternalError(absl::StrCat("kill -9 ", postmaster, ": ", std::strerror(errno)));
  }
  running_ = false;
  processes.push_back(postmaster);
  // The backends, checkpointer and the rest notice the postmaster's death and exit on their own.
  if (!WaitDead(processes, std::chrono::seconds(10))) {
    for (pid_t pid : processes) ::kill(pid, SIGKILL);
    if (!WaitDead(processes, std::chrono::seconds(5))) {
      return absl::InternalError(
          absl::StrCat("the postmaster (", postmaster, ") or a child outlived SIGKILL"));
    }
  }
  // A zombie postmaster that its parent (init, after pg_ctl exited) has not reaped yet still
  // passes kill(pid, 0), and the next postmaster would take its lock files for a live server's.
  // It is dead, so they are stale.
  char state = 0;
  pid_t parent = 0;
  if (ProcessState(postmaster, &state, &parent)) {
    const std::string socket = absl::StrCat(data_dir_, "/.s.PGSQL.", port_);
    for (const std::string& stale : {data_dir_ + "/postmaster.pid", socket + ".lock", socket}) {
      std::error_code ec;
      std::filesystem::remove(stale, ec);
    }
  }
  return absl::OkStatus();
}

int PostgresServer::ReapStale() {
  int reaped = 0;
  std::error_code ec;
  for (const auto& entry : std::filesystem::directory_iterator("/tmp", ec)) {
    const std::string dir = entry.path().string();
    if (dir.rfind("/tmp/esg-pg-", 0) != 0 || !entry.is_directory(ec) || OwnerAlive(dir)) continue;
    std::unique_ptr<PostgresServer> stale(new PostgresServer(dir, BinDir()));
    const pid_t postmaster = stale->PostmasterPid();
    // The destructor stops a running postmaster (pg_ctl stop, else kill -9) and removes the dir.
    stale->running_ = postmaster > 0 && !Dead(postmaster);
    stale.reset();
    ++reaped;
  }
  return reaped;
}

absl::Status PostgresServer::Restart() {
  if (!owned_) return NotOwned();
  if (running_) return absl::FailedPreconditionError("the server is running");
  return StartOnPort();
}

}  // namespace esg::testing
