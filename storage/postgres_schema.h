// The PostgreSQL schema of the service database (postgres_db.h) and its versions, kept in the
// table esg_schema. A new PostgreSQL database is created at schema version 7 of schema.h (the
// same tables, columns and keys as SQLite's, in PostgreSQL types: BIGINT, DOUBLE PRECISION, TEXT,
// BYTEA) plus session_leases (lease_store.h) and upgraded to the current version in the same
// transaction; a database created by an older program at version 7 or later is upgraded the same
// way. A later version appends its migration to both engines.
// Creation and migrations hold a transaction-scoped advisory lock, so several servers starting
// against one database at once create the schema once.
#ifndef ESG_STORAGE_POSTGRES_SCHEMA_H_
#define ESG_STORAGE_POSTGRES_SCHEMA_H_

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "storage/database.h"

namespace esg::storage {

// The channel a trigger on the alerts table NOTIFYs at each commit that inserts or updates an
// alert, with the payload "<sequence> <spacecraft_id>" (PostgresListener).
inline constexpr char kAlertsChannel[] = "esg_alerts";

// The channel a trigger on the estimates table NOTIFYs at each commit that inserts or replaces a
// per-step estimate, with the payload "<measurement_time_unix_ns> <spacecraft_id>".
inline constexpr char kEstimatesChannel[] = "esg_estimates";

// The version in esg_schema; 0 for a database without the service's tables.
absl::StatusOr<int> PostgresSchemaVersion(Database& db);

// Creates the current schema in a database without it, or upgrades one at version 7 or later to
// it (in one created at version 7 before the estimates trigger existed, adds that trigger);
// FailedPrecondition for a database newer than this program or one holding other tables named
// like the service's. `target_version` is 0 (nothing to do) or in [7, kCurrentSchemaVersion]:
// production code asks for the current one; an older one makes the database an earlier program
// wrote (the migration tests).
absl::Status MigratePostgresTo(Database& db, int target_version);

}  // namespace esg::storage

#endif  // ESG_STORAGE_POSTGRES_SCHEMA_H_
