// The operations kit against the real esgd (docs/service.md "Metrics", "Logs" and "Operations
// kit"): a conflicting replay by the real `esg replay` writes a bounded number of frame_conflict
// lines and counts the rest; a client retrying a wrong token likewise; the process and build
// metrics scraped from the running esgd; and every query of deploy/grafana/esgd-dashboard.json
// and every rule of deploy/prometheus/esgd-alerts.yml names a metric that esgd exports (the list
// scraped from it), the rules passing `promtool check rules`.
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <regex>
#include <set>
#include <string>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/strings/strip.h"
#include "absl/time/clock.h"
#include "formats/recording_csv.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/prometheus_text.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

#ifndef ESG_PATH
#error "ESG_PATH must name the esg binary"
#endif

namespace esg::server {
namespace {

using ::esg::testing::Daemon;
using ::esg::testing::Exposition;
using ::esg::testing::RunResult;
using ::esg::testing::TempDir;

// Runs `command` through the shell; its stdout, and its exit code in `*code`.
std::string Shell(const std::string& command, int* code = nullptr) {
  std::string out;
  FILE* pipe = popen(command.c_str(), "r");
  if (pipe == nullptr) return out;
  char buffer[4096];
  size_t n = 0;
  while ((n = fread(buffer, 1, sizeof buffer, pipe)) > 0) out.append(buffer, n);
  const int status = pclose(pipe);
  if (code != nullptr) *code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return out;
}

absl::StatusOr<Exposition> Scrape(int port) {
  return esg::testing::ParseExposition(
      Shell(absl::StrCat("curl -sS --max-time 10 http://127.0.0.1:", port, "/metrics")));
}

std::string Quote(const std::string& s) { return "'" + s + "'"; }

std::string SourcePath(const std::string& relative) {
  return (std::filesystem::path(ESG_SOURCE_DIR) / relative).string();
}

RunResult Esg(const TempDir& dir, const std::string& args) {
  return esg::testing::RunBinary(dir, ESG_PATH, args);
}

// The JSON lines of a log file.
std::vector<nlohmann::json> JsonLines(const std::string& path) {
  std::vector<nlohmann::json> lines;
  const std::string text = esg::testing::ReadFile(path);
  for (absl::string_view line : absl::StrSplit(text, '\n', absl::SkipEmpty())) {
    lines.push_back(nlohmann::json::parse(line, nullptr, /*allow_exceptions=*/false));
    EXPECT_FALSE(lines.back().is_discarded()) << line;
  }
  return lines;
}

// Lines of `event`, and the count of the log_suppressed summaries of it.
struct EventCount {
  int lines = 0;
  int summaries = 0;
  int64_t suppressed = 0;
};
EventCount CountEvent(const std::vector<nlohmann::json>& lines, const std::string& event) {
  EventCount c;
  for (const nlohmann::json& j : lines) {
    if (j.value("event", "") == event) ++c.lines;
    if (j.value("event", "") == "log_suppressed" && j.value("suppressedEvent", "") == event) {
      ++c.summaries;
      c.suppressed += j.value("suppressed", int64_t{0});
    }
  }
  return c;
}

TEST(OperationsKit, ConflictingReplayWritesBoundedFrameConflictLinesAndCountsTheRest) {
  TempDir dir;
  const std::string log = dir.File("esgd.log");
  const std::string rdk1 = SourcePath("deploy/examples/rdk1.json");
  RunResult r = Esg(dir, "simulate --config " + Quote(rdk1) + " --hours 12 --seed 11 --out " +
                             Quote(dir.File("rec.csv")));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  absl::StatusOr<estimator::Recording> recording = storage::ReadRecordingCsv(dir.File("rec.csv"));
  ASSERT_TRUE(recording.ok()) << recording.status();
  const int64_t rows = static_cast<int64_t>(recording->frames.size());
  // The same rows (station, sequence and time) with other readings: every one conflicts.
  for (estimator::TelemetryFrame& f : recording->frames) {
    for (auto& g : f.gyros) {
      if (g.has_value()) g->h_k = (g->h_k + Eigen::Vector3d(1e-4, 0, 0)).normalized();
    }
  }
  ASSERT_TRUE(storage::WriteRecordingCsv(dir.File("conflict.csv"), *recording).ok());

  absl::Duration replay_time;
  {
    Daemon daemon(dir.File("esg.db"), log, {}, {"--log-format", "json"});
    const std::string at = "--server " + daemon.address() + " ";
    r = Esg(dir, at + "configure --config " + Quote(rdk1));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    r = Esg(dir, at + "replay --recording " + Quote(dir.File("rec.csv")));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const absl::Time start = absl::Now();
    r = Esg(dir,
            at + "replay --allow-rejects --json --recording " + Quote(dir.File("conflict.csv")));
    replay_time = absl::Now() - start;
    ASSERT_EQ(r.exit_code, 0) << r.err;
    const nlohmann::json tally = nlohmann::json::parse(r.out);
    ASSERT_EQ(tally["rejected"], rows) << r.out;
    // SIGTERM: the summary of the last interval is written at the stop.
    daemon.Stop(SIGTERM);
  }
  const std::vector<nlohmann::json> lines = JsonLines(log);
  const EventCount conflict = CountEvent(lines, "frame_conflict");
  // Every conflict is either a line or counted in a summary; before the throttle each was a
  // line (docs/service.md "Logs").
  EXPECT_EQ(conflict.lines + conflict.suppressed, rows);
  // At most 10 lines and one summary per 10 s interval of the replay (one key: the station).
  const int intervals = static_cast<int>(std::ceil(absl::ToDoubleSeconds(replay_time) / 10)) + 1;
  EXPECT_GE(conflict.lines, 10);
  EXPECT_LE(conflict.lines, 10 * intervals);
  EXPECT_GE(conflict.summaries, 1);
  EXPECT_LE(conflict.summaries, intervals);
  // The repeats of the INGEST_CONFLICT alert are throttled too; the whole log stays short
  // (start, configuration, two streams, the alert, a few repeats, stop).
  const EventCount repeats = CountEvent(lines, "alert_repeated");
  EXPECT_LE(repeats.lines, 10 * intervals);
  EXPECT_LE(lines.size(), 60u);
  RecordProperty("conflicting_frames", static_cast<int>(rows));
  RecordProperty("frame_conflict_lines", conflict.lines);
  RecordProperty("summary_lines", conflict.summaries);
  RecordProperty("log_lines", static_cast<int>(lines.size()));
  std::printf(
      "conflicting replay: %lld conflicts in %.1f s, %d frame_conflict lines, %d summaries, "
      "%zu log lines in all\n",
      static_cast<long long>(rows), absl::ToDoubleSeconds(replay_time), conflict.lines,
      conflict.summaries, lines.size());
  for (const nlohmann::json& j : lines) {
    if (j.value("event", "") != "log_suppressed") continue;
    EXPECT_THAT(j["message"].get<std::string>(),
                ::testing::MatchesRegex("[0-9]+ more frame_conflict lines for station default of "
                                        "spacecraft RDK-1 in the last [0-9]+ s"));
  }
}

TEST(OperationsKit, RefusedTokensWriteBoundedLinesAndCountTheRest) {
  TempDir dir;
  const std::string log = dir.File("esgd.log");
  esg::testing::WriteTokens(dir.File("tokens"), "ops-5b1e9d7c3a2f48 read,write ops\n");
  constexpr int kCalls = 500;
  {
    Daemon daemon(dir.File("esg.db"), log, {},
                  {"--log-format", "json", "--tokens", dir.File("tokens")});
    auto stub = daemon.Stub();
    for (int i = 0; i < kCalls; ++i) {
      grpc::ClientContext ctx;
      ctx.AddMetadata("authorization", absl::StrCat("Bearer guess-", i, "-0123456789abcdef"));
      esg::v1::ListSessionsResponse response;
      const grpc::Status s = stub->ListSessions(&ctx, esg::v1::ListSessionsRequest(), &response);
      ASSERT_TRUE(s.error_code() == grpc::StatusCode::UNAUTHENTICATED ||
                  s.error_code() == grpc::StatusCode::RESOURCE_EXHAUSTED)
          << s.error_message();
    }
    daemon.Stop(SIGTERM);
  }
  const EventCount refused = CountEvent(JsonLines(log), "authorization_refused");
  EXPECT_EQ(refused.lines + refused.suppressed, kCalls);
  EXPECT_GE(refused.lines, 10);
  EXPECT_LE(refused.lines, 40);  // a few intervals at most: the loop takes seconds
  EXPECT_GE(refused.summaries, 1);
  std::printf("%d refused calls: %d authorization_refused lines, %d summaries\n", kCalls,
              refused.lines, refused.summaries);
}

// One running esgd for the metric checks: the families it exports (TYPE lines), with the
// _bucket, _sum and _count series of its histograms.
class ExportedMetrics : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir;
    daemon_ = new Daemon(dir_->File("esg.db"), dir_->File("esgd.log"), {},
                         {"--metrics-listen", "127.0.0.1:0"});
    absl::StatusOr<Exposition> e = Scrape(daemon_->metrics_port());
    ASSERT_TRUE(e.ok()) << e.status();
    exposition_ = new Exposition(*std::move(e));
    names_ = new std::set<std::string>;
    for (const auto& [name, type] : exposition_->type) {
      names_->insert(name);
      if (type == "histogram") {
        for (const char* suffix : {"_bucket", "_sum", "_count"}) names_->insert(name + suffix);
      }
    }
  }
  static void TearDownTestSuite() {
    delete names_;
    delete exposition_;
    delete daemon_;
    delete dir_;
  }
  static TempDir* dir_;
  static Daemon* daemon_;
  static Exposition* exposition_;
  static std::set<std::string>* names_;
};
TempDir* ExportedMetrics::dir_ = nullptr;
Daemon* ExportedMetrics::daemon_ = nullptr;
Exposition* ExportedMetrics::exposition_ = nullptr;
std::set<std::string>* ExportedMetrics::names_ = nullptr;

TEST_F(ExportedMetrics, ProcessAndBuildMetricsDescribeTheRunningEsgd) {
  const absl::Time before = absl::Now();
  absl::StatusOr<Exposition> e = Scrape(daemon_->metrics_port());
  ASSERT_TRUE(e.ok()) << e.status();
  EXPECT_EQ(e->type.at("process_cpu_seconds_total"), "counter");
  EXPECT_GT(e->Value("process_cpu_seconds_total"), 0);
  // The figures of the child's own /proc entry, read here independently.
  const std::string status =
      esg::testing::ReadFile(absl::StrCat("/proc/", daemon_->pid(), "/status"));
  double rss_kb = 0;
  for (absl::string_view line : absl::StrSplit(status, '\n')) {
    if (absl::ConsumePrefix(&line, "VmRSS:")) {
      ASSERT_TRUE(
          absl::SimpleAtod(absl::StripSuffix(absl::StripAsciiWhitespace(line), " kB"), &rss_kb));
    }
  }
  ASSERT_GT(rss_kb, 0);
  // Within 20 % of VmRSS read a moment later (the heap moves between the two reads).
  EXPECT_NEAR(e->Value("process_resident_memory_bytes"), rss_kb * 1024, rss_kb * 1024 * 0.2);
  const int fds = static_cast<int>(std::distance(
      std::filesystem::directory_iterator(absl::StrCat("/proc/", daemon_->pid(), "/fd")),
      std::filesystem::directory_iterator{}));
  EXPECT_NEAR(e->Value("process_open_fds"), fds, 3);
  EXPECT_GE(e->Value("process_max_fds"), e->Value("process_open_fds"));
  const double start = e->Value("process_start_time_seconds");
  EXPECT_LE(start, absl::ToDoubleSeconds(before - absl::UnixEpoch()) + 1);
  EXPECT_GT(start, absl::ToDoubleSeconds(before - absl::UnixEpoch()) - 300);
  EXPECT_GT(e->Value("process_threads"), 2);
  EXPECT_GT(e->Value("esgd_memory_limit_bytes"), 0);  // +Inf without a limit
  // esgd_build_info: one series, value 1, the project version and a git commit (or none).
  ASSERT_EQ(e->Sum("esgd_build_info"), 1);
  for (const esg::testing::Sample& s : e->samples) {
    if (s.name != "esgd_build_info") continue;
    EXPECT_THAT(s.labels.at("version"), ::testing::MatchesRegex("[0-9]+\\.[0-9]+\\.[0-9]+"));
    EXPECT_THAT(s.labels.at("commit"), ::testing::MatchesRegex("([0-9a-f]{7,40})?"));
  }
}

// The metric names a PromQL expression selects: string literals, label matchers, ranges and the
// label lists of by/without/on/ignoring/group_* removed; then every identifier that is not a
// function (followed by '('), a keyword or a Grafana variable ($name).
std::set<std::string> MetricNamesIn(std::string expr) {
  const std::regex strings(R"re("(\\.|[^"\\])*"|'(\\.|[^'\\])*')re");
  expr = std::regex_replace(expr, strings, "\"\"");
  // label_values(selector, label) (Grafana's variable query): only the selector names a metric.
  expr = std::regex_replace(expr, std::regex(R"(label_values\s*\(([^,()]*),\s*\w+\s*\))"), "($1)");
  expr = std::regex_replace(expr, std::regex(R"(\{[^}]*\})"), " ");
  expr = std::regex_replace(expr, std::regex(R"(\[[^\]]*\])"), " ");
  expr = std::regex_replace(
      expr, std::regex(R"(\b(by|without|on|ignoring|group_left|group_right)\s*\([^)]*\))"), " ");
  static const std::set<std::string> kKeywords = {
      "and",      "or",         "unless",      "bool", "offset", "by",  "without", "on",
      "ignoring", "group_left", "group_right", "inf",  "nan",    "Inf", "NaN"};
  std::set<std::string> names;
  const std::regex identifier(R"([A-Za-z_:][A-Za-z0-9_:]*)");
  for (auto it = std::sregex_iterator(expr.begin(), expr.end(), identifier);
       it != std::sregex_iterator(); ++it) {
    const size_t at = static_cast<size_t>(it->position());
    const std::string word = it->str();
    const char before = at > 0 ? expr[at - 1] : ' ';
    if (before == '$' || std::isdigit(static_cast<unsigned char>(before)) || before == '.')
      continue;
    size_t next = at + word.size();
    while (next < expr.size() && std::isspace(static_cast<unsigned char>(expr[next]))) ++next;
    if (next < expr.size() && expr[next] == '(') continue;  // a function
    if (kKeywords.count(word)) continue;
    names.insert(word);
  }
  return names;
}

TEST(PromQl, MetricNamesAreTheSelectorsOnly) {
  EXPECT_EQ(MetricNamesIn("histogram_quantile(0.99, sum by (le, instance) "
                          "(rate(esg_ack_latency_seconds_bucket{instance=~\"$instance\"}[5m])))"),
            std::set<std::string>{"esg_ack_latency_seconds_bucket"});
  EXPECT_EQ(MetricNamesIn("process_resident_memory_bytes / on (instance) esgd_memory_limit_bytes "
                          "> 0.9 and time() - process_start_time_seconds > 1e3"),
            (std::set<std::string>{"process_resident_memory_bytes", "esgd_memory_limit_bytes",
                                   "process_start_time_seconds"}));
  EXPECT_EQ(MetricNamesIn("label_values(esgd_build_info, instance)"),
            std::set<std::string>{"esgd_build_info"});
  EXPECT_EQ(MetricNamesIn("sum(rate(esg_frames_received_total[$__rate_interval]))"),
            std::set<std::string>{"esg_frames_received_total"});
}

// Every string under a key named `key` in `j`, recursively.
void Collect(const nlohmann::json& j, const std::string& key, std::vector<std::string>* out) {
  if (j.is_object()) {
    for (const auto& [k, v] : j.items()) {
      if (k == key && v.is_string()) out->push_back(v.get<std::string>());
      if (k == key && v.is_object() && v.contains("query") && v["query"].is_string()) {
        out->push_back(v["query"].get<std::string>());
      }
      Collect(v, key, out);
    }
  } else if (j.is_array()) {
    for (const nlohmann::json& v : j) Collect(v, key, out);
  }
}

TEST_F(ExportedMetrics, EveryDashboardQueryNamesMetricsEsgdExports) {
  const nlohmann::json dashboard = nlohmann::json::parse(
      esg::testing::ReadFile(SourcePath("deploy/grafana/esgd-dashboard.json")), nullptr, false);
  ASSERT_FALSE(dashboard.is_discarded()) << "deploy/grafana/esgd-dashboard.json is not JSON";
  std::vector<std::string> queries;
  Collect(dashboard["panels"], "expr", &queries);
  const size_t panel_queries = queries.size();
  // Variables of type query (the datasource variable's "query" is a plugin id).
  for (const nlohmann::json& variable : dashboard["templating"]["list"]) {
    if (variable.value("type", "") == "query") Collect(variable, "query", &queries);
  }
  EXPECT_GT(queries.size(), panel_queries) << "no query variable ($instance)";
  EXPECT_GE(panel_queries, 20u);
  std::set<std::string> used;
  for (const std::string& q : queries) {
    const std::set<std::string> names = MetricNamesIn(q);
    EXPECT_FALSE(names.empty()) << "no metric in the query " << q;
    for (const std::string& name : names) {
      EXPECT_TRUE(names_->count(name)) << name << " (in " << q << ") is not exported by esgd";
      used.insert(name);
    }
  }
  // The operator's questions each have a panel (issue 41's list).
  for (const char* name :
       {"esg_frames_received_total", "esg_ack_latency_seconds_bucket", "esg_storage_healthy",
        "esg_sessions", "esg_sessions_degraded", "esg_alerts_raised_total", "esg_diagnoses_total",
        "process_resident_memory_bytes", "esgd_memory_limit_bytes", "esgd_build_info"}) {
    EXPECT_TRUE(used.count(name)) << "no dashboard panel shows " << name;
  }
}

// The `expr:` and `alert:` values of the rules file (one line each, as the file keeps them).
std::vector<std::string> RuleValues(const std::string& text, const std::string& key) {
  std::vector<std::string> values;
  for (absl::string_view line : absl::StrSplit(text, '\n')) {
    line = absl::StripLeadingAsciiWhitespace(line);
    absl::ConsumePrefix(&line, "- ");
    if (absl::ConsumePrefix(&line, key + ":")) {
      values.emplace_back(absl::StripAsciiWhitespace(line));
    }
  }
  return values;
}

TEST_F(ExportedMetrics, EveryAlertRuleNamesMetricsEsgdExports) {
  const std::string text = esg::testing::ReadFile(SourcePath("deploy/prometheus/esgd-alerts.yml"));
  const std::vector<std::string> alerts = RuleValues(text, "alert");
  const std::vector<std::string> exprs = RuleValues(text, "expr");
  ASSERT_EQ(alerts.size(), exprs.size());
  for (const std::string& expr : exprs) {
    ASSERT_FALSE(expr.empty() || expr[0] == '|' || expr[0] == '>')
        << "each expr is kept on its line (this test reads them line by line)";
    const std::set<std::string> names = MetricNamesIn(expr);
    EXPECT_FALSE(names.empty()) << expr;
    for (const std::string& name : names) {
      EXPECT_TRUE(names_->count(name)) << name << " (in " << expr << ") is not exported by esgd";
    }
  }
  // What an operator must be told (issue 41).
  for (const char* alert :
       {"EsgdDown", "EsgdIngestStalled", "EsgdAckLatencyHigh", "EsgdStorageFailing",
        "EsgdSessionFaulted", "EsgdSessionsDegraded", "EsgdSessionQuarantined",
        "EsgdModelInconsistent", "EsgdDiagnosesFailing", "EsgdMemoryNearLimit"}) {
    EXPECT_THAT(alerts, ::testing::Contains(alert));
  }
}

TEST(OperationsKit, AlertRulesPassPromtool) {
  int code = 0;
  if (Shell("command -v promtool", &code).empty()) {
    GTEST_SKIP() << "promtool not found: install Debian's prometheus package "
                    "(scripts/install-deps.sh does) to check deploy/prometheus/esgd-alerts.yml";
  }
  const std::string out = Shell(
      "promtool check rules " + Quote(SourcePath("deploy/prometheus/esgd-alerts.yml")) + " 2>&1",
      &code);
  EXPECT_EQ(code, 0) << out;
  EXPECT_THAT(out, ::testing::HasSubstr("SUCCESS"));

  // The dashboard's queries parse as PromQL too: promtool checks them as recording rules, with
  // Grafana's variables given values.
  const nlohmann::json dashboard = nlohmann::json::parse(
      esg::testing::ReadFile(SourcePath("deploy/grafana/esgd-dashboard.json")), nullptr, false);
  std::vector<std::string> queries;
  Collect(dashboard["panels"], "expr", &queries);
  ASSERT_FALSE(queries.empty());
  TempDir dir;
  std::string rules = "groups:\n  - name: dashboard\n    rules:\n";
  for (size_t i = 0; i < queries.size(); ++i) {
    std::string q = std::regex_replace(queries[i], std::regex(R"(\$__rate_interval)"), "5m");
    q = std::regex_replace(q, std::regex(R"(\$instance)"), ".*");
    absl::StrAppend(&rules, "      - record: dashboard:query", i,
                    "\n        expr: ", nlohmann::json(q).dump(), "\n");
  }
  esg::testing::WriteFile(dir.File("dashboard-rules.yml"), rules);
  const std::string dash_out =
      Shell("promtool check rules " + Quote(dir.File("dashboard-rules.yml")) + " 2>&1", &code);
  EXPECT_EQ(code, 0) << dash_out << rules;
}

}  // namespace
}  // namespace esg::server
