// The two engines' schemas agree (storage/schema.cc for SQLite, storage/postgres_schema.cc for
// PostgreSQL, each written for its engine's types): a fresh database of each has the same tables
// (apart from two of PostgreSQL's own, named with their reason) with the same columns in the same
// order, so a change made to one DDL and not the other fails here rather than in a query on one
// engine only.
#include <map>
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/storage.h"
#include "tests/testing/postgres_server.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

namespace esg::storage {
namespace {

using ::esg::testing::IsOk;

// Rows of a one-column-or-two query, each row's columns joined by '.'.
std::vector<std::string> Rows(Database& db, const std::string& sql) {
  std::vector<std::string> rows;
  absl::StatusOr<Transaction> txn = db.Begin(TransactionMode::kDeferred);
  EXPECT_THAT(txn, IsOk());
  if (!txn.ok()) return rows;
  absl::StatusOr<Statement*> st = txn->Prepare(sql);
  EXPECT_THAT(st, IsOk()) << sql;
  if (!st.ok()) return rows;
  while (true) {
    absl::StatusOr<bool> row = (*st)->Step();
    EXPECT_THAT(row, IsOk()) << sql;
    if (!row.ok() || !*row) break;
    std::string text = (*st)->ColumnText(0);
    for (int c = 1; c < (*st)->ColumnCount(); ++c) text += "." + (*st)->ColumnText(c);
    rows.push_back(text);
  }
  return rows;
}

// Table -> its columns in order.
using Layout = std::map<std::string, std::vector<std::string>>;

Layout SqliteLayout(Database& db) {
  Layout layout;
  for (const std::string& table :
       Rows(db, "SELECT name FROM sqlite_schema WHERE type = 'table' AND name NOT LIKE "
                "'sqlite_%' ORDER BY name")) {
    layout[table] = Rows(db, "SELECT name FROM pragma_table_info('" + table + "') ORDER BY cid");
  }
  return layout;
}

Layout PostgresLayout(Database& db) {
  Layout layout;
  for (const std::string& table :
       Rows(db, "SELECT table_name FROM information_schema.tables WHERE table_schema = "
                "current_schema() AND table_type = 'BASE TABLE' ORDER BY table_name")) {
    layout[table] = Rows(db,
                         "SELECT column_name FROM information_schema.columns WHERE table_schema "
                         "= current_schema() AND table_name = '" +
                             table + "' ORDER BY ordinal_position");
  }
  return layout;
}

TEST(SchemaAgreement, BothEnginesHaveTheSameTablesAndColumnsInOrder) {
  ::esg::testing::TempDir dir;
  absl::StatusOr<std::unique_ptr<Storage>> sqlite = Storage::Open(dir.File("esg.db"));
  ASSERT_THAT(sqlite, IsOk());
  std::string error;
  ::esg::testing::PostgresServer* server = ::esg::testing::PostgresServer::Shared(&error);
  ASSERT_NE(server, nullptr) << "the PostgreSQL test server cannot start: " << error;
  absl::StatusOr<std::string> uri = server->CreateDatabase();
  ASSERT_THAT(uri, IsOk());
  absl::StatusOr<std::unique_ptr<Storage>> postgres = Storage::Open(*uri);
  ASSERT_THAT(postgres, IsOk());

  const Layout a = SqliteLayout((*sqlite)->database());
  const Layout b = PostgresLayout((*postgres)->database());
  ASSERT_GE(a.size(), 5u) << "the SQLite schema was not read";
  // PostgreSQL's own tables, each for a stated reason: the schema version (SQLite keeps it in
  // PRAGMA user_version) and the session leases (only a database several servers share has
  // them: docs/service.md "Several servers").
  const std::set<std::string> postgres_only = {"esg_schema", "session_leases"};
  std::vector<std::string> tables_a, tables_b;
  for (const auto& [t, c] : a) tables_a.push_back(t);
  for (const auto& [t, c] : b) {
    if (!postgres_only.count(t)) tables_b.push_back(t);
  }
  EXPECT_EQ(tables_a, tables_b);
  for (const std::string& t : postgres_only) EXPECT_TRUE(b.count(t)) << t;
  for (const auto& [table, columns] : a) {
    const auto it = b.find(table);
    if (it == b.end()) continue;  // reported above
    EXPECT_EQ(columns, it->second) << "table " << table;
  }
}

}  // namespace
}  // namespace esg::storage
