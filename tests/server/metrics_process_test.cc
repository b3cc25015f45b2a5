// Tests of server/metrics_process.h: a /proc/<pid>/stat line parsed (a command name with spaces
// and parentheses), the cgroup memory limit of cgroup v1 and v2 layouts, this process's own
// figures, and the build info. The running esgd's are in operations_kit_test.cc.
#include "server/metrics_process.h"

#include <unistd.h>

#include <cmath>
#include <ctime>
#include <filesystem>
#include <string>

#include "absl/time/clock.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/prometheus_text.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::server {
namespace {

TEST(ProcessMetrics, ParsesAStatLineFromTheLastParenthesis) {
  // Fields 14/15 utime/stime 250+150 ticks, 20 threads 9, 22 starttime 500 ticks, 23 vsize,
  // 24 rss 1000 pages (proc(5)).
  const std::string stat =
      "4242 (esgd (a) b) S 1 4242 4242 0 -1 4194560 100 0 0 0 250 150 0 0 20 0 9 0 500 "
      "123456789 1000 18446744073709551615 1 1 0 0 0 0 0 0 0 0 0 0 17 1 0 0 0 0 0";
  absl::StatusOr<ProcessStats> s = ParseProcStat(stat, 1700000000, 100, 4096);
  ASSERT_TRUE(s.ok()) << s.status();
  EXPECT_DOUBLE_EQ(s->cpu_seconds, 4.0);
  EXPECT_DOUBLE_EQ(s->threads, 9);
  EXPECT_DOUBLE_EQ(s->start_time_seconds, 1700000005.0);
  EXPECT_DOUBLE_EQ(s->virtual_memory_bytes, 123456789);
  EXPECT_DOUBLE_EQ(s->resident_memory_bytes, 4096000);
  EXPECT_FALSE(ParseProcStat("4242 esgd S 1", 0, 100, 4096).ok());
  EXPECT_FALSE(ParseProcStat("4242 (esgd) S 1 2 3", 0, 100, 4096).ok());
}

TEST(ProcessMetrics, ReadsTheCgroupMemoryLimitOfV1AndV2) {
  namespace fs = std::filesystem;
  esg::testing::TempDir dir;
  const std::string root = dir.File("cgroup");
  // v2, limited in the process's own cgroup.
  fs::create_directories(root + "/system.slice/esgd.service");
  esg::testing::WriteFile(root + "/system.slice/esgd.service/memory.max", "2147483648\n");
  EXPECT_EQ(CgroupMemoryLimit("0::/system.slice/esgd.service\n", root), 2147483648.0);
  // v2 "max": no limit.
  esg::testing::WriteFile(root + "/system.slice/esgd.service/memory.max", "max\n");
  EXPECT_TRUE(std::isinf(CgroupMemoryLimit("0::/system.slice/esgd.service\n", root)));
  // v1 in a container (its cgroup is the namespace's root): the path is not under the mount.
  fs::create_directories(root + "/memory");
  esg::testing::WriteFile(root + "/memory/memory.limit_in_bytes", "536870912\n");
  EXPECT_EQ(CgroupMemoryLimit("5:cpu,cpuacct:/\n4:memory:/docker/abc\n", root), 536870912.0);
  // v1 unlimited, and nothing readable.
  esg::testing::WriteFile(root + "/memory/memory.limit_in_bytes", "9223372036854771712\n");
  EXPECT_TRUE(std::isinf(CgroupMemoryLimit("4:memory:/\n", root)));
  EXPECT_TRUE(std::isinf(CgroupMemoryLimit("", root)));
}

TEST(ProcessMetrics, ThisProcessHasMemoryCpuFilesAndAStartTime) {
  // /proc counts CPU time in clock ticks (10 ms): a test binary run alone had used less than one
  // when it got here, and read 0. Spend 50 ms of CPU first, by the process's own clock.
  const auto process_cpu_seconds = [] {
    timespec t{};
    clock_gettime(CLOCK_PROCESS_CPUTIME_ID, &t);
    return static_cast<double>(t.tv_sec) + 1e-9 * static_cast<double>(t.tv_nsec);
  };
  volatile double sink = 0.0;
  while (process_cpu_seconds() < 0.05) {
    for (int i = 0; i < 100000; ++i) sink = sink + 1e-9 * i;
  }
  absl::StatusOr<ProcessStats> s = ReadProcessStats();
  ASSERT_TRUE(s.ok()) << s.status();
  EXPECT_GT(s->resident_memory_bytes, 1 << 20);
  EXPECT_GE(s->virtual_memory_bytes, s->resident_memory_bytes);
  // At least the 50 ms less two ticks, at most what the process's clock says now plus two.
  EXPECT_GE(s->cpu_seconds, 0.03);
  EXPECT_LE(s->cpu_seconds, process_cpu_seconds() + 0.02);
  EXPECT_GE(s->open_fds, 3);  // stdin, stdout, stderr
  EXPECT_GE(s->max_fds, s->open_fds);
  EXPECT_GE(s->threads, 1);
  const double now = absl::ToDoubleSeconds(absl::Now() - absl::UnixEpoch());
  EXPECT_LE(s->start_time_seconds, now);
  EXPECT_GT(s->start_time_seconds, now - 3600);  // a test binary started within the hour
  // One more open file is counted.
  const double before = s->open_fds;
  const int fd = dup(2);
  ASSERT_GE(fd, 0);
  EXPECT_EQ(ReadProcessStats()->open_fds, before + 1);
  close(fd);
}

TEST(ProcessMetrics, RegistryExposesTheProcessFamiliesAndTheBuild) {
  MetricsRegistry registry;
  AddProcessMetrics(registry);
  AddBuildInfo(registry);
  absl::StatusOr<esg::testing::Exposition> e = esg::testing::ParseExposition(registry.Render());
  ASSERT_TRUE(e.ok()) << e.status();
  EXPECT_EQ(e->type.at("process_cpu_seconds_total"), "counter");
  for (const char* gauge : {"process_resident_memory_bytes", "process_virtual_memory_bytes",
                            "process_open_fds", "process_max_fds", "process_start_time_seconds",
                            "process_threads", "esgd_memory_limit_bytes", "esgd_build_info"}) {
    EXPECT_EQ(e->type.at(gauge), "gauge") << gauge;
  }
  EXPECT_GT(e->Value("process_resident_memory_bytes"), 0);
  EXPECT_EQ(e->Value("esgd_build_info", {{"version", BuildVersion()}, {"commit", BuildCommit()}}),
            1);
  EXPECT_THAT(BuildVersion(), ::testing::MatchesRegex("[0-9]+\\.[0-9]+\\.[0-9]+"));
}

}  // namespace
}  // namespace esg::server
