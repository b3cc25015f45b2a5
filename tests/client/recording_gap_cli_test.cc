// The offline verbs (`esg calibrate`, `esg gap`, `esg diagnose`) refuse a recording row more than
// 7 days after the previous one at once, naming the line and both times (docs/formats.md,
// "Validation"; estimator/frame_gap.h), as esgd refuses such a frame at ingest. Before, one wrong
// time tag 5 years ahead kept `esg calibrate` integrating across the gap for minutes.
#include <chrono>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "absl/time/time.h"
#include "estimator/utc_time.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/client/cli_test_support.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using ::esg::testing::ReadFile;
using ::esg::testing::RunBinary;
using ::esg::testing::RunResult;
using ::esg::testing::TempDir;
using ::esg::testing::WriteFile;
using ::testing::HasSubstr;

constexpr char kTimeFormat[] = "%Y-%m-%dT%H:%M:%E*SZ";

struct TimedRun {
  RunResult result;
  double seconds = 0.0;
};

TimedRun RunEsgTimed(const TempDir& dir, const std::string& args) {
  const auto start = std::chrono::steady_clock::now();
  TimedRun run;
  run.result = RunBinary(dir, ESG_BINARY, args);
  run.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  return run;
}

// A 1 h recording of RDK-1 whose last row is moved `jump` after the row before it; returns the
// path, and the 1-based line of the moved row and the two times as the message writes them.
struct JumpedRecording {
  std::string path;
  int line = 0;
  std::string previous_time, moved_time;
};

JumpedRecording WriteJumpedRecording(const TempDir& dir, absl::Duration jump) {
  JumpedRecording out;
  out.path = dir.File("rec.csv");
  RunResult r = RunBinary(dir, ESG_BINARY,
                          "simulate --config " + Quote(Rdk1()) + " --hours 1 --seed 3 --out " +
                              Quote(out.path));
  EXPECT_EQ(r.exit_code, 0) << r.err;
  std::vector<std::string> lines = absl::StrSplit(ReadFile(out.path), '\n');
  while (!lines.empty() && lines.back().empty()) lines.pop_back();
  EXPECT_GT(lines.size(), 10u);
  if (lines.size() < 2) return out;
  std::string& last = lines.back();
  const std::string before = lines[lines.size() - 2].substr(0, lines[lines.size() - 2].find(','));
  absl::Time previous;
  std::string error;
  EXPECT_TRUE(absl::ParseTime(absl::RFC3339_full, before, &previous, &error)) << error;
  const absl::Time moved = previous + jump;
  // The row is written exactly (the recording CSV's form); messages print the one UTC form.
  out.previous_time = estimator::FormatUtc(previous);
  out.moved_time = estimator::FormatUtc(moved);
  last = absl::FormatTime(kTimeFormat, moved, absl::UTCTimeZone()) + last.substr(last.find(','));
  out.line = static_cast<int>(lines.size());
  WriteFile(out.path, absl::StrJoin(lines, "\n") + "\n");
  return out;
}

TEST(RecordingGapCli, RowFiveYearsLaterIsRefusedAtOnceByEveryOfflineVerb) {
  TempDir dir;
  const JumpedRecording rec = WriteJumpedRecording(dir, absl::Hours(24 * 365 * 5));
  ASSERT_GT(rec.line, 0);
  const std::string inputs = "--config " + Quote(Rdk1()) + " --recording " + Quote(rec.path);
  const std::string columns =
      " --columns " + Quote(std::string(ESG_SOURCE_DIR) +
                            "/deploy/examples/columns_esg_recording.json");
  const std::vector<std::string> commands = {
      "calibrate " + inputs,
      "gap " + inputs + " --gap-start 0.5",
      "diagnose " + inputs,
      "calibrate " + inputs + columns,
  };
  for (const std::string& command : commands) {
    const TimedRun run = RunEsgTimed(dir, command);
    EXPECT_EQ(run.result.exit_code, 2) << command << "\n" << run.result.err;
    EXPECT_THAT(run.result.err, HasSubstr("--recording " + rec.path + ": ")) << command;
    EXPECT_THAT(run.result.err,
                HasSubstr(absl::StrCat("line ", rec.line, ", column time_utc")))
        << command << "\n" << run.result.err;
    EXPECT_THAT(run.result.err,
                HasSubstr(rec.moved_time + " is more than 7 days after the previous row (line " +
                          std::to_string(rec.line - 1) + ", " + rec.previous_time + ")"))
        << command << "\n" << run.result.err;
    // At once: reading the file is all it takes (before, minutes of filtering).
    EXPECT_LT(run.seconds, 20.0) << command;
  }
}

}  // namespace
}  // namespace esg::client
