// Tests of server/metrics.h (registry and Prometheus text exposition), server/service_metrics.h
// (label helpers) and server/log.h (text and JSON lines), and that every log event the server
// writes is in docs/service.md's "Logs" table. Pure: no server, no SQLite.
#include "server/metrics.h"

#include <cmath>
#include <filesystem>
#include <limits>
#include <regex>
#include <set>
#include <string>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "server/log.h"
#include "server/service_metrics.h"
#include "tests/testing/prometheus_text.h"
#include "tests/testing/run_process.h"

namespace esg::server {
namespace {

using ::testing::HasSubstr;

TEST(MetricsRegistry, RendersCountersGaugesAndHistogramsInTheTextFormat) {
  MetricsRegistry registry;
  Family<Counter>& frames = registry.AddCounter("test_frames_total", "Frames.", {"station"});
  Gauge& depth = registry.AddGauge("test_depth", "Depth.").Get();
  Histogram& latency =
      registry.AddHistogram("test_latency_seconds", "Latency.", {}, {0.001, 0.01, 0.1}).Get();
  frames.With({"gs-a"}).Increment();
  frames.With({"gs-a"}).Increment(2);
  frames.With({"gs-b"}).Increment();
  depth.Set(7.5);
  for (double v : {0.0005, 0.001, 0.005, 0.05, 0.5}) latency.Observe(v);

  const std::string text = registry.Render();
  EXPECT_THAT(text, HasSubstr("# HELP test_frames_total Frames.\n# TYPE test_frames_total counter\n"
                              "test_frames_total{station=\"gs-a\"} 3\n"
                              "test_frames_total{station=\"gs-b\"} 1\n"));
  EXPECT_THAT(text, HasSubstr("# TYPE test_depth gauge\ntest_depth 7.5\n"));
  // Cumulative buckets, le inclusive (0.001 falls in le="0.001"), +Inf equal to _count.
  EXPECT_THAT(text, HasSubstr("# TYPE test_latency_seconds histogram\n"
                              "test_latency_seconds_bucket{le=\"0.001\"} 2\n"
                              "test_latency_seconds_bucket{le=\"0.01\"} 3\n"
                              "test_latency_seconds_bucket{le=\"0.1\"} 4\n"
                              "test_latency_seconds_bucket{le=\"+Inf\"} 5\n"
                              "test_latency_seconds_sum "));
  EXPECT_THAT(text, HasSubstr("\ntest_latency_seconds_count 5\n"));
  absl::StatusOr<esg::testing::Exposition> parsed = esg::testing::ParseExposition(text);
  ASSERT_TRUE(parsed.ok()) << parsed.status();
  EXPECT_EQ(parsed->Value("test_frames_total", {{"station", "gs-a"}}), 3);
  EXPECT_EQ(parsed->type.at("test_latency_seconds"), "histogram");
  EXPECT_NEAR(parsed->Value("test_latency_seconds_sum"), 0.5565, 1e-12);
}

TEST(MetricsRegistry, EscapesLabelValuesAndHelp) {
  MetricsRegistry registry;
  registry.AddCounter("test_total", "A \\ backslash\nand a newline.", {"id"})
      .With({"a\"b\\c\nd"})
      .Increment();
  const std::string text = registry.Render();
  EXPECT_THAT(text, HasSubstr("# HELP test_total A \\\\ backslash\\nand a newline.\n"));
  EXPECT_THAT(text, HasSubstr("test_total{id=\"a\\\"b\\\\c\\nd\"} 1\n"));
  absl::StatusOr<esg::testing::Exposition> parsed = esg::testing::ParseExposition(text);
  ASSERT_TRUE(parsed.ok()) << parsed.status();
  EXPECT_EQ(parsed->Value("test_total", {{"id", "a\"b\\c\nd"}}), 1);
}

TEST(MetricsRegistry, SampleValuesUseTheShortestExactText) {
  EXPECT_EQ(FormatSampleValue(0.0001), "0.0001");
  EXPECT_EQ(FormatSampleValue(42), "42");
  EXPECT_EQ(FormatSampleValue(2.5), "2.5");
  EXPECT_EQ(FormatSampleValue(1e-12), "1e-12");
  EXPECT_EQ(FormatSampleValue(std::numeric_limits<double>::infinity()), "+Inf");
  EXPECT_EQ(FormatSampleValue(-std::numeric_limits<double>::infinity()), "-Inf");
  EXPECT_EQ(FormatSampleValue(std::nan("")), "NaN");
}

TEST(MetricsRegistry, LabelSetsBeyondTheCapShareOneOverflowSeries) {
  MetricsRegistry registry;
  Family<Counter>& family = registry.AddCounter("test_total", "Capped.", {"station", "reason"});
  for (size_t i = 0; i < kMaxSeries + 10; ++i) {
    family.With({"st-" + std::to_string(i), "X"}).Increment();
  }
  absl::StatusOr<esg::testing::Exposition> parsed =
      esg::testing::ParseExposition(registry.Render());
  ASSERT_TRUE(parsed.ok()) << parsed.status();
  EXPECT_EQ(parsed->samples.size(), kMaxSeries + 1);
  EXPECT_EQ(parsed->Value("test_total", {{"station", kOverflowLabel}, {"reason", kOverflowLabel}}),
            10);
  EXPECT_EQ(parsed->Sum("test_total"), kMaxSeries + 10);
}

TEST(MetricsRegistry, CollectorsRunBeforeEachRendering) {
  MetricsRegistry registry;
  Gauge& g = registry.AddGauge("test_gauge", "Collected.").Get();
  int calls = 0;
  registry.AddCollector([&] { g.Set(++calls); });
  EXPECT_THAT(registry.Render(), HasSubstr("test_gauge 1\n"));
  EXPECT_THAT(registry.Render(), HasSubstr("test_gauge 2\n"));
}

TEST(ServiceMetrics, StationAndFieldLabelsAreBounded) {
  EXPECT_EQ(StationLabel(""), "default");
  EXPECT_EQ(StationLabel("gs-a"), "gs-a");
  EXPECT_EQ(StationLabel("bad station\n"), "");
  EXPECT_EQ(FieldLabel("gyros[12].gyro_id"), "gyros[].gyro_id");
  EXPECT_EQ(FieldLabel("sequence"), "sequence");
  EXPECT_EQ(FieldLabel("a\"b{c}"), "abc");
  EXPECT_EQ(FieldLabel(std::string(200, 'x')).size(), 64u);
}

TEST(ServiceMetrics, EveryDocumentedFamilyIsExposedWithHelpAndType) {
  ServiceMetrics metrics;
  absl::StatusOr<esg::testing::Exposition> parsed =
      esg::testing::ParseExposition(metrics.registry.Render());
  ASSERT_TRUE(parsed.ok()) << parsed.status();
  for (const char* name :
       {"esg_frames_received_total", "esg_frames_acknowledged_total", "esg_frames_refused_total",
        "esg_frames_unacknowledged_total", "esg_ack_latency_seconds", "esg_storage_commit_seconds",
        "esg_commit_batch_frames", "esg_storage_healthy", "esg_commit_backlog_bytes",
        "esg_sessions", "esg_filter_step_seconds", "esg_alerts_raised_total",
        "esg_alerts_cleared_total", "esg_revisions_total", "esg_diagnoses_total",
        "esg_diagnosis_duration_seconds"}) {
    EXPECT_TRUE(parsed->type.count(name)) << name;
    EXPECT_TRUE(parsed->help.count(name)) << name;
  }
  EXPECT_EQ(parsed->Value("esg_revisions_total"), 0);
  EXPECT_EQ(parsed->Value("esg_diagnoses_total", {{"result", "ok"}}), 0);
}

TEST(Log, TextLinesEscapeControlCharacters) {
  const std::string line = FormatLogLine(LogFormat::kText, "WARN", "frame_conflict",
                                         "id X\n2019-01-01 INFO esgd: forged\x1b[2J", {});
  EXPECT_THAT(line, HasSubstr(" WARN esgd: id X\\x0a2019-01-01 INFO esgd: forged\\x1b[2J\n"));
  EXPECT_EQ(line.find('\n'), line.size() - 1);
}

TEST(Log, JsonLinesAreOneObjectWithEscapedIds) {
  const std::string id = "RDK\"1\n{\"level\":\"ERROR\"}\x01\xff";
  const std::string line =
      FormatLogLine(LogFormat::kJson, "ERROR", "alert_raised", "alert " + id,
                    {{"spacecraftId", id}, {"alertSequence", int64_t{7}}, {"created", true},
                     {"durationSeconds", 0.25}});
  ASSERT_EQ(line.find('\n'), line.size() - 1) << line;
  const nlohmann::json j = nlohmann::json::parse(line);
  ASSERT_TRUE(j.is_object());
  EXPECT_EQ(j.at("level"), "ERROR");
  EXPECT_EQ(j.at("event"), "alert_raised");
  EXPECT_EQ(j.at("alertSequence"), 7);
  EXPECT_EQ(j.at("created"), true);
  EXPECT_EQ(j.at("durationSeconds"), 0.25);
  // Invalid UTF-8 is replaced (U+FFFD); everything else round-trips.
  EXPECT_EQ(j.at("spacecraftId"), "RDK\"1\n{\"level\":\"ERROR\"}\x01\xef\xbf\xbd");
  const std::string ts = j.at("ts");
  EXPECT_EQ(ts.size(), 24u) << ts;  // 2019-03-01T00:00:00.000Z
  EXPECT_EQ(ts.back(), 'Z');
}

// Every LogEvent("LEVEL", "event", ...) with literal arguments in server/*.cc: the level is one
// docs/service.md names (INFO, WARN, ERROR) and the event has a row in its "Logs" table.
TEST(Log, EveryEventTheServerWritesIsDocumentedWithADocumentedLevel) {
  namespace fs = std::filesystem;
  const fs::path root(ESG_SOURCE_DIR);
  const std::string doc = esg::testing::ReadFile((root / "docs/service.md").string());
  const size_t logs = doc.find("### Logs");
  ASSERT_NE(logs, std::string::npos);
  const std::string table = doc.substr(logs, doc.find("\n## ", logs) - logs);
  const std::regex call(R"re(LogEvent\(\s*"([A-Z]+)",\s*"([a-z_]+)")re");
  std::set<std::string> events;
  for (const fs::directory_entry& e : fs::directory_iterator(root / "server")) {
    if (e.path().extension() != ".cc") continue;
    const std::string source = esg::testing::ReadFile(e.path().string());
    for (auto it = std::sregex_iterator(source.begin(), source.end(), call);
         it != std::sregex_iterator(); ++it) {
      const std::string level = (*it)[1], event = (*it)[2];
      EXPECT_TRUE(level == "INFO" || level == "WARN" || level == "ERROR")
          << e.path().filename() << ": " << event << " at level " << level;
      EXPECT_NE(table.find("`" + event + "`"), std::string::npos)
          << e.path().filename() << ": " << event << " is not in docs/service.md's Logs table";
      events.insert(event);
    }
  }
  // The scan sees the calls (a changed call shape would otherwise pass vacuously).
  EXPECT_GE(events.size(), 25u);
  EXPECT_TRUE(events.count("session_taken"));
}

}  // namespace
}  // namespace esg::server
