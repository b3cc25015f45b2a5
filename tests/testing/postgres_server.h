// A real PostgreSQL 15 server for tests, on 127.0.0.1 at a free TCP port, in a temp dir of its
// own. The cluster is made by `initdb -E UTF8 --locale=C -A trust -U esg` and run by
// `pg_ctl start` with fsync on (durability is what the tests check), listen_addresses 127.0.0.1
// only and its unix socket in the data dir, so nothing under /etc, /var or /run is read or written.
//
// initdb and pg_ctl refuse to run as root: when the test runs as root they run as the system user
// `postgres` (`runuser -u postgres -- ...`, Debian's postgresql-15 creates that user) in a
// directory chowned to it; otherwise they run as the test's own user. The binaries come from
// $ESG_PG_BINDIR, else /usr/lib/postgresql/15/bin (Debian's postgresql-15, installed by
// scripts/install-deps.sh). Every process is started by fork/exec with an argument vector (no
// shell), its output captured in a log file of the temp dir.
#ifndef ESG_TESTS_TESTING_POSTGRES_SERVER_H_
#define ESG_TESTS_TESTING_POSTGRES_SERVER_H_

#include <sys/types.h>

#include <atomic>
#include <memory>
#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"

namespace esg::testing {

// CreateDatabase, Uri and port may be called from several threads at once; Kill and Restart
// must not run concurrently with any other call.
class PostgresServer {
 public:
  // initdb into a fresh temp dir (mkdtemp under $TMPDIR or /tmp), then pg_ctl start on a port the
  // OS reported free (bind to port 0, release it); a start that fails, as when another process
  // took the port in between, is retried on a new port (3 attempts). Returns once the server
  // accepts connections as user esg. Errors: kNotFound when the binaries are missing,
  // kInternal when initdb or the start fails, with the command's output and the tail of the
  // server log in the message. The temp dir is removed on failure.
  static absl::StatusOr<std::unique_ptr<PostgresServer>> Start();

  // The server the tests of this process share. Under ctest that is one server for every test
  // that needs one: the fixture `postgres_fixture` (tests/CMakeLists.txt) starts it before them,
  // stops it after them and names its file in $ESG_TEST_POSTGRES (see Publish), and Shared()
  // attaches to it; each test still makes its own databases (CreateDatabase). Without
  // $ESG_TEST_POSTGRES (a test binary run by hand), or when its server cannot be reached, this
  // is Own(). The first call decides (thread-safe). Kill and Restart of the fixture's server are
  // refused: a test that kills its server uses Own().
  static PostgresServer* Shared(std::string* error = nullptr);

  // The process-wide server this process starts itself: started on the first call
  // (thread-safe), stopped and its dir removed at process exit (std::atexit; not in a forked
  // child). Returns nullptr when it could not start, with the reason in *error if error is not
  // null (the same reason on every call).
  static PostgresServer* Own(std::string* error = nullptr);

  // For the ctest fixture (tests/testing/postgres_fixture.cc). Publish writes the server's port
  // and temp dir to `path` and hands the server over: this object no longer stops it, and the
  // server runs on after the process exits. Attach reads such a file and checks that the server
  // accepts connections; with `take_over` the returned object owns the server again (its
  // destructor stops it and removes its dir), otherwise it only uses it (Kill and Restart are
  // refused). Errors: kNotFound for a missing file, kInvalidArgument for a malformed one,
  // kUnavailable when the server does not answer.
  absl::Status Publish(const std::string& path);
  static absl::StatusOr<std::unique_ptr<PostgresServer>> Attach(const std::string& path,
                                                                bool take_over);

  // Stops the servers of earlier processes that were killed before they could stop them (a test
  // killed by ctest's timeout, a ctest interrupted before its cleanup fixture) and removes their
  // temp dirs. Each temp dir records its owner (`owner`: the pid and its start time, so a reused
  // pid is not taken for it): the process that started the server, or for a published server
  // the publisher's parent (ctest under the fixture). A dir whose owner has exited is stale; one
  // without a record is left alone. Start() calls it first. Returns how many it reaped.
  static int ReapStale();

  // Stops the server (pg_ctl stop -m fast) and removes the temp dir with everything in it.
  ~PostgresServer();
  PostgresServer(const PostgresServer&) = delete;
  PostgresServer& operator=(const PostgresServer&) = delete;

  int port() const { return port_; }

  // "postgresql://esg@127.0.0.1:<port>/<database>"
  std::string Uri(const std::string& database) const;

  // Creates a new empty database named esg_test_<n>_<pid> (n counts up from 1 in this process;
  // a name left by an earlier process with the same pid on a shared server is skipped)
  // through libpq on the `postgres` database, and returns Uri(name). kUnavailable when the
  // server cannot be reached, kInternal when CREATE DATABASE fails; the message carries libpq's.
  absl::StatusOr<std::string> CreateDatabase();

  // kill -9 of the postmaster, for crash tests: returns once the postmaster and its children are
  // gone (they notice the postmaster's death and exit; any still there after 10 s get SIGKILL
  // too). What was committed is on disk; nothing was shut down cleanly. kFailedPrecondition when
  // the server is not running or is not this object's (attached without take_over).
  absl::Status Kill();

  // Starts the server again on the same data dir and port (crash recovery runs when it was
  // killed) and waits until it accepts connections. kFailedPrecondition when it is running;
  // kInternal (with the log tail) when the start fails, e.g. because the port was taken; also
  // kFailedPrecondition when the server is not this object's.
  absl::Status Restart();

  // The data directory and the server's log file (for messages and debugging).
  const std::string& data_dir() const { return data_dir_; }
  std::string LogPath() const;

 private:
  PostgresServer(std::string dir, std::string bin_dir);

  // pg_ctl start on port_ and the wait for connections.
  absl::Status StartOnPort();
  // The "postgres" (or other) database's URI with a connect timeout, for libpq.
  std::string ConnInfo(const std::string& database) const;
  // The postmaster's pid from the first line of data_dir_/postmaster.pid; 0 if none.
  pid_t PostmasterPid() const;

  std::string dir_;       // the temp dir: data/, logs
  std::string data_dir_;  // dir_ + "/data"
  std::string bin_dir_;   // initdb, pg_ctl
  int port_ = 0;
  bool running_ = false;
  bool owned_ = true;  // this object stops it; false once published, or attached to use only
  pid_t owner_pid_;  // the process that created the server; a forked child never stops it
  std::atomic<int> databases_{0};
};

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_POSTGRES_SERVER_H_
