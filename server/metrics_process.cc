// Process and build metrics (see metrics_process.h).
#include "server/metrics_process.h"

#include <dirent.h>
#include <sys/resource.h>
#include <unistd.h>

#include <fstream>
#include <limits>
#include <memory>
#include <sstream>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/synchronization/mutex.h"

// Set for this file alone by server/CMakeLists.txt, so a new commit recompiles nothing else.
#ifndef ESG_VERSION
#define ESG_VERSION ""
#endif
#ifndef ESG_GIT_COMMIT
#define ESG_GIT_COMMIT ""
#endif

namespace esg::server {
namespace {

absl::StatusOr<std::string> ReadText(const char* path) {
  std::ifstream in(path);
  if (!in) return absl::UnavailableError(absl::StrCat("process: cannot read ", path));
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

// btime of /proc/stat: the boot time, Unix seconds.
absl::StatusOr<int64_t> BootTime() {
  absl::StatusOr<std::string> stat = ReadText("/proc/stat");
  if (!stat.ok()) return stat.status();
  for (absl::string_view line : absl::StrSplit(*stat, '\n')) {
    int64_t seconds = 0;
    if (absl::ConsumePrefix(&line, "btime ") && absl::SimpleAtoi(line, &seconds)) return seconds;
  }
  return absl::UnavailableError("process: no btime in /proc/stat");
}

// Entries of /proc/self/fd, without the one this listing opens.
absl::StatusOr<int> OpenFds() {
  DIR* dir = opendir("/proc/self/fd");
  if (dir == nullptr) return absl::UnavailableError("process: cannot list /proc/self/fd");
  int n = 0;
  while (const dirent* e = readdir(dir)) {
    if (e->d_name[0] != '.') ++n;
  }
  closedir(dir);
  return n - 1;
}

}  // namespace

double CgroupMemoryLimit(absl::string_view proc_self_cgroup, const std::string& cgroup_root) {
  constexpr double kUnlimited = std::numeric_limits<double>::infinity();
  // Inside a container the cgroup namespace makes the process's own cgroup the root, so the
  // path named in /proc/self/cgroup is tried first, then the root.
  std::vector<std::string> files;
  for (absl::string_view line : absl::StrSplit(proc_self_cgroup, '\n', absl::SkipEmpty())) {
    const std::vector<absl::string_view> parts = absl::StrSplit(line, absl::MaxSplits(':', 2));
    if (parts.size() != 3) continue;
    const std::string path(parts[2] == "/" ? "" : parts[2]);
    if (parts[0] == "0" && parts[1].empty()) {
      files.push_back(absl::StrCat(cgroup_root, path, "/memory.max"));
      files.push_back(absl::StrCat(cgroup_root, "/memory.max"));
    } else if (absl::StrContains(absl::StrCat(",", parts[1], ","), ",memory,")) {
      files.push_back(absl::StrCat(cgroup_root, "/memory", path, "/memory.limit_in_bytes"));
      files.push_back(absl::StrCat(cgroup_root, "/memory/memory.limit_in_bytes"));
    }
  }
  for (const std::string& file : files) {
    absl::StatusOr<std::string> text = ReadText(file.c_str());
    if (!text.ok()) continue;
    const absl::string_view value = absl::StripAsciiWhitespace(*text);
    if (value == "max") return kUnlimited;
    double bytes = 0;
    if (!absl::SimpleAtod(value, &bytes)) continue;
    return bytes >= 0x1p60 ? kUnlimited : bytes;
  }
  return kUnlimited;
}

absl::StatusOr<ProcessStats> ParseProcStat(absl::string_view stat, int64_t boot_time_seconds,
                                           int64_t ticks_per_second, int64_t page_bytes) {
  // "pid (comm) state ppid ...": comm may hold spaces and parentheses, so fields are counted
  // from the last ')'; after it field 3 (state) comes first (proc(5)).
  const size_t close = stat.rfind(')');
  if (close == absl::string_view::npos || ticks_per_second <= 0) {
    return absl::InvalidArgumentError("process: not a /proc/<pid>/stat line");
  }
  const std::vector<absl::string_view> f =
      absl::StrSplit(stat.substr(close + 1), ' ', absl::SkipWhitespace());
  auto field = [&](int number, double* out) {
    const size_t i = static_cast<size_t>(number - 3);
    return i < f.size() && absl::SimpleAtod(f[i], out);
  };
  double utime = 0, stime = 0, threads = 0, start = 0, vsize = 0, rss = 0;
  if (!field(14, &utime) || !field(15, &stime) || !field(20, &threads) || !field(22, &start) ||
      !field(23, &vsize) || !field(24, &rss)) {
    return absl::InvalidArgumentError("process: not a /proc/<pid>/stat line");
  }
  ProcessStats s;
  const double ticks = static_cast<double>(ticks_per_second);
  s.cpu_seconds = (utime + stime) / ticks;
  s.threads = threads;
  s.start_time_seconds = static_cast<double>(boot_time_seconds) + start / ticks;
  s.virtual_memory_bytes = vsize;
  s.resident_memory_bytes = rss * static_cast<double>(page_bytes);
  return s;
}

absl::StatusOr<ProcessStats> ReadProcessStats() {
  absl::StatusOr<std::string> stat = ReadText("/proc/self/stat");
  if (!stat.ok()) return stat.status();
  absl::StatusOr<int64_t> boot = BootTime();
  if (!boot.ok()) return boot.status();
  absl::StatusOr<ProcessStats> s =
      ParseProcStat(*stat, *boot, sysconf(_SC_CLK_TCK), sysconf(_SC_PAGESIZE));
  if (!s.ok()) return s.status();
  absl::StatusOr<int> fds = OpenFds();
  if (!fds.ok()) return fds.status();
  s->open_fds = *fds;
  rlimit limit{};
  if (getrlimit(RLIMIT_NOFILE, &limit) == 0) {
    s->max_fds = static_cast<double>(limit.rlim_cur);
  }
  absl::StatusOr<std::string> cgroup = ReadText("/proc/self/cgroup");
  s->memory_limit_bytes = CgroupMemoryLimit(cgroup.ok() ? *cgroup : "", "/sys/fs/cgroup");
  return s;
}

void AddProcessMetrics(MetricsRegistry& registry) {
  // The names, help texts and units of Prometheus' Go and Python clients, so that dashboards
  // written for them apply.
  Gauge& resident =
      registry.AddGauge("process_resident_memory_bytes", "Resident memory size in bytes.").Get();
  Gauge& virtual_memory =
      registry.AddGauge("process_virtual_memory_bytes", "Virtual memory size in bytes.").Get();
  Counter& cpu = registry
                     .AddCounter("process_cpu_seconds_total",
                                 "Total user and system CPU time spent in seconds.")
                     .Get();
  Gauge& open_fds = registry.AddGauge("process_open_fds", "Number of open file descriptors.").Get();
  Gauge& max_fds =
      registry.AddGauge("process_max_fds", "Maximum number of open file descriptors.").Get();
  Gauge& start = registry
                     .AddGauge("process_start_time_seconds",
                               "Start time of the process since unix epoch in seconds.")
                     .Get();
  Gauge& threads =
      registry.AddGauge("process_threads", "Number of OS threads in the process.").Get();
  Gauge& memory_limit = registry
                            .AddGauge("esgd_memory_limit_bytes",
                                      "The memory limit of esgd's cgroup (cgroup v2 memory.max, v1 "
                                      "memory.limit_in_bytes), bytes; +Inf when none is set.")
                            .Get();
  // Scrapes may run at once: the counter is advanced by the difference under one mutex.
  auto mu = std::make_shared<absl::Mutex>();
  registry.AddCollector(
      [=, &resident, &virtual_memory, &cpu, &open_fds, &max_fds, &start, &threads, &memory_limit] {
        absl::StatusOr<ProcessStats> s = ReadProcessStats();
        if (!s.ok()) return;
        absl::MutexLock lock(mu.get());
        resident.Set(s->resident_memory_bytes);
        virtual_memory.Set(s->virtual_memory_bytes);
        cpu.Increment(s->cpu_seconds - cpu.Value());
        open_fds.Set(s->open_fds);
        max_fds.Set(s->max_fds);
        start.Set(s->start_time_seconds);
        threads.Set(s->threads);
        memory_limit.Set(s->memory_limit_bytes);
      });
}

std::string BuildVersion() { return ESG_VERSION; }
std::string BuildCommit() { return ESG_GIT_COMMIT; }

void AddBuildInfo(MetricsRegistry& registry) {
  registry
      .AddGauge("esgd_build_info",
                "Always 1; the labels name the build: version (the project's) and commit (git, "
                "at configuration; empty outside a checkout).",
                {"version", "commit"})
      .With({BuildVersion(), BuildCommit()})
      .Set(1);
}

}  // namespace esg::server
