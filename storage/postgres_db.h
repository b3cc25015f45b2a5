// The PostgreSQL engine of database.h: PostgresDatabase (one libpq connection) and
// PostgresStatement. Several servers may share one PostgreSQL database (docs/service.md
// "Storage backends"); each holds one connection.
//
// Durability contract (what an OK Transaction::Commit() guarantees)
// ------------------------------------------------------------------
// Commit() returns OK only after the server answered COMMIT, which with synchronous_commit=on
// (set by Open() for its session) it does only once the transaction's WAL record is flushed to
// disk with fsync: a committed transaction survives a crash of the PostgreSQL server or its host,
// as with SQLite's Synchronous::kFull. Open() refuses a server running with fsync=off, which
// would break that promise silently. Anything but an OK Commit() leaves nothing of the
// transaction visible, with one exception no client can rule out: when the connection is lost
// while COMMIT is under way, Commit() reports Unavailable although the server may have
// committed. The service then does not acknowledge the frames; a station that sends them again
// gets the duplicate outcome for each one stored (docs/service.md "Telemetry ingest"), so
// nothing is lost and nothing is applied twice.
//
// Faults: a lost connection (server restart, network) fails the statement or commit under way
// with Unavailable; the next Begin() reconnects, so the same PostgresDatabase takes the next
// transaction as soon as the server is back. A full disk at the server is ResourceExhausted
// (SQLSTATE class 53), a lock held elsewhere longer than lock_timeout Unavailable.
//
// Types (docs/service.md "Storage backends"): integers are BIGINT, doubles DOUBLE PRECISION
// (sent and read as text with 17 significant digits / shortest exact form, so every double
// round-trips exactly), text TEXT (UTF-8; a NUL byte in a text value is InvalidArgument, as
// PostgreSQL cannot store it), blobs BYTEA (sent in binary).
#ifndef ESG_STORAGE_POSTGRES_DB_H_
#define ESG_STORAGE_POSTGRES_DB_H_

#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "storage/database.h"

struct pg_conn;
struct pg_result;

namespace esg::storage {

struct PostgresOptions {
  // How long Open() and a reconnect wait for the server (libpq connect_timeout, whole seconds).
  absl::Duration connect_timeout = absl::Seconds(10);
  // How long a statement waits for a row lock held by another connection before Unavailable.
  absl::Duration lock_timeout = absl::Seconds(5);
};

// True for a --db value that names a PostgreSQL database ("postgresql://..." or
// "postgres://...", libpq's connection URI).
bool IsPostgresUri(absl::string_view db);

// `uri` with any password removed (user:password@ and password= parameters), for messages.
std::string RedactPostgresUri(absl::string_view uri);

// The absl::StatusCode for a PostgreSQL SQLSTATE (five characters); see database.h.
absl::StatusCode StatusCodeForSqlState(absl::string_view sqlstate);

class PostgresDatabase;

// A statement of a PostgresDatabase: the SQL with "?N" rewritten as "$N", executed at the first
// Step() with the bound values (unbound parameters are NULL), its rows held until Reset().
class PostgresStatement final : public Statement {
 public:
  ~PostgresStatement() override;

  PostgresStatement& BindInt64(int index, int64_t value) override;
  PostgresStatement& BindDouble(int index, double value) override;
  PostgresStatement& BindText(int index, absl::string_view value) override;
  PostgresStatement& BindBlob(int index, absl::string_view bytes) override;
  PostgresStatement& BindNull(int index) override;
  absl::StatusOr<bool> Step() override;
  void Reset() override;
  int ColumnCount() const override;
  bool ColumnIsNull(int column) const override;
  int64_t ColumnInt64(int column) const override;
  double ColumnDouble(int column) const override;
  std::string ColumnText(int column) const override;
  std::string ColumnBlob(int column) const override;

 private:
  friend class PostgresDatabase;
  struct Param {
    unsigned int type = 0;  // PostgreSQL type OID; 0: inferred by the server
    bool null = true;
    bool binary = false;
    std::string value;
  };
  PostgresStatement(PostgresDatabase* db, std::string sql, std::string pg_sql,
                    std::vector<bool> used);
  Param* At(int index);

  PostgresDatabase* db_;
  const std::string pg_sql_;     // with $N parameters
  const std::vector<bool> used_;  // [N - 1]: whether $N occurs in pg_sql_
  std::vector<Param> params_;
  absl::Status bind_status_;
  pg_result* result_ = nullptr;
  int row_ = -1;
};

// A connection that LISTENs on notification channels (PostgreSQL LISTEN/NOTIFY): how a
// server learns of changes another server committed. Not thread-safe: one thread waits on it.
class PostgresListener {
 public:
  struct Notification {
    std::string channel;
    std::string payload;
    int sender_pid = 0;  // backend process of the connection that notified
  };

  // Connects to `uri` and LISTENs on each of `channels` (SQL identifiers of lowercase letters,
  // digits and _; at least one). Errors as PostgresDatabase::Open; InvalidArgument for a
  // channel that is not such a name.
  static absl::StatusOr<std::unique_ptr<PostgresListener>> Open(
      const std::string& uri, const std::vector<std::string>& channels,
      const PostgresOptions& options);
  ~PostgresListener();

  // Waits up to `timeout` for notifications and returns those that arrived (maybe none).
  // Unavailable when the connection was lost: the next call reconnects and LISTENs again, and
  // notifications sent meanwhile are lost (the caller re-reads what it follows).
  absl::StatusOr<std::vector<Notification>> Wait(absl::Duration timeout);

 private:
  PostgresListener(pg_conn* conn, std::string uri, std::vector<std::string> channels,
                   PostgresOptions options);
  absl::Status ListenLocked();

  pg_conn* conn_;
  const std::string uri_;
  const std::vector<std::string> channels_;
  const PostgresOptions options_;
};

class PostgresDatabase final : public Database {
 public:
  // Connects to `uri` (libpq connection URI, e.g. "postgresql://esg@db.example:5432/esg"),
  // sets the session (synchronous_commit=on, lock_timeout, UTC, exact float output) and checks
  // that the server runs with fsync=on. Errors: InvalidArgument for a URI libpq cannot parse
  // (naming the problem, never the password), Unavailable "db: <uri>: cannot connect: <reason>"
  // when the server cannot be reached or refuses the login, FailedPrecondition for fsync=off.
  static absl::StatusOr<std::unique_ptr<PostgresDatabase>> Open(
      const std::string& uri, const PostgresOptions& options = {});

  ~PostgresDatabase() override;

  // Reads every table of the schema; OK, or DataLoss/the read's error. PostgreSQL checks its own
  // pages (data checksums when the cluster was created with them).
  absl::Status QuickCheck() override;
  const std::string& path() const override { return name_; }
  Dialect dialect() const override { return Dialect::kPostgres; }

  // A new connection to the same database LISTENing on `channels`.
  absl::StatusOr<std::unique_ptr<PostgresListener>> Listen(
      const std::vector<std::string>& channels) const;
  // The server process of this connection now (it changes when the connection is re-made):
  // PostgresListener::Notification::sender_pid of what this connection's commits notify.
  int BackendPid();

 protected:
  absl::Status BeginLocked(TransactionMode mode) override;
  absl::Status ExecLocked(absl::string_view sql) override;
  absl::StatusOr<Statement*> PrepareLocked(absl::string_view sql) override;
  int64_t ChangedRowsLocked() const override { return changed_rows_; }
  absl::Status CommitLocked() override;
  absl::Status RollbackLocked() override;

 private:
  friend class PostgresStatement;
  PostgresDatabase(pg_conn* conn, std::string uri, const PostgresOptions& options);
  // The session settings of Open(), again after a reconnect.
  absl::Status ConfigureSessionLocked();
  // Reconnects if the connection was lost; Unavailable if the server is still unreachable.
  absl::Status EnsureConnectedLocked();
  // The status of a finished command (`result` may be null); sets changed_rows_.
  absl::Status CheckResult(pg_result* result, absl::string_view context);

  pg_conn* conn_;
  const std::string uri_;
  const std::string name_;  // uri_ without a password
  const PostgresOptions options_;
  int64_t changed_rows_ = 0;
  absl::flat_hash_map<std::string, std::unique_ptr<PostgresStatement>> cache_;  // by SQL text
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_POSTGRES_DB_H_
