// tests/testing/postgres_server.h: the shared server starts as configured, its databases are
// separate, a committed row survives kill -9 of the postmaster while an uncommitted one does
// not, and a server published for the ctest fixture serves the tests that attach to it until
// the one that takes it over stops it.
#include "tests/testing/postgres_server.h"

#include <libpq-fe.h>
#include <sys/wait.h>
#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/status_matchers.h"

namespace esg::testing {
namespace {

using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::IsEmpty;
using ::testing::StartsWith;

using Connection = std::unique_ptr<PGconn, decltype(&PQfinish)>;

Connection Connect(const std::string& uri) {
  Connection conn(PQconnectdb(uri.c_str()), &PQfinish);
  EXPECT_EQ(PQstatus(conn.get()), CONNECTION_OK) << uri << ": " << PQerrorMessage(conn.get());
  return conn;
}

// Runs sql; returns the first column of every row, or fails the test and returns {"<error>"}.
std::vector<std::string> Query(PGconn* conn, const std::string& sql) {
  std::unique_ptr<PGresult, decltype(&PQclear)> result(PQexec(conn, sql.c_str()), &PQclear);
  const ExecStatusType status = PQresultStatus(result.get());
  if (status != PGRES_COMMAND_OK && status != PGRES_TUPLES_OK) {
    ADD_FAILURE() << sql << ": " << PQerrorMessage(conn);
    return {"<error>"};
  }
  std::vector<std::string> column;
  for (int row = 0; row < PQntuples(result.get()); ++row) {
    column.emplace_back(PQgetvalue(result.get(), row, 0));
  }
  return column;
}

PostgresServer* SharedOrFail() {
  std::string error;
  PostgresServer* server = PostgresServer::Shared(&error);
  EXPECT_NE(server, nullptr) << error;
  return server;
}

TEST(PostgresServerTest, SharedServerListensOnLoopbackWithFsyncOn) {
  PostgresServer* server = SharedOrFail();
  ASSERT_NE(server, nullptr);
  EXPECT_EQ(PostgresServer::Shared(), server);
  EXPECT_GT(server->port(), 0);
  EXPECT_EQ(server->Uri("db1"),
            "postgresql://esg@127.0.0.1:" + std::to_string(server->port()) + "/db1");

  Connection conn = Connect(server->Uri("postgres"));
  ASSERT_EQ(PQstatus(conn.get()), CONNECTION_OK);
  EXPECT_THAT(Query(conn.get(), "SHOW fsync"), ElementsAre("on"));
  EXPECT_THAT(Query(conn.get(), "SHOW listen_addresses"), ElementsAre("127.0.0.1"));
  EXPECT_THAT(Query(conn.get(), "SHOW unix_socket_directories"), ElementsAre(server->data_dir()));
  EXPECT_THAT(Query(conn.get(), "SHOW server_encoding"), ElementsAre("UTF8"));
  EXPECT_THAT(Query(conn.get(), "SELECT current_user"), ElementsAre("esg"));
  EXPECT_THAT(Query(conn.get(), "SHOW server_version_num"), ElementsAre(StartsWith("15")));
}

TEST(PostgresServerTest, DatabasesAreSeparate) {
  PostgresServer* server = SharedOrFail();
  ASSERT_NE(server, nullptr);
  absl::StatusOr<std::string> first = server->CreateDatabase();
  absl::StatusOr<std::string> second = server->CreateDatabase();
  ASSERT_THAT(first, IsOk());
  ASSERT_THAT(second, IsOk());
  EXPECT_NE(*first, *second);
  EXPECT_THAT(*first, HasSubstr("/esg_test_"));

  Connection a = Connect(*first);
  Connection b = Connect(*second);
  ASSERT_EQ(PQstatus(a.get()), CONNECTION_OK);
  ASSERT_EQ(PQstatus(b.get()), CONNECTION_OK);
  EXPECT_THAT(Query(a.get(), "SELECT current_database()"),
              ElementsAre(first->substr(first->rfind('/') + 1)));
  Query(a.get(), "CREATE TABLE t (v text)");
  Query(b.get(), "CREATE TABLE t (v text)");
  Query(a.get(), "INSERT INTO t VALUES ('written in the first')");
  EXPECT_THAT(Query(a.get(), "SELECT v FROM t"), ElementsAre("written in the first"));
  EXPECT_THAT(Query(b.get(), "SELECT v FROM t"), IsEmpty());
}

TEST(PostgresServerTest, KillAndRestartKeepCommittedRowsOnly) {
  std::string error;
  PostgresServer* server = PostgresServer::Own(&error);  // not the shared one: it is killed
  EXPECT_NE(server, nullptr) << error;
  ASSERT_NE(server, nullptr);
  absl::StatusOr<std::string> uri = server->CreateDatabase();
  ASSERT_THAT(uri, IsOk());
  const int port = server->port();
  {
    Connection conn = Connect(*uri);
    ASSERT_EQ(PQstatus(conn.get()), CONNECTION_OK);
    Query(conn.get(), "CREATE TABLE t (v text)");
    Query(conn.get(), "INSERT INTO t VALUES ('committed')");
    Connection open_transaction = Connect(*uri);
    ASSERT_EQ(PQstatus(open_transaction.get()), CONNECTION_OK);
    Query(open_transaction.get(), "BEGIN");
    Query(open_transaction.get(), "INSERT INTO t VALUES ('not committed')");

    ASSERT_THAT(server->Kill(), IsOk());
    // The connection's backend died with the postmaster.
    std::unique_ptr<PGresult, decltype(&PQclear)> after_kill(PQexec(conn.get(), "SELECT 1"),
                                                             &PQclear);
    EXPECT_NE(PQresultStatus(after_kill.get()), PGRES_TUPLES_OK);
  }
  EXPECT_THAT(server->Kill(),
              StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("not running")));

  ASSERT_THAT(server->Restart(), IsOk());
  EXPECT_EQ(server->port(), port);
  EXPECT_THAT(server->Restart(),
              StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("is running")));
  Connection conn = Connect(*uri);
  ASSERT_EQ(PQstatus(conn.get()), CONNECTION_OK);
  EXPECT_THAT(Query(conn.get(), "SELECT v FROM t ORDER BY v"), ElementsAre("committed"));
  // The restarted server still makes databases.
  EXPECT_THAT(server->CreateDatabase(), IsOk());
}

TEST(PostgresServerTest, APublishedServerServesWhoAttachesUntilTheOneThatTakesItOverStopsIt) {
  absl::StatusOr<std::unique_ptr<PostgresServer>> started = PostgresServer::Start();
  ASSERT_THAT(started, IsOk());
  const std::string dir = std::filesystem::path((*started)->data_dir()).parent_path().string();
  const std::string file = dir + ".fixture";
  const int port = (*started)->port();
  ASSERT_THAT((*started)->Publish(file), IsOk());
  started->reset();  // published: the server runs on
  EXPECT_EQ(PQping(("postgresql://esg@127.0.0.1:" + std::to_string(port) + "/postgres").c_str()),
            PQPING_OK);

  // A test process attaches: it makes databases, cannot kill the server, does not stop it.
  for (int user = 0; user < 2; ++user) {
    absl::StatusOr<std::unique_ptr<PostgresServer>> attached =
        PostgresServer::Attach(file, /*take_over=*/false);
    ASSERT_THAT(attached, IsOk());
    EXPECT_EQ((*attached)->port(), port);
    absl::StatusOr<std::string> uri = (*attached)->CreateDatabase();
    ASSERT_THAT(uri, IsOk());
    Connection conn = Connect(*uri);
    EXPECT_THAT(Query(conn.get(), "SELECT 1"), ElementsAre("1"));
    EXPECT_THAT((*attached)->Kill(),
                StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("shared")));
    EXPECT_THAT((*attached)->Restart(),
                StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("shared")));
  }

  // The fixture's cleanup takes it over: stopped, its dir removed.
  {
    absl::StatusOr<std::unique_ptr<PostgresServer>> owner =
        PostgresServer::Attach(file, /*take_over=*/true);
    ASSERT_THAT(owner, IsOk());
  }
  EXPECT_NE(PQping(("postgresql://esg@127.0.0.1:" + std::to_string(port) + "/postgres").c_str()),
            PQPING_OK);
  EXPECT_FALSE(std::filesystem::exists(dir));
  EXPECT_THAT(PostgresServer::Attach(file, /*take_over=*/false),
              StatusIs(absl::StatusCode::kUnavailable, HasSubstr("does not answer")));
  std::filesystem::remove(file);
  EXPECT_THAT(PostgresServer::Attach(file, /*take_over=*/false),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("no PostgreSQL fixture file")));
}

}  // namespace
// A test killed before it stopped its server (ctest's timeout) leaves the server running; the
// next start in any process stops it and removes its dir. A server whose owner runs is kept.
TEST(PostgresServerTest, AServerWhoseOwnerExitedIsReapedAndALiveOnesIsKept) {
  absl::StatusOr<std::unique_ptr<PostgresServer>> kept = PostgresServer::Start();
  ASSERT_THAT(kept, IsOk());
  absl::StatusOr<std::unique_ptr<PostgresServer>> abandoned = PostgresServer::Start();
  ASSERT_THAT(abandoned, IsOk());
  const std::string dir = std::filesystem::path((*abandoned)->data_dir()).parent_path().string();
  const std::string uri =
      "postgresql://esg@127.0.0.1:" + std::to_string((*abandoned)->port()) + "/postgres";
  // Its owner becomes a process that has exited (as a killed test has), and nothing stops it.
  const pid_t child = fork();
  if (child == 0) _exit(0);
  ASSERT_GT(child, 0);
  int status = 0;
  ASSERT_EQ(waitpid(child, &status, 0), child);
  std::ofstream(dir + "/owner", std::ios::trunc) << "pid " << child << " start 1\n";
  abandoned->release();
  ASSERT_EQ(PQping(uri.c_str()), PQPING_OK);

  EXPECT_GE(PostgresServer::ReapStale(), 1);
  EXPECT_NE(PQping(uri.c_str()), PQPING_OK);
  EXPECT_FALSE(std::filesystem::exists(dir));
  // Ours is untouched.
  EXPECT_THAT((*kept)->CreateDatabase(), IsOk());
}

}  // namespace esg::testing
