// Hands memory freed after large answers back to the operating system (docs/service.md
// "Memory").
//
// glibc's malloc keeps freed memory in its arenas for reuse: a 100 000-sample prediction with
// AEM builds some 33 MB of response, freed once written, but esgd's resident set stays at its
// peak (8 such predictions at once took it from 354 MB to about 1.1 GB, and it stayed there).
// After large answers, and after a subscriber's unread queue is dropped, the service notes the
// bytes it freed; once enough are noted, a background thread calls malloc_trim(0), which
// returns the free pages of every arena (glibc >= 2.8 releases whole free pages inside the
// heaps, not only its top).
#ifndef ESG_SERVER_MEMORY_RELEASE_H_
#define ESG_SERVER_MEMORY_RELEASE_H_

#include <cstdint>

namespace esg::server {

// Fixes glibc malloc's thresholds for a server process (call once, first thing in main):
// blocks of kMmapThresholdBytes or more get their own mapping (returned to the system when
// freed), and an arena's free top beyond kTrimThresholdBytes is returned on free. By default
// glibc raises both thresholds as it sees large blocks freed (the mmap threshold up to 32 MiB,
// the trim threshold to twice that), after which each thread arena keeps up to 64 MiB of free
// top that malloc_trim does not return (it trims only the main arena's top): measured with
// scripts/memory_after_predictions.sh, eight 100 000-sample predictions left esgd at 223 MiB
// instead of 29 MiB, six prediction arenas holding 21-32 MiB each (with an 8 MiB trim
// threshold: 35 MiB). Setting the thresholds turns that adjustment off (mallopt(3)).
void ConfigureMalloc();

inline constexpr int kMmapThresholdBytes = 1 << 20;
inline constexpr int kTrimThresholdBytes = 1 << 20;

// Notes that about `bytes` of heap were, or are about to be, freed (a response written, a queue
// dropped). Once kTrimAfterBytes are noted, malloc_trim(0) runs on a background thread
// 300 ms later (time for gRPC to destroy the call that held the response), then again 2 s and
// 12 s later (what is freed later on a loaded machine); notes before the first trim join that
// run. Cheap and thread-safe; never blocks the caller.
void NoteFreedMemory(int64_t bytes);

inline constexpr int64_t kTrimAfterBytes = int64_t{16} << 20;

// Number of malloc_trim runs so far (tests, diagnostics).
int64_t MemoryTrims();

}  // namespace esg::server

#endif  // ESG_SERVER_MEMORY_RELEASE_H_
