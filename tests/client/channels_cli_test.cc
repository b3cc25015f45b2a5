// Housekeeping channels through the real `esg` and esgd (docs/formats.md "Channels"): a recording
// with `ch:` columns replayed into esgd (a SQLite file in a temporary directory) and exported by
// `esg export telemetry` is the same recording, channels included, and replaying the export into
// a second esgd and exporting again gives the same file; the offline verbs refuse a recording
// whose channel is out of its declared range or not declared, naming frame and channel (exit 2).
#include <fstream>
#include <sstream>
#include <string>

#include "absl/strings/str_cat.h"
#include "estimator/channels.h"
#include "formats/recording_csv.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "proto/convert.h"
#include "tests/client/cli_test_support.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using ::esg::testing::Daemon;
using ::esg::testing::RunBinary;
using ::esg::testing::RunResult;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;

std::string Slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

// RDK-1 with a temperature every 10 min (held up to 15 min) and a heater state in every frame.
std::string ConfigWithChannels(const TempDir& dir) {
  absl::StatusOr<estimator::SpacecraftConfig> config = proto_convert::ReadConfigFile(Rdk1());
  EXPECT_TRUE(config.ok()) << config.status();
  estimator::ChannelConfig t;
  t.name = "T_gyro2";
  t.unit = "K";
  t.valid_min = 250.0;
  t.valid_max = 350.0;
  t.max_age = absl::Minutes(15);
  estimator::ChannelConfig heater;
  heater.name = "heater_1";
  heater.unit = "1";
  heater.valid_min = 0.0;
  heater.valid_max = 1.0;
  config->channels = {t, heater};
  const std::string path = dir.File("rdk1_channels.json");
  EXPECT_TRUE(proto_convert::WriteConfigFile(path, *config).ok());
  return path;
}

// A 2 h simulated RDK-1 recording with the channels added: T_gyro2 every tenth frame, a heater
// cycling every 7 frames, absent from every fifth frame.
std::string RecordingWithChannels(const TempDir& dir, estimator::Recording* out) {
  const std::string plain = dir.File("plain.csv");
  RunResult r = RunBinary(dir, ESG_BINARY,
                          "simulate --config " + Quote(Rdk1()) + " --hours 2 --seed 38 --out " +
                              Quote(plain));
  EXPECT_EQ(r.exit_code, 0) << r.err;
  absl::StatusOr<estimator::Recording> recording = storage::ReadRecordingCsv(plain);
  EXPECT_TRUE(recording.ok()) << recording.status();
  for (size_t i = 0; i < recording->frames.size(); ++i) {
    estimator::Channels& c = recording->frames[i].channels;
    if (i % 10 == 0) c.Set("T_gyro2", 290.0 + 0.01 * static_cast<double>(i) + 1.0 / 3.0);
    if (i % 5 != 4) c.Set("heater_1", (i / 7) % 2 == 0 ? 1.0 : 0.0);
  }
  const std::string path = dir.File("channels.csv");
  EXPECT_TRUE(storage::WriteRecordingCsv(path, *recording).ok());
  *out = *recording;
  return path;
}

// An export longer than one chunk of the stream (1000 frames) and one batch of the spill file
// (1000): the header names a channel first carried after the first chunk, and one carried only
// in the first, and the file is the recording as the writer writes it whole.
TEST(ChannelsCli, AnExportLongerThanAChunkNamesEveryChannelOfTheSpan) {
  TempDir dir;
  const std::string config = ConfigWithChannels(dir);
  const std::string plain = dir.File("plain.csv");
  RunResult r = RunBinary(dir, ESG_BINARY,
                          "simulate --config " + Quote(Rdk1()) + " --hours 20 --seed 39 --out " +
                              Quote(plain));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  absl::StatusOr<estimator::Recording> recording = storage::ReadRecordingCsv(plain);
  ASSERT_TRUE(recording.ok()) << recording.status();
  ASSERT_EQ(recording->frames.size(), 1201u);
  for (size_t i = 0; i < recording->frames.size(); ++i) {
    if (i < 50) recording->frames[i].channels.Set("T_gyro2", 280.0 + 0.1 * static_cast<double>(i));
    if (i >= 1100) recording->frames[i].channels.Set("heater_1", i % 2 == 0 ? 1.0 : 0.0);
  }
  const std::string path = dir.File("channels.csv");
  ASSERT_TRUE(storage::WriteRecordingCsv(path, *recording).ok());
  Daemon daemon(dir.File("esg.db"), dir.File("esg.log"));
  ASSERT_GT(daemon.port(), 0);
  r = Esg(dir, daemon, "configure --config " + Quote(config));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = Esg(dir, daemon, "replay --recording " + Quote(path) + " --wait");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string exported = dir.File("export.csv");
  r = Esg(dir, daemon, "export telemetry --spacecraft RDK-1 --out " + Quote(exported));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr("RDK-1: 1201 frames"));
  const std::string text = Slurp(exported);
  EXPECT_THAT(text, HasSubstr(",ch:T_gyro2,ch:heater_1\n"));
  absl::StatusOr<estimator::Recording> back = storage::ReadRecordingCsv(exported);
  ASSERT_TRUE(back.ok()) << back.status();
  estimator::Recording expected = *recording;
  expected.metadata = back->metadata;
  EXPECT_EQ(text, storage::FormatRecordingCsv(expected));
}

TEST(ChannelsCli, ExportedRecordingIsTheReplayedOneAndReplaysToTheSameFrames) {
  TempDir dir;
  const std::string config = ConfigWithChannels(dir);
  estimator::Recording original;
  const std::string recording = RecordingWithChannels(dir, &original);
  ASSERT_EQ(original.frames.size(), 121u);
  ASSERT_THAT(Slurp(recording), HasSubstr(",ch:T_gyro2,ch:heater_1\n"));

  std::string first_export;
  {
    Daemon daemon(dir.File("first.db"), dir.File("first.log"));
    ASSERT_GT(daemon.port(), 0);
    RunResult r = Esg(dir, daemon, "configure --config " + Quote(config));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    r = Esg(dir, daemon, "replay --recording " + Quote(recording) + " --wait");
    ASSERT_EQ(r.exit_code, 0) << r.err;
    first_export = dir.File("first_export.csv");
    r = Esg(dir, daemon, "export telemetry --spacecraft RDK-1 --out " + Quote(first_export));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    EXPECT_THAT(r.err, HasSubstr("RDK-1: 121 frames"));
  }
  absl::StatusOr<estimator::Recording> back = storage::ReadRecordingCsv(first_export);
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_EQ(back->frames.size(), original.frames.size());
  int with_temperature = 0;
  for (size_t i = 0; i < back->frames.size(); ++i) {
    SCOPED_TRACE(absl::StrCat("frame ", i));
    EXPECT_EQ(back->frames[i].time, original.frames[i].time);
    EXPECT_EQ(back->frames[i].channels, original.frames[i].channels);  // bit for bit
    ASSERT_EQ(back->frames[i].gyros[1].has_value(), original.frames[i].gyros[1].has_value());
    if (original.frames[i].gyros[1].has_value()) {
      EXPECT_EQ(back->frames[i].gyros[1]->h_k, original.frames[i].gyros[1]->h_k);
    }
    with_temperature += back->frames[i].channels.Find("T_gyro2") != nullptr ? 1 : 0;
  }
  EXPECT_EQ(with_temperature, 13);
  // The exported file is the recording as the writer writes it (with the export's metadata).
  estimator::Recording expected = original;
  expected.metadata = back->metadata;
  EXPECT_EQ(Slurp(first_export), storage::FormatRecordingCsv(expected));

  // Replaying the export into a fresh esgd stores the same frames: its export is the same file.
  Daemon second(dir.File("second.db"), dir.File("second.log"));
  ASSERT_GT(second.port(), 0);
  RunResult r = Esg(dir, second, "configure --config " + Quote(config));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  r = Esg(dir, second, "replay --recording " + Quote(first_export) + " --wait");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string second_export = dir.File("second_export.csv");
  r = Esg(dir, second, "export telemetry --spacecraft RDK-1 --out " + Quote(second_export));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(Slurp(second_export), Slurp(first_export));
}

TEST(ChannelsCli, OfflineVerbsRefuseAChannelOutOfRangeOrUndeclaredNamingFrameAndChannel) {
  TempDir dir;
  const std::string config = ConfigWithChannels(dir);
  estimator::Recording recording;
  RecordingWithChannels(dir, &recording);
  recording.frames[20].channels.Set("T_gyro2", 412.0);
  const std::string hot = dir.File("hot.csv");
  ASSERT_TRUE(storage::WriteRecordingCsv(hot, recording).ok());
  for (const char* verb : {"calibrate", "diagnose"}) {
    SCOPED_TRACE(verb);
    const RunResult r = RunBinary(dir, ESG_BINARY,
                                  absl::StrCat(verb, " --config ", Quote(config),
                                               " --recording ", Quote(hot)));
    EXPECT_EQ(r.exit_code, 2) << r.err;
    EXPECT_THAT(r.err, HasSubstr("frame 21 (2019-03-01T00:20:00.000Z): channels[\"T_gyro2\"]: "
                                 "412 K is outside its valid range [250, 350] K"));
  }
  // The same recording's channels under the configuration without declarations.
  const RunResult r = RunBinary(dir, ESG_BINARY,
                                "calibrate --config " + Quote(Rdk1()) + " --recording " +
                                    Quote(hot));
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_THAT(r.err, HasSubstr("frame 1 (2019-03-01T00:00:00.000Z): channels[\"T_gyro2\"]: not "
                               "declared in the configuration (declared: none)"));
}

}  // namespace
}  // namespace esg::client
