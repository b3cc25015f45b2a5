// The process metrics of Prometheus' client libraries (process_resident_memory_bytes,
// process_cpu_seconds_total, process_open_fds, process_max_fds, process_start_time_seconds, and
// process_virtual_memory_bytes, process_threads) read from /proc/self at each scrape,
// esgd_memory_limit_bytes (the memory limit of esgd's cgroup, for an alert on memory near it) and
// esgd_build_info{version,commit} (docs/service.md "Metrics"; docs/decisions.md D55 says why
// /proc and not prometheus-cpp). Linux only, as esgd is.
#ifndef ESG_SERVER_METRICS_PROCESS_H_
#define ESG_SERVER_METRICS_PROCESS_H_

#include <cstdint>
#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "server/metrics.h"

namespace esg::server {

struct ProcessStats {
  double resident_memory_bytes = 0;
  double virtual_memory_bytes = 0;
  double cpu_seconds = 0;         // user + system
  double start_time_seconds = 0;  // Unix time
  double open_fds = 0;
  double max_fds = 0;  // the soft RLIMIT_NOFILE
  double threads = 0;
  // The cgroup's memory limit (v2 memory.max, v1 memory.limit_in_bytes); +Inf when none is set
  // or it cannot be read.
  double memory_limit_bytes = 0;
};

// This process's figures. Unavailable "process: ..." when /proc cannot be read.
absl::StatusOr<ProcessStats> ReadProcessStats();

// The fields of a /proc/<pid>/stat line, and /proc/stat's btime (exposed for the tests).
// InvalidArgument when `stat` is not such a line.
absl::StatusOr<ProcessStats> ParseProcStat(absl::string_view stat, int64_t boot_time_seconds,
                                           int64_t ticks_per_second, int64_t page_bytes);

// The memory limit of the cgroup named by `proc_self_cgroup` (the text of /proc/self/cgroup),
// read under `cgroup_root` (/sys/fs/cgroup): +Inf for "max", a v1 "unlimited" (>= 2^60) or a
// file that cannot be read.
double CgroupMemoryLimit(absl::string_view proc_self_cgroup, const std::string& cgroup_root);

// Adds the process_* families to `registry` and a collector that sets them at each scrape (a
// failed read leaves the last values).
void AddProcessMetrics(MetricsRegistry& registry);

// Adds esgd_build_info{version,commit} = 1: the project version and the git commit the build was
// configured at (empty outside a git checkout).
void AddBuildInfo(MetricsRegistry& registry);

// The version and commit that AddBuildInfo exposes.
std::string BuildVersion();
std::string BuildCommit();

}  // namespace esg::server

#endif  // ESG_SERVER_METRICS_PROCESS_H_
