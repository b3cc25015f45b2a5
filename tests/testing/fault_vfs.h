// A fault-injecting SQLite VFS for tests, after SQLite's own test harness (src/test_vfs.c, the
// "inject I/O errors" loops of its TCL tests): a shim registered under the name "esg-fault" that
// forwards every call to the default VFS ("unix") and, when armed, makes the Nth call of one
// kind of file operation fail with an SQLite error code of the test's choice, as a full disk or
// a failing device would. Open a Database or Storage through it with DatabaseOptions::vfs =
// FaultVfs::kName; everything else behaves exactly like the default VFS.
//
// Typical use (a disk that fills up at the 3rd write of the next commit and stays full):
//   FaultVfs& vfs = FaultVfs::Instance();          // registers "esg-fault" once per process
//   DatabaseOptions options;
//   options.vfs = FaultVfs::kName;
//   auto storage = Storage::Open(path, options);
//   vfs.Arm(FaultOp::kWrite, 3, SQLITE_FULL, FaultPersistence::kUntilDisarmed);
//   ... ArchiveFrames() now returns ResourceExhausted ...
//   vfs.Disarm();                                  // space is back
//
// Counting: every call of an operation on any file opened through the VFS (main database, -wal,
// -shm, journals, temp files) counts, in every thread and every connection using the VFS. Arm()
// restarts the count of its operation at zero; ResetCounters() restarts all of them. The VFS is
// one process-wide object, so tests that arm it must not run concurrently with other tests
// that use it in the same process (gtest runs the tests of one binary sequentially).
//
// Thread-safe: all state is std::atomic; Arm/Disarm may be called while other threads use
// connections opened through the VFS (a call racing with Arm() may count either before or after
// it).
#ifndef ESG_TESTS_TESTING_FAULT_VFS_H_
#define ESG_TESTS_TESTING_FAULT_VFS_H_

#include <array>
#include <atomic>
#include <cstdint>

namespace esg::testing {

// The file operations the VFS can fail.
enum class FaultOp {
  kWrite,     // xWrite: write(2) of pages to the database, -wal or a journal
  kSync,      // xSync: fsync/fdatasync of the database or -wal
  kTruncate,  // xTruncate: ftruncate of the database or -wal (checkpoints, journal_size_limit)
  kSizeHint,  // xFileControl(SQLITE_FCNTL_SIZE_HINT): SQLite ignores its result
  kShmMap,    // xShmMap: mapping or growing the -shm wal-index (not used in exclusive mode)
};
inline constexpr int kNumFaultOps = 5;

enum class FaultPersistence {
  kOnce,           // only call number `nth` fails (a transient error)
  kUntilDisarmed,  // call `nth` and every later one fail until Disarm() (a disk that stays full)
};

class FaultVfs {
 public:
  // The name to put into DatabaseOptions::vfs.
  static constexpr const char* kName = "esg-fault";

  // The process-wide instance; the first call registers the VFS with SQLite (not as the
  // default VFS). Aborts if the default VFS cannot be found, which a working SQLite never does.
  static FaultVfs& Instance();

  FaultVfs(const FaultVfs&) = delete;
  FaultVfs& operator=(const FaultVfs&) = delete;

  // Restarts the count of `op` at zero and makes its call number `nth` (1-based) fail with
  // `sqlite_error` (e.g. SQLITE_FULL, SQLITE_IOERR_WRITE, SQLITE_IOERR_FSYNC): the call is not
  // forwarded, so nothing is written, synced or truncated. With kUntilDisarmed every later call
  // of `op` fails too. Other operations keep their own arming. `nth` < 1 disarms `op`.
  void Arm(FaultOp op, int64_t nth, int sqlite_error,
           FaultPersistence persistence = FaultPersistence::kOnce);
  // Stops injecting faults for every operation. Counters keep counting.
  void Disarm();
  // Sets every call and injection counter to zero (arming is kept).
  void ResetCounters();

  // Calls of `op` since it was last armed or the counters were reset, including failed ones.
  int64_t Calls(FaultOp op) const;
  // Calls of `op` that were made to fail in that time.
  int64_t Injected(FaultOp op) const;

  // For the VFS callbacks (fault_vfs.cc): counts one call of `op` and returns 0 to forward it,
  // or the SQLite error code to return instead.
  int CountCall(FaultOp op);

 private:
  FaultVfs() = default;

  struct OpState {
    std::atomic<int64_t> calls{0};
    std::atomic<int64_t> injected{0};
    std::atomic<int64_t> nth{0};  // 0: disarmed
    std::atomic<int> error{0};
    std::atomic<bool> persistent{false};
  };
  std::array<OpState, kNumFaultOps> ops_;
};

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_FAULT_VFS_H_
