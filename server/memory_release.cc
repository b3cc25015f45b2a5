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

// When to trim after the service noted freed memory: first once gRPC has had time to destroy
// the call (its arena holds the response), then twice more for what is freed later on a loaded
// machine (the last of eight concurrent predictions' buffers, a peer that reads slowly).
// Measured on CI with one trim at 300 ms: 58 MiB left where 32-42 MiB were seen unloaded.
constexpr absl::Duration kTrimDelays[] = {absl::Milliseconds(300), absl::Seconds(2),
                                          absl::Seconds(10)};

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
  // A detached thread: at most one scheduling at a time, living about 12 s plus the trims
  // themselves (a few milliseconds per hundred MB of heap). Notes after its first trim schedule
  // a new run; the later trims of this one only return what was freed since.
  std::thread([] {
    bool first = true;
    for (const absl::Duration delay : kTrimDelays) {
      absl::SleepFor(delay);
      if (first) {
        noted.store(0);
        scheduled.store(false);
        first = false;
      }
      malloc_trim(0);
      trims.fetch_add(1);
    }
  }).detach();
}

int64_t MemoryTrims() { return trims.load(); }

}  // namespace esg::server
