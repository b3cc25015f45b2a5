// Engine-independent parts of the database wrappers; contract in database.h.
#include "storage/database.h"

#include <limits>
#include <utility>

#include "absl/strings/str_cat.h"

namespace esg::storage {

// ---------------------------------------------------------------------------------------------
// Statement

absl::Status Statement::Run() {
  absl::StatusOr<bool> row = Step();
  if (!row.ok()) return row.status();
  if (*row) return absl::InternalError(absl::StrCat("statement returned a row: ", sql_));
  return absl::OkStatus();
}

double Statement::ColumnDoubleOrNaN(int column) const {
  return ColumnIsNull(column) ? std::numeric_limits<double>::quiet_NaN() : ColumnDouble(column);
}

// ---------------------------------------------------------------------------------------------
// Transaction

Transaction::Transaction(Transaction&& other) noexcept
    : db_(std::exchange(other.db_, nullptr)), used_(std::move(other.used_)) {}

Transaction::~Transaction() {
  // Nothing can be reported from a destructor; a failed ROLLBACK leaves the engine to roll the
  // transaction back when the connection closes or the next BEGIN fails loudly.
  Rollback().IgnoreError();
}

void Transaction::ResetUsedStatements() {
  // A statement left mid-iteration would keep its read open and block COMMIT of writes.
  for (Statement* st : used_) st->Reset();
  used_.clear();
}

void Transaction::Release() {
  Database* db = std::exchange(db_, nullptr);
  if (db != nullptr) db->ReleaseLock();
}

absl::Status Transaction::Execute(absl::string_view sql) {
  if (db_ == nullptr) return absl::FailedPreconditionError("transaction already ended");
  return db_->ExecLocked(sql);
}

absl::StatusOr<Statement*> Transaction::Prepare(absl::string_view sql) {
  if (db_ == nullptr) return absl::FailedPreconditionError("transaction already ended");
  absl::StatusOr<Statement*> st = db_->PrepareLocked(sql);
  if (st.ok()) used_.push_back(*st);
  return st;
}

int64_t Transaction::ChangedRows() const { return db_ == nullptr ? 0 : db_->ChangedRowsLocked(); }

absl::Status Transaction::Commit() {
  if (db_ == nullptr) return absl::FailedPreconditionError("transaction already ended");
  ResetUsedStatements();
  absl::Status status = db_->CommitLocked();
  if (!status.ok()) {
    status = absl::Status(status.code(), absl::StrCat("db: ", db_->path(),
                                                      ": commit failed and was rolled back: ",
                                                      status.message()));
  }
  Release();
  return status;
}

absl::Status Transaction::Rollback() {
  if (db_ == nullptr) return absl::OkStatus();
  ResetUsedStatements();
  absl::Status status = db_->RollbackLocked();
  Release();
  return status;
}

// ---------------------------------------------------------------------------------------------
// Database

absl::Status Database::Acquire() {
  if (owner_.load(std::memory_order_relaxed) == std::this_thread::get_id()) {
    return absl::FailedPreconditionError(
        "this thread already holds a transaction on this database (nested use would deadlock)");
  }
  mu_.Lock();
  owner_.store(std::this_thread::get_id(), std::memory_order_relaxed);
  return absl::OkStatus();
}

void Database::ReleaseLock() {
  owner_.store(std::thread::id(), std::memory_order_relaxed);
  mu_.Unlock();
}

absl::StatusOr<Transaction> Database::Begin(TransactionMode mode) {
  absl::Status status = Acquire();
  if (!status.ok()) return status;
  status = BeginLocked(mode);
  if (!status.ok()) {
    ReleaseLock();
    return status;
  }
  return Transaction(this);
}

absl::Status Database::Execute(absl::string_view sql) {
  absl::Status status = Acquire();
  if (!status.ok()) return status;
  status = ExecLocked(sql);
  ReleaseLock();
  return status;
}

}  // namespace esg::storage
