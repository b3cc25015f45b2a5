// The storage conformance suite's two backends (storage/database.h): a test written once as
// TEST_P on a BackendTest fixture runs against SQLite (a file in the fixture's temp dir) and
// PostgreSQL (a fresh database on the shared test server, tests/testing/postgres_server.h), so
// the stores are shown to behave the same on both engines.
//
//   class AlertStoreTest : public BackendTest {};
//   ESG_INSTANTIATE_BACKEND_TEST_SUITE(AlertStoreTest);
//   TEST_P(AlertStoreTest, Numbers...) {
//     absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
//
// Test names end in "/Sqlite" or "/Postgres" (--gtest_filter='*/Postgres' runs one backend).
// A PostgreSQL server that cannot start FAILS the PostgreSQL half with the reason: it is never
// skipped, so a missing server cannot pass for a conforming engine.
#ifndef ESG_TESTS_STORAGE_BACKEND_H_
#define ESG_TESTS_STORAGE_BACKEND_H_

#include <ostream>
#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "gtest/gtest.h"
#include "tests/testing/postgres_server.h"
#include "tests/testing/temp_dir.h"

namespace esg::storage::testing {

enum class Backend { kSqlite, kPostgres };

inline const char* BackendName(Backend backend) {
  return backend == Backend::kSqlite ? "Sqlite" : "Postgres";
}

inline std::ostream& operator<<(std::ostream& os, Backend backend) {
  return os << BackendName(backend);
}

// The parameter-name printer of INSTANTIATE_TEST_SUITE_P: "Sqlite" or "Postgres".
struct BackendParamName {
  std::string operator()(const ::testing::TestParamInfo<Backend>& info) const {
    return BackendName(info.param);
  }
};

class BackendTest : public ::testing::TestWithParam<Backend> {
 protected:
  // Starts (once per process) the shared PostgreSQL server for the PostgreSQL half; a fatal
  // failure naming the reason when it cannot start, so the test body does not run. A fixture
  // that overrides SetUp() calls this first and returns on HasFatalFailure().
  void SetUp() override {
    if (GetParam() != Backend::kPostgres) return;
    std::string error;
    server_ = ::esg::testing::PostgresServer::Shared(&error);
    ASSERT_NE(server_, nullptr) << "the PostgreSQL test server cannot start: " << error;
  }

  // A new empty database, distinct on every call: an SQLite file path in this fixture's temp
  // dir, or the URI of a fresh PostgreSQL database. Storage::Open() takes either; opening the
  // same string again reopens the same database. On failure the test fails with the reason
  // and "" is returned, which Storage::Open() refuses (InvalidArgument).
  std::string NewDatabase() {
    if (GetParam() == Backend::kSqlite) return dir_.File(absl::StrCat("esg-", ++files_, ".db"));
    if (server_ == nullptr) {
      ADD_FAILURE() << "no PostgreSQL test server (SetUp failed)";
      return "";
    }
    absl::StatusOr<std::string> uri = server_->CreateDatabase();
    if (!uri.ok()) {
      ADD_FAILURE() << "cannot create a PostgreSQL test database: " << uri.status();
      return "";
    }
    return *uri;
  }

  ::esg::testing::TempDir dir_;

 private:
  ::esg::testing::PostgresServer* server_ = nullptr;
  int files_ = 0;
};

}  // namespace esg::storage::testing

// Runs every TEST_P of `suite` (a BackendTest subclass) once per backend.
#define ESG_INSTANTIATE_BACKEND_TEST_SUITE(suite)                                          \
  INSTANTIATE_TEST_SUITE_P(Backends, suite,                                                \
                           ::testing::Values(::esg::storage::testing::Backend::kSqlite,    \
                                             ::esg::storage::testing::Backend::kPostgres), \
                           ::esg::storage::testing::BackendParamName())

#endif  // ESG_TESTS_STORAGE_BACKEND_H_
