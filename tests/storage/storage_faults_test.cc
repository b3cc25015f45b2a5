// Storage faults at the storage layer (storage/sqlite_db.h, "Storage faults" and "Exclusive
// locking"): write, fsync and disk-full errors injected at every write of a realistic commit
// through the fault VFS (tests/testing/fault_vfs.h), checkpoint failures, files, directories
// and mounts that cannot be written (refused at Open), exclusive locking (no -shm mapping, so no
// SIGBUS; a second opener is refused), and a real full tmpfs.
//
// Several tests need root powers (chattr +i, mount); they skip with the reason when the
// machine refuses. Mode bits (chmod 0444) are not used: they do not stop root.
#include <fcntl.h>
#include <linux/fs.h>
#include <signal.h>
#include <sqlite3.h>
#include <sys/ioctl.h>
#include <sys/mount.h>
#include <sys/types.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>
#include <system_error>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/sqlite_db.h"
#include "storage/storage.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/fault_vfs.h"
#include "tests/testing/tmpfs.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::Frame;
using ::esg::storage::testing::QueryInt;
using ::esg::storage::testing::T;
using ::esg::testing::FaultOp;
using ::esg::testing::FaultPersistence;
using ::esg::testing::FaultVfs;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::esg::testing::TempDir;
using ::esg::testing::Tmpfs;
using ::testing::HasSubstr;

constexpr char kId[] = "SC-FAULT";
// The measured commit: a few hundred frames of a realistic size plus the checkpoint after them,
// in one transaction (what the server's committer and apply workers write).
constexpr int kFramesPerCommit = 300;
constexpr int kPayloadBytes = 240;
constexpr int kStateBlobBytes = 6000;  // larger than a page: exercises overflow pages

std::string ErrnoText(int e) { return std::error_code(e, std::generic_category()).message(); }

std::vector<ArchivedFrame> Frames(int64_t first_sequence, int count) {
  std::vector<ArchivedFrame> frames;
  for (int64_t s = first_sequence; s < first_sequence + count; ++s) {
    ArchivedFrame f = Frame(kId, s);
    f.payload.resize(kPayloadBytes, static_cast<char>('a' + s % 26));
    frames.push_back(std::move(f));
  }
  return frames;
}

CheckpointRecord Checkpoint(int64_t last_sequence) {
  CheckpointRecord c;
  c.spacecraft_id = kId;
  c.last_sequence = last_sequence;
  c.measurement_time = T(60.0 * static_cast<double>(last_sequence));
  c.compute_time = c.measurement_time + absl::Seconds(1);
  c.state_blob.assign(kStateBlobBytes, static_cast<char>(last_sequence % 251));
  return c;
}

// Commit number `k` (0, 1, ...): frames k*300+1 .. (k+1)*300 and the checkpoint after them, in
// one IMMEDIATE transaction through Database::Begin / Transaction::Commit.
absl::Status CommitNumber(Storage& storage, int k) {
  const int64_t first = int64_t{k} * kFramesPerCommit + 1;
  ASSIGN_OR_RETURN(Transaction txn, storage.database().Begin(TransactionMode::kImmediate));
  ASSIGN_OR_RETURN(AppendResult appended,
                   storage.archive().AppendBatch(txn, kId, Frames(first, kFramesPerCommit)));
  if (appended.new_sequences.size() != static_cast<size_t>(kFramesPerCommit)) {
    return absl::InternalError("frames already stored");
  }
  RETURN_IF_ERROR(storage.sessions().PutCheckpoint(txn, Checkpoint(first + kFramesPerCommit - 1)));
  return txn.Commit();
}

// How many of the commits 0..k-1 the database holds, or -1 if it holds part of one: the frame
// count must be a whole number of commits and the checkpoint must be the one of the last.
int CommitsStored(Storage& storage) {
  absl::StatusOr<int64_t> frames = QueryInt(
      storage.database(),
      absl::StrCat("SELECT COUNT(*) FROM telemetry_frames WHERE spacecraft_id = '", kId, "'"));
  if (!frames.ok() || *frames % kFramesPerCommit != 0) return -1;
  const int commits = static_cast<int>(*frames / kFramesPerCommit);
  absl::StatusOr<CheckpointRecord> checkpoint = storage.sessions().GetCheckpoint(kId);
  if (commits == 0) return checkpoint.status().code() == absl::StatusCode::kNotFound ? 0 : -1;
  if (!checkpoint.ok() || checkpoint->last_sequence != int64_t{commits} * kFramesPerCommit ||
      checkpoint->state_blob != Checkpoint(checkpoint->last_sequence).state_blob) {
    return -1;
  }
  absl::StatusOr<std::optional<int64_t>> highest = storage.archive().HighestSequence(kId);
  if (!highest.ok() || highest->value_or(0) != int64_t{commits} * kFramesPerCommit) return -1;
  return commits;
}

DatabaseOptions FaultOptions() {
  FaultVfs::Instance();  // registers the VFS
  DatabaseOptions options;
  options.vfs = FaultVfs::kName;
  return options;
}

// A database in the state before the measured commit: schema, and commit 0 durable.
std::unique_ptr<Storage> Prepared(const std::string& path) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path, FaultOptions());
  if (!storage.ok()) return nullptr;
  if (!CommitNumber(**storage, 0).ok()) return nullptr;
  return std::move(*storage);
}

struct OpCounts {
  int64_t writes = 0, syncs = 0, truncates = 0, size_hints = 0, shm_maps = 0;
};

// The file operations of commit 1 on a prepared database, with no fault armed.
OpCounts CountCommitOperations() {
  TempDir dir;
  std::unique_ptr<Storage> storage = Prepared(dir.File("esg.db"));
  EXPECT_NE(storage, nullptr);
  if (storage == nullptr) return {};
  FaultVfs& vfs = FaultVfs::Instance();
  vfs.Disarm();
  vfs.ResetCounters();
  EXPECT_THAT(CommitNumber(*storage, 1), IsOk());
  return {vfs.Calls(FaultOp::kWrite), vfs.Calls(FaultOp::kSync), vfs.Calls(FaultOp::kTruncate),
          vfs.Calls(FaultOp::kSizeHint), vfs.Calls(FaultOp::kShmMap)};
}

// Arms `op` to fail at call `nth` of commit 1 with `error`, runs the commit, and checks the
// contract of sqlite_db.h: the commit fails with `expected`, nothing of it is visible, the file
// is consistent, and the same Database commits again once the fault is gone; after a reopen the
// database holds both commits.
void ExpectFailedCommitLeavesNothingAndRecovers(FaultOp op, int64_t nth, int error,
                                                absl::StatusCode expected) {
  SCOPED_TRACE(absl::StrCat("op ", static_cast<int>(op), ", call ", nth, ", error ", error));
  TempDir dir;
  const std::string path = dir.File("esg.db");
  {
    std::unique_ptr<Storage> storage = Prepared(path);
    ASSERT_NE(storage, nullptr);
    FaultVfs& vfs = FaultVfs::Instance();
    vfs.Arm(op, nth, error);
    const absl::Status failed = CommitNumber(*storage, 1);
    const int64_t injected = vfs.Injected(op);
    vfs.Disarm();
    EXPECT_EQ(injected, 1);
    EXPECT_THAT(failed, StatusIs(expected, HasSubstr("db: " + path)));
    EXPECT_THAT(storage->database().QuickCheck(), IsOk());
    EXPECT_EQ(CommitsStored(*storage), 1) << "the failed commit must leave nothing";
    // Same Database object, no reopen: the connection is not poisoned.
    EXPECT_THAT(CommitNumber(*storage, 1), IsOk());
    EXPECT_EQ(CommitsStored(*storage), 2);
  }
  absl::StatusOr<std::unique_ptr<Storage>> reopened = Storage::Open(path);
  ASSERT_THAT(reopened, IsOk());
  EXPECT_THAT((*reopened)->database().QuickCheck(), IsOk());
  EXPECT_EQ(CommitsStored(**reopened), 2);
}

// Like above, but the process dies (_exit, no close) right after the failed commit: the next
// Open() must find a consistent file holding the failed commit entirely or not at all. Returns
// how many commits it holds (1 or 2), or -1.
int CommitsAfterCrashFollowingFailedCommit(FaultOp op, int64_t nth, int error,
                                           absl::StatusCode expected) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  const pid_t child = ::fork();
  if (child == 0) {
    std::unique_ptr<Storage> storage = Prepared(path);
    if (storage == nullptr) ::_exit(100);
    FaultVfs::Instance().Arm(op, nth, error);
    const absl::Status failed = CommitNumber(*storage, 1);
    ::_exit(failed.ok() ? 101 : static_cast<int>(failed.code()));
  }
  int wait_status = 0;
  EXPECT_EQ(::waitpid(child, &wait_status, 0), child);
  EXPECT_TRUE(WIFEXITED(wait_status));
  EXPECT_EQ(WEXITSTATUS(wait_status), static_cast<int>(expected));
  absl::StatusOr<std::unique_ptr<Storage>> reopened = Storage::Open(path);
  EXPECT_THAT(reopened, IsOk());
  if (!reopened.ok()) return -1;
  EXPECT_THAT((*reopened)->database().QuickCheck(), IsOk());
  const int commits = CommitsStored(**reopened);
  EXPECT_THAT(commits, ::testing::AnyOf(1, 2));
  // Whatever was recovered, the database takes the next commit.
  EXPECT_THAT(CommitNumber(**reopened, commits), IsOk());
  return commits;
}

TEST(StorageFaults, CommitMakesAFixedNumberOfWritesAndOneSync) {
  const OpCounts first = CountCommitOperations();
  const OpCounts second = CountCommitOperations();
  // Each -wal frame is two writes (24-byte frame header, 4096-byte page), and the payloads
  // alone fill more than 17 pages.
  EXPECT_GT(first.writes, 2 * (kFramesPerCommit * kPayloadBytes / 4096));
  EXPECT_EQ(first.syncs, 1);  // synchronous=FULL: the -wal once per commit
  EXPECT_EQ(first.truncates, 0);
  EXPECT_EQ(first.shm_maps, 0);  // exclusive mode: the wal-index lives in heap memory
  // Deterministic, so "the Nth write" names the same write in every run.
  EXPECT_EQ(second.writes, first.writes);
  EXPECT_EQ(second.syncs, first.syncs);
  std::printf(
      "commit of %d frames + checkpoint: %lld writes, %lld syncs, %lld truncates, "
      "%lld size hints, %lld shm maps\n",
      kFramesPerCommit, static_cast<long long>(first.writes), static_cast<long long>(first.syncs),
      static_cast<long long>(first.truncates), static_cast<long long>(first.size_hints),
      static_cast<long long>(first.shm_maps));
}

TEST(StorageFaults, DiskFullAtEveryWriteOfACommitIsResourceExhaustedAndRecoverable) {
  const OpCounts counts = CountCommitOperations();
  ASSERT_GT(counts.writes, 0);
  for (int64_t n = 1; n <= counts.writes; ++n) {
    ExpectFailedCommitLeavesNothingAndRecovers(FaultOp::kWrite, n, SQLITE_FULL,
                                               absl::StatusCode::kResourceExhausted);
    if (::testing::Test::HasFailure()) break;  // one failing N explains the rest
  }
}

TEST(StorageFaults, WriteErrorAtEveryWriteOfACommitIsUnavailableAndRecoverable) {
  const OpCounts counts = CountCommitOperations();
  ASSERT_GT(counts.writes, 0);
  for (int64_t n = 1; n <= counts.writes; ++n) {
    ExpectFailedCommitLeavesNothingAndRecovers(FaultOp::kWrite, n, SQLITE_IOERR_WRITE,
                                               absl::StatusCode::kUnavailable);
    if (::testing::Test::HasFailure()) break;
  }
}

TEST(StorageFaults, FsyncErrorAtCommitIsUnavailableAndRecoverable) {
  const OpCounts counts = CountCommitOperations();
  ASSERT_GT(counts.syncs, 0);
  for (int64_t n = 1; n <= counts.syncs; ++n) {
    ExpectFailedCommitLeavesNothingAndRecovers(FaultOp::kSync, n, SQLITE_IOERR_FSYNC,
                                               absl::StatusCode::kUnavailable);
  }
}

TEST(StorageFaults, CrashAfterAFailedWriteRecoversNoneOfTheCommit) {
  const OpCounts counts = CountCommitOperations();
  for (int64_t n = 1; n <= counts.writes; ++n) {
    SCOPED_TRACE(absl::StrCat("write ", n));
    // The commit record is in the last frame; a failed write means it never reached the -wal.
    EXPECT_EQ(CommitsAfterCrashFollowingFailedCommit(FaultOp::kWrite, n, SQLITE_IOERR_WRITE,
                                                     absl::StatusCode::kUnavailable),
              1);
    if (::testing::Test::HasFailure()) break;
  }
}

TEST(StorageFaults, CrashAfterAFailedFsyncRecoversAllOrNoneOfTheCommit) {
  // All frames were written before the fsync failed, so recovery may find the commit complete
  // in the -wal (sqlite_db.h, "Storage faults"). Both outcomes are whole; print which.
  const int commits = CommitsAfterCrashFollowingFailedCommit(FaultOp::kSync, 1, SQLITE_IOERR_FSYNC,
                                                             absl::StatusCode::kUnavailable);
  EXPECT_THAT(commits, ::testing::AnyOf(1, 2));
  std::printf("after a failed fsync and a crash, the reopened database holds %s\n",
              commits == 2 ? "the failed commit (recovered from the -wal)" : "none of it");
}

TEST(StorageFaults, DiskStayingFullFailsEveryCommitUntilSpaceReturns) {
  TempDir dir;
  std::unique_ptr<Storage> storage = Prepared(dir.File("esg.db"));
  ASSERT_NE(storage, nullptr);
  FaultVfs& vfs = FaultVfs::Instance();
  vfs.Arm(FaultOp::kWrite, 1, SQLITE_FULL, FaultPersistence::kUntilDisarmed);
  for (int attempt = 0; attempt < 5; ++attempt) {
    EXPECT_THAT(CommitNumber(*storage, 1),
                StatusIs(absl::StatusCode::kResourceExhausted, HasSubstr("full")));
    // Reads keep working while the disk is full.
    EXPECT_EQ(CommitsStored(*storage), 1);
  }
  EXPECT_GE(vfs.Injected(FaultOp::kWrite), 5);
  EXPECT_THAT(storage->database().QuickCheck(), IsOk());
  vfs.Disarm();
  EXPECT_THAT(CommitNumber(*storage, 1), IsOk());
  EXPECT_EQ(CommitsStored(*storage), 2);
}

TEST(StorageFaults, PersistentWriteAndFsyncErrorsFailEveryCommitUntilDisarmed) {
  for (const auto& [op, error] : {std::pair{FaultOp::kWrite, SQLITE_IOERR_WRITE},
                                  std::pair{FaultOp::kSync, SQLITE_IOERR_FSYNC}}) {
    TempDir dir;
    std::unique_ptr<Storage> storage = Prepared(dir.File("esg.db"));
    ASSERT_NE(storage, nullptr);
    FaultVfs& vfs = FaultVfs::Instance();
    vfs.Arm(op, 1, error, FaultPersistence::kUntilDisarmed);
    for (int attempt = 0; attempt < 3; ++attempt) {
      EXPECT_THAT(CommitNumber(*storage, 1),
                  StatusIs(absl::StatusCode::kUnavailable, HasSubstr("I/O error")));
    }
    vfs.Disarm();
    EXPECT_THAT(CommitNumber(*storage, 1), IsOk());
    EXPECT_EQ(CommitsStored(*storage), 2);
    EXPECT_THAT(storage->database().QuickCheck(), IsOk());
  }
}

TEST(StorageFaults, FailedCheckpointLosesNothingAndCommitsContinue) {
  for (const FaultOp op : {FaultOp::kWrite, FaultOp::kSync, FaultOp::kTruncate}) {
    SCOPED_TRACE(static_cast<int>(op));
    TempDir dir;
    const std::string path = dir.File("esg.db");
    {
      std::unique_ptr<Storage> storage = Prepared(path);
      ASSERT_NE(storage, nullptr);
      ASSERT_THAT(CommitNumber(*storage, 1), IsOk());
      FaultVfs& vfs = FaultVfs::Instance();
      vfs.Arm(op, 1,
              op == FaultOp::kWrite
                  ? SQLITE_IOERR_WRITE
                  : (op == FaultOp::kSync ? SQLITE_IOERR_FSYNC : SQLITE_IOERR_TRUNCATE));
      EXPECT_THAT(storage->database().Execute("PRAGMA wal_checkpoint(TRUNCATE)"),
                  StatusIs(absl::StatusCode::kUnavailable, HasSubstr("I/O error")));
      EXPECT_EQ(vfs.Injected(op), 1);
      vfs.Disarm();
      EXPECT_EQ(CommitsStored(*storage), 2);
      EXPECT_THAT(CommitNumber(*storage, 2), IsOk());
      EXPECT_THAT(storage->database().Execute("PRAGMA wal_checkpoint(TRUNCATE)"), IsOk());
    }
    absl::StatusOr<std::unique_ptr<Storage>> reopened = Storage::Open(path);
    ASSERT_THAT(reopened, IsOk());
    EXPECT_THAT((*reopened)->database().QuickCheck(), IsOk());
    EXPECT_EQ(CommitsStored(**reopened), 3);
  }
}

TEST(StorageFaults, FaultWhileSpillingALargeTransactionIsReportedByTheStatement) {
  // A transaction larger than SQLite's page cache (2 MiB by default) writes pages to the -wal
  // before COMMIT, so the fault surfaces at the INSERT that needed the space.
  TempDir dir;
  std::unique_ptr<Storage> storage = Prepared(dir.File("esg.db"));
  ASSERT_NE(storage, nullptr);
  std::vector<ArchivedFrame> frames;
  for (int64_t s = 100001; s <= 104000; ++s) {
    frames.push_back(Frame(kId, s));
    frames.back().payload.resize(1000, 'x');
  }
  FaultVfs& vfs = FaultVfs::Instance();
  vfs.Arm(FaultOp::kWrite, 1, SQLITE_FULL, FaultPersistence::kUntilDisarmed);
  {
    absl::StatusOr<Transaction> txn = storage->database().Begin();
    ASSERT_THAT(txn, IsOk());
    EXPECT_THAT(storage->archive().AppendBatch(*txn, kId, frames),
                StatusIs(absl::StatusCode::kResourceExhausted, HasSubstr("INSERT")));
    EXPECT_GE(vfs.Injected(FaultOp::kWrite), 1);
  }  // the caller gives up: destruction rolls back
  vfs.Disarm();
  EXPECT_EQ(CommitsStored(*storage), 1);
  EXPECT_THAT(storage->database().QuickCheck(), IsOk());
  EXPECT_THAT(CommitNumber(*storage, 1), IsOk());
  EXPECT_EQ(CommitsStored(*storage), 2);
}

TEST(StorageFaults, FaultVfsForwardsSharedMemoryInSharedMode) {
  TempDir dir;
  DatabaseOptions shared = FaultOptions();
  shared.exclusive = false;
  FaultVfs& vfs = FaultVfs::Instance();
  vfs.ResetCounters();
  auto storage = Storage::Open(dir.File("esg.db"), shared);
  ASSERT_THAT(storage, IsOk());
  ASSERT_THAT(CommitNumber(**storage, 0), IsOk());
  EXPECT_GT(vfs.Calls(FaultOp::kShmMap), 0);  // the -shm is mapped through the shim
  EXPECT_EQ(CommitsStored(**storage), 1);
  EXPECT_THAT((*storage)->database().QuickCheck(), IsOk());
}

TEST(StorageFaults, UnknownVfsIsInvalidArgument) {
  TempDir dir;
  DatabaseOptions options;
  options.vfs = "no-such-vfs";
  EXPECT_THAT(SqliteDatabase::Open(dir.File("a.db"), options),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("no-such-vfs")));
}

// ----------------------------------------------------------------------------------------------
// Files that cannot be written

// Sets the immutable attribute (chattr +i) on `path` for its lifetime; ok() is false, with the
// reason in error(), where the file system or the process's capabilities refuse it.
class Immutable {
 public:
  explicit Immutable(std::string path) : path_(std::move(path)) { ok_ = Set(true); }
  ~Immutable() {
    if (ok_) Set(false);
  }
  Immutable(const Immutable&) = delete;
  Immutable& operator=(const Immutable&) = delete;
  bool ok() const { return ok_; }
  const std::string& error() const { return error_; }

  // chattr -i, for a flag left by a process that died.
  static void Clear(const std::string& path) {
    Immutable flag(path, /*set=*/false);
    flag.Set(false);
  }

 private:
  Immutable(std::string path, bool) : path_(std::move(path)) {}
  bool Set(bool on) {
    const int fd = ::open(path_.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd < 0) {
      error_ = absl::StrCat("open ", path_, ": ", ErrnoText(errno));
      return false;
    }
    int flags = 0;
    bool done = ::ioctl(fd, FS_IOC_GETFLAGS, &flags) == 0;
    if (done) {
      flags = on ? (flags | FS_IMMUTABLE_FL) : (flags & ~FS_IMMUTABLE_FL);
      done = ::ioctl(fd, FS_IOC_SETFLAGS, &flags) == 0;
    }
    if (!done)
      error_ = absl::StrCat("chattr ", on ? "+" : "-", "i ", path_, ": ", ErrnoText(errno));
    ::close(fd);
    return done;
  }

  std::string path_;
  bool ok_ = false;
  std::string error_;
};

// Creates a migrated database with commit 0 at `path` and closes it.
void CreateDatabase(const std::string& path) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  ASSERT_THAT(CommitNumber(**storage, 0), IsOk());
}

TEST(ReadOnly, ImmutableDatabaseFileIsRefusedAtOpen) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  ASSERT_NO_FATAL_FAILURE(CreateDatabase(path));
  Immutable immutable(path);
  if (!immutable.ok()) GTEST_SKIP() << immutable.error();
  // Root ignores mode bits but not the immutable flag: SQLite falls back to a read-only open.
  EXPECT_THAT(Storage::Open(path),
              StatusIs(absl::StatusCode::kFailedPrecondition,
                       HasSubstr("db: " + path + " cannot be written: " + path +
                                 ": Operation not permitted (SQLite could open the file only "
                                 "read-only)")));
  DatabaseOptions shared;
  shared.exclusive = false;
  EXPECT_THAT(SqliteDatabase::Open(path, shared),
              StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("cannot be written")));
}

TEST(ReadOnly, ImmutableDirectoryIsRefusedAtOpen) {
  TempDir dir;
  const std::filesystem::path sub = dir.path() / "var";
  std::filesystem::create_directory(sub);
  const std::string path = (sub / "esg.db").string();
  ASSERT_NO_FATAL_FAILURE(CreateDatabase(path));
  ASSERT_FALSE(std::filesystem::exists(path + "-wal"));  // removed at the last close
  Immutable immutable(sub.string());
  if (!immutable.ok()) GTEST_SKIP() << immutable.error();
  // The -wal cannot be created next to an existing file ...
  EXPECT_THAT(Storage::Open(path),
              StatusIs(absl::StatusCode::kFailedPrecondition,
                       HasSubstr("db: " + path + " cannot be written: directory " + sub.string() +
                                 ": Operation not permitted")));
  // ... and a new file cannot be created at all.
  const std::string fresh = (sub / "new.db").string();
  EXPECT_THAT(Storage::Open(fresh),
              StatusIs(absl::StatusCode::kFailedPrecondition,
                       HasSubstr("db: " + fresh + " cannot be written: directory " + sub.string() +
                                 ": Operation not permitted")));
}

TEST(ReadOnly, ImmutableWalLeftByACrashIsRefusedAtOpen) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  const pid_t child = ::fork();
  if (child == 0) {
    absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
    ::_exit(storage.ok() && CommitNumber(**storage, 0).ok() ? 0 : 1);  // no close: -wal stays
  }
  int wait_status = 0;
  ASSERT_EQ(::waitpid(child, &wait_status, 0), child);
  ASSERT_TRUE(WIFEXITED(wait_status) && WEXITSTATUS(wait_status) == 0);
  ASSERT_TRUE(std::filesystem::exists(path + "-wal"));
  {
    Immutable immutable(path + "-wal");
    if (!immutable.ok()) GTEST_SKIP() << immutable.error();
    EXPECT_THAT(Storage::Open(path), StatusIs(absl::StatusCode::kFailedPrecondition,
                                              HasSubstr("db: " + path + " cannot be written: " +
                                                        path + "-wal: Operation not permitted")));
  }
  // Nothing was lost: the committed transaction is recovered from the -wal.
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  EXPECT_EQ(CommitsStored(**storage), 1);
}

TEST(ReadOnly, DatabaseOnAReadOnlyMountIsRefusedAtOpen) {
  TempDir dir;
  Tmpfs tmpfs(dir, "4m");
  if (!tmpfs.ok()) GTEST_SKIP() << tmpfs.error();
  const std::string path = tmpfs.File("esg.db");
  ASSERT_NO_FATAL_FAILURE(CreateDatabase(path));
  const std::string refused = tmpfs.RemountReadOnly();
  if (!refused.empty()) GTEST_SKIP() << refused;
  EXPECT_THAT(Storage::Open(path), StatusIs(absl::StatusCode::kFailedPrecondition,
                                            HasSubstr("db: " + path + " cannot be written: " +
                                                      path + ": Read-only file system")));
  const std::string fresh = tmpfs.File("new.db");
  EXPECT_THAT(Storage::Open(fresh),
              StatusIs(absl::StatusCode::kFailedPrecondition,
                       HasSubstr("db: " + fresh + " cannot be written: directory")));
}

TEST(ReadOnly, FullDiskAtOpenIsRefusedByTheWriteProbe) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  ASSERT_NO_FATAL_FAILURE(CreateDatabase(path));
  FaultVfs& vfs = FaultVfs::Instance();
  vfs.Arm(FaultOp::kWrite, 1, SQLITE_FULL, FaultPersistence::kUntilDisarmed);
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path, FaultOptions());
  vfs.Disarm();
  EXPECT_THAT(storage, StatusIs(absl::StatusCode::kFailedPrecondition,
                                HasSubstr("db: " + path + " cannot be written: ")));
  EXPECT_THAT(storage, StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("full")));
  EXPECT_THAT(Storage::Open(path, FaultOptions()), IsOk());
}

// ----------------------------------------------------------------------------------------------
// Exclusive locking

TEST(Exclusive, SecondOpenOfTheSameFileIsRefusedUntilTheFirstCloses) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  auto first = Storage::Open(path);
  ASSERT_THAT(first, IsOk());
  DatabaseOptions impatient;
  impatient.busy_timeout = absl::Milliseconds(50);
  EXPECT_THAT(Storage::Open(path, impatient),
              StatusIs(absl::StatusCode::kUnavailable,
                       HasSubstr("db: " + path + " is locked by another process")));
  // A connection that does not ask for exclusivity is refused as well: nobody reads meanwhile.
  impatient.exclusive = false;
  EXPECT_THAT(SqliteDatabase::Open(path, impatient),
              StatusIs(absl::StatusCode::kUnavailable, HasSubstr("is locked by another process")));
  first->reset();
  EXPECT_THAT(Storage::Open(path, impatient), IsOk());
}

TEST(Exclusive, AnotherProcessSeesTheLockAndNoShmFileIsUsed) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  auto storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  ASSERT_THAT(CommitNumber(**storage, 0), IsOk());
  EXPECT_TRUE(std::filesystem::exists(path + "-wal"));
  EXPECT_FALSE(std::filesystem::exists(path + "-shm"));  // the wal-index is in heap memory
  // POSIX record locks are per process: ask from a child whether any part of the file is locked.
  const pid_t child = ::fork();
  if (child == 0) {
    const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
    struct flock query = {};
    query.l_type = F_WRLCK;
    query.l_whence = SEEK_SET;
    query.l_start = 0;
    query.l_len = 0;  // the whole file, including SQLite's lock bytes at 1 GiB
    const bool locked = fd >= 0 && ::fcntl(fd, F_GETLK, &query) == 0 && query.l_type != F_UNLCK;
    ::_exit(locked ? 0 : 1);
  }
  int wait_status = 0;
  ASSERT_EQ(::waitpid(child, &wait_status, 0), child);
  ASSERT_TRUE(WIFEXITED(wait_status));
  EXPECT_EQ(WEXITSTATUS(wait_status), 0) << "no lock visible to another process";
}

TEST(Exclusive, SharedModeStillWorksForSeveralConnections) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  DatabaseOptions shared;
  shared.exclusive = false;
  auto a = Storage::Open(path, shared);
  auto b = Storage::Open(path, shared);
  ASSERT_THAT(a, IsOk());
  ASSERT_THAT(b, IsOk());
  ASSERT_THAT(CommitNumber(**a, 0), IsOk());
  EXPECT_EQ(CommitsStored(**b), 1);
  EXPECT_TRUE(std::filesystem::exists(path + "-shm"));
}

// With a mapped -shm (exclusive = false), making it immutable kills the process with SIGBUS at
// the next store into a page the kernel has written back (sync() here; the periodic writeback
// within ~30 s in a running server). This is the crash operators saw, reproduced.
TEST(ExclusiveDeathTest, SharedMemoryModeDiesOfSigbusWhenTheShmBecomesImmutable) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  {
    // Is chattr possible here at all?
    std::ofstream(dir.File("probe")) << "x";
    Immutable probe(dir.File("probe"));
    if (!probe.ok()) GTEST_SKIP() << probe.error();
  }
  EXPECT_EXIT(
      {
        DatabaseOptions shared;
        shared.exclusive = false;
        auto storage = Storage::Open(path, shared);
        if (!storage.ok() || !CommitNumber(**storage, 0).ok()) ::_exit(2);
        Immutable shm(path + "-shm");
        if (!shm.ok()) ::_exit(3);
        ::sync();
        const absl::Status s = CommitNumber(**storage, 1);
        ::_exit(s.ok() ? 0 : 1);
      },
      ::testing::KilledBySignal(SIGBUS), "");
  // The child died with the flag set; clear it so that the directory can be removed.
  Immutable::Clear(path + "-shm");
}

TEST(Exclusive, ImmutableFilesOfALiveDatabaseGiveStatusesNotSignals) {
  TempDir dir;
  const std::string path = dir.File("esg.db");
  auto storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  ASSERT_THAT(CommitNumber(**storage, 0), IsOk());
  {
    Immutable wal(path + "-wal");
    if (!wal.ok()) GTEST_SKIP() << wal.error();
    ::sync();
    EXPECT_THAT(CommitNumber(**storage, 1),
                StatusIs(absl::StatusCode::kUnavailable, HasSubstr("I/O error")));
    EXPECT_EQ(CommitsStored(**storage), 1);
  }
  ASSERT_THAT(CommitNumber(**storage, 1), IsOk());
  {
    // An immutable database file only stops checkpoints; commits go on into the -wal.
    Immutable db(path);
    ASSERT_TRUE(db.ok()) << db.error();
    ::sync();
    EXPECT_THAT(CommitNumber(**storage, 2), IsOk());
    EXPECT_THAT((*storage)->database().Execute("PRAGMA wal_checkpoint(TRUNCATE)"),
                StatusIs(absl::StatusCode::kUnavailable, HasSubstr("I/O error")));
  }
  EXPECT_THAT((*storage)->database().Execute("PRAGMA wal_checkpoint(TRUNCATE)"), IsOk());
  EXPECT_EQ(CommitsStored(**storage), 3);
  EXPECT_THAT((*storage)->database().QuickCheck(), IsOk());
}

// ----------------------------------------------------------------------------------------------
// A real full file system

TEST(StorageFaults, FullTmpfsIsResourceExhaustedUntilSpaceIsFreed) {
  TempDir dir;
  Tmpfs tmpfs(dir, "2m");
  if (!tmpfs.ok()) GTEST_SKIP() << tmpfs.error();
  const std::string path = tmpfs.File("esg.db");
  const std::string ballast = tmpfs.File("ballast");
  {
    // Space the test gives back later: enough for the failed commit and the checkpoint that
    // copies it and the one before into the database file (about 160 KiB each).
    std::ofstream out(ballast, std::ios::binary);
    out << std::string(640 * 1024, 'b');
  }
  auto storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  // Checkpoint after every commit, so the data ends up in the database file and the -wal stays
  // small. (Without it the -wal would hold everything, and copying it into the database at a
  // checkpoint needs as much space again: on a nearly full disk that checkpoint fails, the -wal
  // is never reset, and even the write probe of the next Open() finds the disk full.)
  absl::Status failed;
  int k = 0;
  for (; k < 100; ++k) {
    failed = CommitNumber(**storage, k);
    if (!failed.ok()) break;
    (*storage)->database().Execute("PRAGMA wal_checkpoint(TRUNCATE)").IgnoreError();
  }
  ASSERT_LT(k, 100) << "2 MiB never filled up";
  EXPECT_THAT(failed, StatusIs(absl::StatusCode::kResourceExhausted,
                               HasSubstr("database or disk is full")));
  EXPECT_EQ(CommitsStored(**storage), k);
  EXPECT_THAT((*storage)->database().QuickCheck(), IsOk());
  // Still full: the same commit fails the same way, quickly.
  EXPECT_THAT(CommitNumber(**storage, k),
              StatusIs(absl::StatusCode::kResourceExhausted, ::testing::_));
  std::filesystem::remove(ballast);
  EXPECT_THAT(CommitNumber(**storage, k), IsOk());
  EXPECT_EQ(CommitsStored(**storage), k + 1);
  EXPECT_THAT((*storage)->database().Execute("PRAGMA wal_checkpoint(TRUNCATE)"), IsOk());
  storage->reset();
  auto reopened = Storage::Open(path);
  ASSERT_THAT(reopened, IsOk());
  EXPECT_EQ(CommitsStored(**reopened), k + 1);
  EXPECT_THAT((*reopened)->database().QuickCheck(), IsOk());
  std::printf("2 MiB tmpfs with 640 KiB ballast: commit %d of %d frames failed with: %s\n", k,
              kFramesPerCommit, std::string(failed.message()).c_str());
}

}  // namespace
}  // namespace esg::storage
