// Exclusive ownership (docs/service.md "Running it"): two real esgd processes on one address, and
// two on one SQLite file. The second exits non-zero with a message naming the address or the file
// (and the holder's pid); the first keeps serving real gRPC calls.
#include <string>

#include "absl/strings/str_cat.h"
#include "esg/v1/estimation_service.grpc.pb.h"
#include "gmock/gmock.h"
#include "grpcpp/client_context.h"
#include "gtest/gtest.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::server {
namespace {

using ::esg::testing::Daemon;
using ::esg::testing::RunBinary;
using ::esg::testing::RunResult;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;

// A second esgd, run to its end; `timeout` ends it (exit 124) if it starts serving, which is
// the failure these tests look for.
RunResult RunSecondDaemon(const TempDir& dir, const std::string& listen, const std::string& db) {
  return RunBinary(dir, "timeout",
                   absl::StrCat("20 '", ESGD_PATH, "' --listen ", listen, " --db '", db,
                                "' --workers 2"));
}

// A real call that needs the first daemon's own state: configure a spacecraft, then read it back
// `calls` times on fresh connections (with SO_REUSEPORT a second daemon on the same port would
// take some of them and answer NOT_FOUND).
void ExpectServes(const Daemon& daemon, const std::string& spacecraft_id, int calls) {
  {
    auto stub = daemon.Stub();
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse response;
    const grpc::Status status = stub->ConfigureSpacecraft(
        &ctx,
        esg::testing::ConfigureRequestFor(esg::testing::ServerTestConfig(spacecraft_id)),
        &response);
    ASSERT_TRUE(status.ok()) << status.error_message();
  }
  for (int i = 0; i < calls; ++i) {
    auto stub = daemon.Stub();  // a new channel: a new connection
    grpc::ClientContext ctx;
    esg::v1::GetSessionRequest request;
    request.set_spacecraft_id(spacecraft_id);
    esg::v1::SessionInfo info;
    const grpc::Status status = stub->GetSession(&ctx, request, &info);
    ASSERT_TRUE(status.ok()) << "call " << i << ": " << status.error_message();
    EXPECT_EQ(info.spacecraft_id(), spacecraft_id);
  }
}

TEST(Ownership, SecondDaemonOnTheSameAddressExitsAndTheFirstKeepsServing) {
  TempDir dir;
  Daemon first(dir.File("first.db"), dir.File("first.log"));
  ASSERT_GT(first.port(), 0);
  const RunResult second = RunSecondDaemon(dir, first.address(), dir.File("second.db"));
  EXPECT_EQ(second.exit_code, 1) << second.err;
  EXPECT_THAT(second.err, HasSubstr(absl::StrCat("listen: cannot serve on ", first.address(),
                                                 ": address already in use")));
  EXPECT_THAT(second.out, ::testing::Not(HasSubstr("listening")));
  ExpectServes(first, "OWN-1", 12);
}

TEST(Ownership, SecondDaemonOnTheSameDatabaseExitsNamingTheFileAndThePid) {
  TempDir dir;
  const std::string db = dir.File("shared.db");
  Daemon first(db, dir.File("first.log"));
  ASSERT_GT(first.port(), 0);
  const RunResult second = RunSecondDaemon(dir, "127.0.0.1:0", db);
  EXPECT_EQ(second.exit_code, 1) << second.err;
  // The pid is the first daemon's: the one written into the lock file.
  const std::string holder = esg::testing::ReadFile(db + ".lock");
  ASSERT_FALSE(holder.empty());
  EXPECT_THAT(second.err,
              HasSubstr(absl::StrCat("db: ", db, " is locked by another process (pid ",
                                     holder.substr(0, holder.find('\n')), " holds ", db,
                                     ".lock")));
  EXPECT_THAT(second.out, ::testing::Not(HasSubstr("listening")));
  ExpectServes(first, "OWN-2", 3);
}

TEST(Ownership, TheDatabaseIsFreeAgainOnceTheOwnerStops) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  {
    Daemon first(db, dir.File("first.log"));
    ASSERT_GT(first.port(), 0);
    first.Stop(SIGKILL);  // a crash: the kernel drops the lock with the process
  }
  Daemon second(db, dir.File("second.log"));
  ASSERT_GT(second.port(), 0);
  ExpectServes(second, "OWN-3", 1);
}

}  // namespace
}  // namespace esg::server
