// Freed memory back to the operating system (see memory_release.h).
#include "server/memory_release.h"

#include <malloc.h>

#include <atomic>
#include <cstdint>
#include <thread>

#include "absl/time/clock.h"
#include "absl/time/time.h"

namespace esg::server {
namespace {

// Time for gRPC to destroy the call (its arena holds the response) after the service noted it.
constexpr absl::Duration kTrimDelay = absl::Milliseconds(300);

std::atomic<int64_t> noted{0};
std::atomic<bool> scheduled{false};
std::atomic<int64_t> trims{0};

}  // namespace

void ConfigureMalloc() {
  mallopt(M_MMAP_THRESHOLD, kMmapThresholdBytes);
  mallopt(M_TRIM_THRESHOLD, kTrimThresholdBytes);
}

void NoteFreedMemory(int64_t bytes) {
  if (bytes <= 0) return;
  if (noted.fetch_add(bytes) + bytes < kTrimAfterBytes) return;
  if (scheduled.exchange(true)) return;  // a run is coming; it covers these bytes too
  // A detached thread: at most one at a time, living kTrimDelay plus the trim itself (a few
  // milliseconds per hundred MB of heap).
  std::thread([] {
    absl::SleepFor(kTrimDelay);
    noted.store(0);
    scheduled.store(false);
    malloc_trim(0);
    trims.fetch_add(1);
  }).detach();
}

int64_t MemoryTrims() { return trims.load(); }

}  // namespace esg::server
