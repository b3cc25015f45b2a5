// The "esg-fault" SQLite VFS shim; contract in fault_vfs.h. Each file opened through it is a
// FaultFile: our sqlite3_file header followed by the real VFS's file object, and every method
// forwards to the real one after FaultVfs::CountCall() allowed it.
#include "tests/testing/fault_vfs.h"

#include <sqlite3.h>

#include <cstdlib>
#include <cstring>
#include <mutex>

namespace esg::testing {
namespace {

sqlite3_vfs* g_real = nullptr;  // the default VFS at registration time
sqlite3_vfs g_vfs;              // the shim

struct FaultFile {
  sqlite3_file base;   // base.pMethods points at one of the kMethods tables below
  sqlite3_file* real;  // the real VFS's file object, stored right after this struct
};

sqlite3_file* Real(sqlite3_file* f) { return reinterpret_cast<FaultFile*>(f)->real; }

int Fail(FaultOp op) { return FaultVfs::Instance().CountCall(op); }

// --- sqlite3_io_methods ----------------------------------------------------------------------

int Close(sqlite3_file* f) {
  sqlite3_file* real = Real(f);
  return real->pMethods != nullptr ? real->pMethods->xClose(real) : SQLITE_OK;
}
int Read(sqlite3_file* f, void* buf, int amount, sqlite3_int64 offset) {
  return Real(f)->pMethods->xRead(Real(f), buf, amount, offset);
}
int Write(sqlite3_file* f, const void* buf, int amount, sqlite3_int64 offset) {
  if (const int rc = Fail(FaultOp::kWrite); rc != 0) return rc;
  return Real(f)->pMethods->xWrite(Real(f), buf, amount, offset);
}
int Truncate(sqlite3_file* f, sqlite3_int64 size) {
  if (const int rc = Fail(FaultOp::kTruncate); rc != 0) return rc;
  return Real(f)->pMethods->xTruncate(Real(f), size);
}
int Sync(sqlite3_file* f, int flags) {
  if (const int rc = Fail(FaultOp::kSync); rc != 0) return rc;
  return Real(f)->pMethods->xSync(Real(f), flags);
}
int FileSize(sqlite3_file* f, sqlite3_int64* size) {
  return Real(f)->pMethods->xFileSize(Real(f), size);
}
int Lock(sqlite3_file* f, int level) { return Real(f)->pMethods->xLock(Real(f), level); }
int Unlock(sqlite3_file* f, int level) { return Real(f)->pMethods->xUnlock(Real(f), level); }
int CheckReservedLock(sqlite3_file* f, int* out) {
  return Real(f)->pMethods->xCheckReservedLock(Real(f), out);
}
int FileControl(sqlite3_file* f, int op, void* arg) {
  if (op == SQLITE_FCNTL_SIZE_HINT) {
    if (const int rc = Fail(FaultOp::kSizeHint); rc != 0) return rc;
  }
  return Real(f)->pMethods->xFileControl(Real(f), op, arg);
}
int SectorSize(sqlite3_file* f) { return Real(f)->pMethods->xSectorSize(Real(f)); }
int DeviceCharacteristics(sqlite3_file* f) {
  return Real(f)->pMethods->xDeviceCharacteristics(Real(f));
}
int ShmMap(sqlite3_file* f, int region, int size, int extend, void volatile** out) {
  if (const int rc = Fail(FaultOp::kShmMap); rc != 0) return rc;
  return Real(f)->pMethods->xShmMap(Real(f), region, size, extend, out);
}
int ShmLock(sqlite3_file* f, int offset, int n, int flags) {
  return Real(f)->pMethods->xShmLock(Real(f), offset, n, flags);
}
void ShmBarrier(sqlite3_file* f) { Real(f)->pMethods->xShmBarrier(Real(f)); }
int ShmUnmap(sqlite3_file* f, int delete_flag) {
  return Real(f)->pMethods->xShmUnmap(Real(f), delete_flag);
}
int Fetch(sqlite3_file* f, sqlite3_int64 offset, int amount, void** out) {
  return Real(f)->pMethods->xFetch(Real(f), offset, amount, out);
}
int Unfetch(sqlite3_file* f, sqlite3_int64 offset, void* p) {
  return Real(f)->pMethods->xUnfetch(Real(f), offset, p);
}

// One table per io_methods version, so SQLite sees exactly the capabilities of the real file
// (for example, a version-1 file has no shared memory and cannot be used in WAL mode).
constexpr sqlite3_io_methods MethodsOfVersion(int version) {
  return {version,
          Close,
          Read,
          Write,
          Truncate,
          Sync,
          FileSize,
          Lock,
          Unlock,
          CheckReservedLock,
          FileControl,
          SectorSize,
          DeviceCharacteristics,
          version >= 2 ? ShmMap : nullptr,
          version >= 2 ? ShmLock : nullptr,
          version >= 2 ? ShmBarrier : nullptr,
          version >= 2 ? ShmUnmap : nullptr,
          version >= 3 ? Fetch : nullptr,
          version >= 3 ? Unfetch : nullptr};
}
const sqlite3_io_methods kMethods[3] = {MethodsOfVersion(1), MethodsOfVersion(2),
                                        MethodsOfVersion(3)};

// --- sqlite3_vfs -------------------------------------------------------------------------------

int Open(sqlite3_vfs*, sqlite3_filename name, sqlite3_file* f, int flags, int* out_flags) {
  FaultFile* file = reinterpret_cast<FaultFile*>(f);
  file->real = reinterpret_cast<sqlite3_file*>(file + 1);
  std::memset(file->real, 0, static_cast<size_t>(g_real->szOsFile));
  const int rc = g_real->xOpen(g_real, name, file->real, flags, out_flags);
  // SQLite calls xClose whenever pMethods is set, even after a failed open (the real VFS sets
  // its own pMethods only when there is something to close).
  const sqlite3_io_methods* methods = file->real->pMethods;
  if (methods == nullptr) {
    f->pMethods = nullptr;
  } else {
    const int version = methods->iVersion < 1 ? 1 : (methods->iVersion > 3 ? 3 : methods->iVersion);
    f->pMethods = &kMethods[version - 1];
  }
  return rc;
}
int Delete(sqlite3_vfs*, const char* name, int sync_dir) {
  return g_real->xDelete(g_real, name, sync_dir);
}
int Access(sqlite3_vfs*, const char* name, int flags, int* out) {
  return g_real->xAccess(g_real, name, flags, out);
}
int FullPathname(sqlite3_vfs*, const char* name, int size, char* out) {
  return g_real->xFullPathname(g_real, name, size, out);
}
void* DlOpen(sqlite3_vfs*, const char* name) { return g_real->xDlOpen(g_real, name); }
void DlError(sqlite3_vfs*, int size, char* out) { g_real->xDlError(g_real, size, out); }
void (*DlSym(sqlite3_vfs*, void* handle, const char* symbol))(void) {
  return g_real->xDlSym(g_real, handle, symbol);
}
void DlClose(sqlite3_vfs*, void* handle) { g_real->xDlClose(g_real, handle); }
int Randomness(sqlite3_vfs*, int size, char* out) { return g_real->xRandomness(g_real, size, out); }
int Sleep(sqlite3_vfs*, int microseconds) { return g_real->xSleep(g_real, microseconds); }
int CurrentTime(sqlite3_vfs*, double* out) { return g_real->xCurrentTime(g_real, out); }
int GetLastError(sqlite3_vfs*, int size, char* out) {
  return g_real->xGetLastError != nullptr ? g_real->xGetLastError(g_real, size, out) : 0;
}
int CurrentTimeInt64(sqlite3_vfs*, sqlite3_int64* out) {
  return g_real->xCurrentTimeInt64(g_real, out);
}
int SetSystemCall(sqlite3_vfs*, const char* name, sqlite3_syscall_ptr call) {
  return g_real->xSetSystemCall(g_real, name, call);
}
sqlite3_syscall_ptr GetSystemCall(sqlite3_vfs*, const char* name) {
  return g_real->xGetSystemCall(g_real, name);
}
const char* NextSystemCall(sqlite3_vfs*, const char* name) {
  return g_real->xNextSystemCall(g_real, name);
}

void Register() {
  g_real = sqlite3_vfs_find(nullptr);
  if (g_real == nullptr) std::abort();
  g_vfs = sqlite3_vfs{};
  // Version 2 and 3 members are forwarded only if the real VFS has them.
  g_vfs.iVersion = g_real->iVersion < 3 ? g_real->iVersion : 3;
  g_vfs.szOsFile = static_cast<int>(sizeof(FaultFile)) + g_real->szOsFile;
  g_vfs.mxPathname = g_real->mxPathname;
  g_vfs.zName = FaultVfs::kName;
  g_vfs.xOpen = Open;
  g_vfs.xDelete = Delete;
  g_vfs.xAccess = Access;
  g_vfs.xFullPathname = FullPathname;
  g_vfs.xDlOpen = DlOpen;
  g_vfs.xDlError = DlError;
  g_vfs.xDlSym = DlSym;
  g_vfs.xDlClose = DlClose;
  g_vfs.xRandomness = Randomness;
  g_vfs.xSleep = Sleep;
  g_vfs.xCurrentTime = CurrentTime;
  g_vfs.xGetLastError = GetLastError;
  if (g_vfs.iVersion >= 2) g_vfs.xCurrentTimeInt64 = CurrentTimeInt64;
  if (g_vfs.iVersion >= 3) {
    g_vfs.xSetSystemCall = SetSystemCall;
    g_vfs.xGetSystemCall = GetSystemCall;
    g_vfs.xNextSystemCall = NextSystemCall;
  }
  if (sqlite3_vfs_register(&g_vfs, /*makeDflt=*/0) != SQLITE_OK) std::abort();
}

}  // namespace

FaultVfs& FaultVfs::Instance() {
  static FaultVfs* const instance = new FaultVfs();
  static std::once_flag registered;
  std::call_once(registered, Register);
  return *instance;
}

void FaultVfs::Arm(FaultOp op, int64_t nth, int sqlite_error, FaultPersistence persistence) {
  OpState& s = ops_[static_cast<int>(op)];
  s.nth.store(0);  // disarmed while the rest changes
  s.calls.store(0);
  s.injected.store(0);
  s.error.store(sqlite_error);
  s.persistent.store(persistence == FaultPersistence::kUntilDisarmed);
  s.nth.store(nth < 1 ? 0 : nth);
}

void FaultVfs::Disarm() {
  for (OpState& s : ops_) s.nth.store(0);
}

void FaultVfs::ResetCounters() {
  for (OpState& s : ops_) {
    s.calls.store(0);
    s.injected.store(0);
  }
}

int64_t FaultVfs::Calls(FaultOp op) const { return ops_[static_cast<int>(op)].calls.load(); }

int64_t FaultVfs::Injected(FaultOp op) const { return ops_[static_cast<int>(op)].injected.load(); }

int FaultVfs::CountCall(FaultOp op) {
  OpState& s = ops_[static_cast<int>(op)];
  const int64_t n = s.calls.fetch_add(1) + 1;
  const int64_t nth = s.nth.load();
  if (nth == 0) return 0;
  if (n == nth || (n > nth && s.persistent.load())) {
    s.injected.fetch_add(1);
    return s.error.load();
  }
  return 0;
}

}  // namespace esg::testing
