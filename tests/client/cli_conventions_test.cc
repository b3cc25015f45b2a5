// The CLI's conventions (docs/cli.md), with `esg` run as a real process (ESG_BINARY) and, where a
// verb talks to the server, a real esgd on 127.0.0.1 over a database in a temporary directory:
// --version prints the project version; $ESG_SERVER is the address when --server is absent and
// the flag wins over it; every verb's --help lists the global options; every verb that prints
// data gives JSON that parses (the proto field names, lowerCamelCase, for proto messages) and a
// CSV with a header and rows of the header's width; every time printed, in every format, is RFC
// 3339 UTC with Z and milliseconds; `esg diagnoses list|show` find what `esg diagnose
// --spacecraft` stored. Also the output helpers themselves (client/output_format.h).
#include <signal.h>
#include <unistd.h>

#include <cstdlib>
#include <fstream>
#include <regex>
#include <set>
#include <string>
#include <vector>

#include "absl/cleanup/cleanup.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/time/time.h"
#include "client/output_format.h"
#include "esg/v1/attitude.pb.h"
#include "esg/v1/estimation_service.pb.h"
#include "gmock/gmock.h"
#include "google/protobuf/util/json_util.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/client/cli_test_support.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using ::esg::testing::RunResult;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;
using ::testing::MatchesRegex;

const std::regex& TimeFormat() {
  static const std::regex re(R"(^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$)");
  return re;
}
// Anything that starts like a date-time: the candidates for TimeFormat.
const std::regex& TimeLike() {
  static const std::regex re(
      R"(\d{4}-\d\d-\d\d[Tt ]\d\d:\d\d(:\d\d)?(\.\d+)?([Zz]|[+-]\d\d:?\d\d)?)");
  return re;
}

RunResult RunEsg(const TempDir& dir, const std::string& args, const std::string& env = "") {
  return ::esg::testing::RunBinary(dir, ESG_BINARY, args, env);
}

// Every date-time in `text` is in the CLI's one format; returns how many there are.
int ExpectTimesInFormat(const std::string& text, const std::string& what) {
  int n = 0;
  for (auto it = std::sregex_iterator(text.begin(), text.end(), TimeLike());
       it != std::sregex_iterator(); ++it) {
    ++n;
    EXPECT_TRUE(std::regex_match(it->str(), TimeFormat())) << what << ": " << it->str();
  }
  return n;
}

// The keys of every object in `doc`, recursively.
void CollectKeys(const nlohmann::json& doc, std::set<std::string>& keys) {
  if (doc.is_object()) {
    for (const auto& [key, value] : doc.items()) {
      keys.insert(key);
      CollectKeys(value, keys);
    }
  } else if (doc.is_array()) {
    for (const auto& value : doc) CollectKeys(value, keys);
  }
}

// The json_name of every field of `descriptor` and of the messages it holds, recursively.
void CollectJsonNames(const google::protobuf::Descriptor* descriptor, std::set<std::string>& names,
                      std::set<const google::protobuf::Descriptor*>& seen) {
  if (!seen.insert(descriptor).second) return;
  for (int i = 0; i < descriptor->field_count(); ++i) {
    const google::protobuf::FieldDescriptor* field = descriptor->field(i);
    names.insert(field->json_name());
    if (field->message_type() != nullptr) CollectJsonNames(field->message_type(), names, seen);
  }
}

// `--format json` of a verb: parses, and for a proto message every key is a field's JSON name
// (lowerCamelCase) of `descriptor` (nullptr: not a proto message; keys lowerCamelCase).
nlohmann::json ExpectJson(const RunResult& r, const std::string& what,
                          const google::protobuf::Descriptor* descriptor,
                          const std::set<std::string>& wrapper_keys = {}) {
  EXPECT_EQ(r.exit_code, 0) << what << ": " << r.err;
  const nlohmann::json doc = nlohmann::json::parse(r.out, nullptr, /*allow_exceptions=*/false);
  EXPECT_FALSE(doc.is_discarded()) << what << ": not JSON: " << r.out;
  std::set<std::string> keys;
  CollectKeys(doc, keys);
  EXPECT_FALSE(keys.empty()) << what;
  std::set<std::string> names = wrapper_keys;
  if (descriptor != nullptr) {
    std::set<const google::protobuf::Descriptor*> seen;
    CollectJsonNames(descriptor, names, seen);
  }
  // Keys of documents that are not proto messages include data (e.g. event kinds), not checked.
  for (const std::string& key : keys) {
    if (descriptor == nullptr) break;
    static const std::regex camel("[a-z][A-Za-z0-9]*");
    EXPECT_TRUE(std::regex_match(key, camel)) << what << ": '" << key << "' not lowerCamelCase";
    EXPECT_TRUE(names.count(key)) << what << ": '" << key << "' is no field of "
                                  << descriptor->full_name();
  }
  ExpectTimesInFormat(r.out, what + " (json)");
  return doc;
}

// `--format csv` of a verb: a header naming `first_column` and at least `min_rows` rows, each as
// wide as the header; times in the CLI's format. Returns the header.
std::vector<std::string> ExpectCsv(const RunResult& r, const std::string& what,
                                   const std::string& first_column, size_t min_rows) {
  EXPECT_EQ(r.exit_code, 0) << what << ": " << r.err;
  const std::vector<std::string> lines = absl::StrSplit(r.out, '\n', absl::SkipEmpty());
  EXPECT_GE(lines.size(), 1 + min_rows) << what << ": " << r.out;
  if (lines.empty()) return {};
  const std::vector<std::string> header = CsvCells(lines[0]);
  EXPECT_EQ(header[0], first_column) << what << ": " << lines[0];
  static const std::regex column(R"([a-z][A-Za-z0-9._\[\]]*)");
  for (const std::string& h : header) {
    EXPECT_TRUE(std::regex_match(h, column)) << what << ": column '" << h << "' of " << lines[0];
  }
  for (size_t i = 1; i < lines.size(); ++i) {
    EXPECT_EQ(CsvCells(lines[i]).size(), header.size()) << what << ": row " << lines[i];
  }
  ExpectTimesInFormat(r.out, what + " (csv)");
  return header;
}

// ---- the helpers ------------------------------------------------------------------------------

TEST(OutputFormat, TimesAreRfc3339UtcWithMilliseconds) {
  const absl::Time t = absl::FromUnixSeconds(1551398400) + absl::Nanoseconds(123456789);
  EXPECT_EQ(FormatUtc(t), "2019-03-01T00:00:00.123Z");  // truncated, not rounded
  EXPECT_EQ(FormatUtc(absl::FromUnixSeconds(1551398400)), "2019-03-01T00:00:00.000Z");
  google::protobuf::Timestamp absent;
  EXPECT_EQ(FormatUtc(absent, /*present=*/false), "-");
}

TEST(OutputFormat, ProtoJsonIsTheCanonicalMappingWithMillisecondTimes) {
  esg::v1::Alert alert;
  alert.set_spacecraft_id("RDK-1");
  alert.set_sequence(7);
  alert.set_severity(esg::v1::ALERT_SEVERITY_WARNING);
  alert.mutable_first_time()->set_seconds(1551398400);  // whole second: proto prints no digits
  alert.mutable_measurement_time()->set_seconds(1551398400);
  alert.mutable_measurement_time()->set_nanos(5000000);
  const Json doc = ProtoToJson(alert);
  EXPECT_EQ(doc["spacecraftId"], "RDK-1");
  EXPECT_EQ(doc["sequence"], "7");  // int64 as a string, as the mapping says
  EXPECT_EQ(doc["severity"], "ALERT_SEVERITY_WARNING");
  EXPECT_EQ(doc["acknowledged"], false);  // defaults printed
  EXPECT_EQ(doc["firstTime"], "2019-03-01T00:00:00.000Z");
  EXPECT_EQ(doc["measurementTime"], "2019-03-01T00:00:00.005Z");
  EXPECT_FALSE(doc.contains("acknowledgedTime"));  // absent message: left out
  // Nested and repeated messages too.
  esg::v1::ListSessionsResponse list;
  list.add_sessions()->mutable_last_frame_time()->set_seconds(1551398401);
  EXPECT_EQ(ProtoToJson(list)["sessions"][0]["lastFrameTime"], "2019-03-01T00:00:01.000Z");
}

// A drift model's deprecated fields (the release before's form, docs/formats.md) are left out of
// esg's JSON when they hold nothing, so a keyed model (what esgd writes) prints its keyed
// coefficients only; a model of the release before prints the fields it holds.
TEST(OutputFormat, ADriftModelsEmptyDeprecatedFieldsAreLeftOut) {
  esg::v1::CoefficientSnapshot snapshot;
  esg::v1::DriftCoefficient* keyed = snapshot.mutable_sigma()->add_coefficients();
  keyed->set_term("c1y");
  keyed->set_value_deg_h(0.5);
  ASSERT_TRUE(google::protobuf::util::JsonStringToMessage(R"({"k0DegH": 0.25, "c1DegH": [0, 1, 0]})",
                                                          snapshot.mutable_model())
                  .ok());
  const Json doc = ProtoToJson(snapshot);
  EXPECT_EQ(doc["sigma"], Json::parse(R"({"coefficients": [{"term": "c1y", "valueDegH": 0.5}]})"));
  EXPECT_EQ(doc["model"],
            Json::parse(R"({"k0DegH": 0.25, "c1DegH": [0, 1, 0], "coefficients": []})"));
  // A field that is not deprecated is printed at its default.
  EXPECT_EQ(doc["gyroId"], 0);
}

TEST(OutputFormat, CsvHasAHeaderFlattensAndQuotes) {
  const std::vector<Json> records = {
      Json{{"id", 1}, {"q", Json::array({0.5, 1})}, {"note", "a, \"b\""}},
      Json{{"id", 2}, {"extra", Json{{"x", true}}}, {"note", nullptr}}};
  EXPECT_EQ(CsvTable(records, {"id"}),
            "id,q[0],q[1],note,extra.x\n"
            "1,0.5,1,\"a, \"\"b\"\"\",\n"
            "2,,,,true\n");
  EXPECT_EQ(CsvTable({}, {"id", "verdict"}), "id,verdict\n");  // a header without records
}

// ---- the binary -------------------------------------------------------------------------------

TEST(CliConventions, VersionPrintsTheProjectVersion) {
  TempDir dir;
  const RunResult r = RunEsg(dir, "--version");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, MatchesRegex("esg [0-9]+\\.[0-9]+\\.[0-9]+( \\(commit [0-9a-f]+\\))?\n"));
  EXPECT_THAT(r.out, HasSubstr(absl::StrCat("esg ", ESG_PROJECT_VERSION)));
}

TEST(CliConventions, EveryVerbsHelpListsTheGlobalOptions) {
  TempDir dir;
  for (const char* verb :
       {"simulate", "calibrate", "gap", "diagnose", "diagnoses", "diagnoses list", "diagnoses show",
        "configure", "replay", "status", "predict", "alerts", "history", "estimates", "export",
        "export history", "export telemetry", "model", "model apply", "gyro", "gyro readmit"}) {
    const RunResult r = RunEsg(dir, std::string(verb) + " --help");
    EXPECT_EQ(r.exit_code, 0) << verb << ": " << r.err;
    for (const char* option : {"--server ADDR", "--token TOKEN", "--tls-ca FILE", "--tls-cert FILE",
                               "--tls-key FILE", "$ESG_SERVER", "$ESG_TOKEN", "the flag wins"}) {
      EXPECT_THAT(r.out, HasSubstr(option)) << verb;
    }
  }
}

// The completion script offers every option that the verb's --help lists (global ones too).
TEST(CliConventions, BashCompletionOffersEveryOptionOfEveryVerb) {
  TempDir dir;
  const std::string script = std::string(ESG_SOURCE_DIR) + "/deploy/completion/esg.bash";
  const std::regex option_line(R"(^  (--[a-z][a-z-]*))");
  for (const std::string verb :
       {"simulate", "calibrate", "gap", "diagnose", "diagnoses list", "diagnoses show", "configure",
        "replay", "status", "predict", "alerts", "history", "estimates", "export history",
        "export telemetry", "model apply", "gyro readmit"}) {
    const RunResult help = RunEsg(dir, verb + " --help");
    ASSERT_EQ(help.exit_code, 0) << verb;
    std::set<std::string> options;
    for (const std::string& line : std::vector<std::string>(absl::StrSplit(help.out, '\n'))) {
      std::smatch m;
      if (std::regex_search(line, m, option_line) && m[1] != "--help") options.insert(m[1]);
    }
    ASSERT_GT(options.size(), 5u) << verb << ": " << help.out;
    const std::vector<std::string> words = absl::StrSplit(verb, ' ');
    const std::string bash = absl::StrCat("source '", script, "'; COMP_WORDS=(esg ", verb,
                                          " --); COMP_CWORD=", words.size() + 1,
                                          "; _esg; printf '%s\\n' \"${COMPREPLY[@]}\"");
    testing::WriteFile(dir.File("complete.sh"), bash);
    const RunResult completed =
        ::esg::testing::RunBinary(dir, "/bin/bash", dir.File("complete.sh"));
    ASSERT_EQ(completed.exit_code, 0) << completed.err;
    const std::vector<std::string> offered = absl::StrSplit(completed.out, '\n', absl::SkipEmpty());
    for (const std::string& option : options) {
      EXPECT_THAT(offered, ::testing::Contains(option)) << "esg " << verb;
    }
  }
  // The verbs themselves, the sub-verbs of export, and the values of --format (csv and json
  // only for an export).
  testing::WriteFile(dir.File("verbs.sh"),
                     "source '" + script +
                         "'; COMP_WORDS=(esg d); COMP_CWORD=1; _esg; echo ${COMPREPLY[@]}; "
                         "COMP_WORDS=(esg status --format ''); COMP_CWORD=3; _esg; "
                         "echo ${COMPREPLY[@]}; "
                         "COMP_WORDS=(esg e); COMP_CWORD=1; _esg; echo ${COMPREPLY[@]}; "
                         "COMP_WORDS=(esg export ''); COMP_CWORD=2; _esg; echo ${COMPREPLY[@]}; "
                         "COMP_WORDS=(esg export history --format ''); COMP_CWORD=4; _esg; "
                         "echo ${COMPREPLY[@]}");
  const RunResult r = ::esg::testing::RunBinary(dir, "/bin/bash", dir.File("verbs.sh"));
  EXPECT_EQ(r.out,
            "diagnose diagnoses\ntable json csv\nestimates export\nhistory telemetry\ncsv json\n");
}

TEST(CliConventions, FormatIsValidatedAndJsonIsItsShortForm) {
  TempDir dir;
  RunResult r = RunEsg(dir, "status --format xml");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("--format"));
  r = RunEsg(dir, "status --format json --json");
  EXPECT_EQ(r.exit_code, 2) << "--json and --format exclude each other";
}

// Every verb that takes a time reads it with the one parser (estimator::ParseUtc) and refuses a
// bad one in its wording, naming the option, with exit 2 before anything else is done: the server
// verbs are pointed at an address where nothing listens, so a time checked after connecting
// would exit 1 (UNAVAILABLE) instead.
TEST(CliConventions, EveryTimeOptionRefusesABadTimeNamingTheOption) {
  TempDir dir;
  const std::string rec = Quote(dir.File("rec.csv"));
  RunResult r =
      RunEsg(dir, "simulate --config " + Quote(Rdk1()) + " --hours 1 --seed 3 --out " + rec);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string bad = "2019-03-01T25:00:00Z";
  const std::string refusal =
      ": '" + bad + "' is not an RFC 3339 time such as 2019-03-01T00:00:00Z";
  const std::string offline =
      " --config " + Quote(Rdk1()) + " --hours 1 --seed 3 --out " + Quote(dir.File("x.csv"));
  struct Case {
    std::string verb, args, option;
  };
  const std::vector<Case> cases = {
      {"simulate", offline + " --start ", "--start"},
      {"gap", " --config " + Quote(Rdk1()) + " --recording " + rec + " --gap-start ",
       "--gap-start"},
      {"predict", " --spacecraft RDK-1 --from ", "--from"},
      {"predict", " --spacecraft RDK-1 --from 2019-03-01T00:00:00Z --to ", "--to"},
      {"alerts", " --spacecraft RDK-1 --since ", "--since"},
      {"history", " --spacecraft RDK-1 --from ", "--from"},
      {"history", " --spacecraft RDK-1 --to ", "--to"},
      {"estimates", " --spacecraft RDK-1 --from ", "--from"},
      {"estimates", " --spacecraft RDK-1 --to ", "--to"},
      {"export history", " --spacecraft RDK-1 --from ", "--from"},
      {"export history", " --spacecraft RDK-1 --to ", "--to"},
      {"export telemetry", " --spacecraft RDK-1 --out x.csv --from ", "--from"},
      {"export telemetry", " --spacecraft RDK-1 --out x.csv --to ", "--to"},
      {"diagnose", " --spacecraft RDK-1 --from ", "--from"},
      {"diagnose", " --spacecraft RDK-1 --to ", "--to"},
  };
  for (const Case& c : cases) {
    r = RunEsg(dir, "--server 127.0.0.1:1 " + c.verb + c.args + bad);
    EXPECT_EQ(r.exit_code, 2) << c.verb << " " << c.option << ": " << r.err;
    EXPECT_THAT(r.err, HasSubstr("esg " + c.verb + ": " + c.option + refusal)) << c.option;
  }
  // --gap-start also takes hours, and says so.
  r = RunEsg(dir, "gap --config " + Quote(Rdk1()) + " --recording " + rec + " --gap-start soon");
  EXPECT_THAT(r.err, HasSubstr("esg gap: --gap-start: 'soon' is not an RFC 3339 time such as "
                               "2019-03-01T00:00:00Z, nor a number of hours from the first frame"));
  // A time inside a file is read by the same parser and named by its place; the planned CSV's
  // lines by the recording CSVs' line reader (a byte order mark dropped, blank lines counted).
  const std::string planned = dir.File("plan.csv");
  {
    std::ofstream out(planned);
    out << "\xEF\xBB\xBFtime,q0,q1,q2,q3\n2019-03-01T00:00:00Z,1,0,0,0\n\nnoon,1,0,0,0\n";
  }
  r = RunEsg(dir,
             "--server 127.0.0.1:1 predict --spacecraft RDK-1 --from 2019-03-01T00:00:00Z "
             "--planned " +
                 Quote(planned));
  EXPECT_EQ(r.exit_code, 2) << r.err;
  EXPECT_THAT(r.err, HasSubstr("line 4: time: 'noon' is not an RFC 3339 time such as "
                               "2019-03-01T00:00:00Z"));
  // A good time in another offset is the same instant: the simulated recording starts there.
  r = RunEsg(dir, "simulate --config " + Quote(Rdk1()) +
                      " --hours 1 --seed 3 --start "
                      "2019-03-01T03:00:00+03:00 --out " +
                      Quote(dir.File("same.csv")));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(esg::testing::ReadFile(dir.File("same.csv")),
            esg::testing::ReadFile(dir.File("rec.csv")));
}

// One esgd with RDK-1 configured and a 6 h recording replayed, shared by the server tests.
class CliAgainstServer : public ReplayedRdk1Suite<CliAgainstServer> {
 protected:
  // The server address through the environment only.
  static std::string Env() { return "ESG_SERVER=" + daemon_->address(); }
};

TEST_F(CliAgainstServer, EsgServerIsTheAddressWithoutServerAndTheFlagWins) {
  TempDir dir;
  RunResult r = RunEsg(dir, "status --format json", Env());
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("\"spacecraftId\": \"RDK-1\""));
  // Nothing listens on port 1: the flag is used over the variable, and the other way round.
  r = RunEsg(dir, "status --server 127.0.0.1:1", Env());
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("UNAVAILABLE: server not reachable at 127.0.0.1:1"));
  r = RunEsg(dir, "--server " + daemon_->address() + " status", "ESG_SERVER=127.0.0.1:1");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("RDK-1"));
}

TEST_F(CliAgainstServer, EveryServerVerbPrintsJsonAndCsvWithMillisecondTimes) {
  TempDir dir;
  const std::string env = Env();
  const std::string rdk = " --spacecraft RDK-1";
  // configure
  nlohmann::json doc =
      ExpectJson(RunEsg(dir, "configure --format json --config " + Quote(Rdk1()), env), "configure",
                 esg::v1::ConfigureResponse::descriptor());
  EXPECT_EQ(doc["session"]["spacecraftId"], "RDK-1");
  ExpectCsv(RunEsg(dir, "configure --format csv --config " + Quote(Rdk1()), env), "configure",
            "created", 1);
  // status, one and all
  doc = ExpectJson(RunEsg(dir, "status --json" + rdk, env), "status",
                   esg::v1::SessionInfo::descriptor());
  EXPECT_EQ(doc["state"].get<std::string>().rfind("SESSION_STATE_", 0), 0u) << doc["state"];
  EXPECT_EQ(doc["framesAccepted"], "361");  // int64 as a string (proto JSON mapping)
  EXPECT_GT(ExpectTimesInFormat(doc.dump(), "status"), 0);
  ExpectJson(RunEsg(dir, "status --format json", env), "status (all)",
             esg::v1::ListSessionsResponse::descriptor());
  ExpectCsv(RunEsg(dir, "status --format csv" + rdk, env), "status", "spacecraftId", 1);
  const RunResult table = RunEsg(dir, "status" + rdk, env);
  EXPECT_GT(ExpectTimesInFormat(table.out, "status (table)"), 0) << table.out;
  // alerts
  doc = ExpectJson(RunEsg(dir, "alerts --format json" + rdk, env), "alerts",
                   esg::v1::Alert::descriptor(), {"alerts"});
  const std::vector<std::string> header = ExpectCsv(RunEsg(dir, "alerts --format csv" + rdk, env),
                                                    "alerts", "spacecraftId", doc["alerts"].size());
  EXPECT_THAT(header, ::testing::Contains("measurementTime"));
  // replay (not a proto message): the tally; again, every frame a duplicate
  doc = ExpectJson(RunEsg(dir, "replay --format json --recording " + Quote(recording_), env),
                   "replay", nullptr);
  EXPECT_EQ(doc["duplicates"], 361);
  ExpectCsv(RunEsg(dir, "replay --format csv --recording " + Quote(recording_), env), "replay",
            "spacecraftId", 1);
  // history and predict keep --json (their --format is their own)
  ExpectJson(RunEsg(dir, "history --json" + rdk, env), "history", nullptr);
  const RunResult history = RunEsg(dir, "history" + rdk, env);
  EXPECT_GT(ExpectTimesInFormat(history.out, "history (table)"), 0);
  // estimates: the per-step estimates of the replayed 6 h (a step a minute)
  doc = ExpectJson(RunEsg(dir, "estimates --json" + rdk, env), "estimates",
                   esg::v1::EstimateHistoryResponse::descriptor());
  EXPECT_GE(doc["estimates"].size(), 350u);
  ExpectCsv(RunEsg(dir, "estimates --format csv" + rdk, env), "estimates", "time_utc",
            doc["estimates"].size());
  const RunResult estimates = RunEsg(dir, "estimates" + rdk, env);
  EXPECT_GT(ExpectTimesInFormat(estimates.out, "estimates (table)"), 350);
}

TEST_F(CliAgainstServer, DiagnoseOnTheServerThenDiagnosesListAndShow) {
  TempDir dir;
  const std::string env = Env();
  // The Diagnose RPC over the archive, its progress on stderr, the stored result on stdout.
  RunResult r = RunEsg(dir, "diagnose --spacecraft RDK-1 --format json", env);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr("diagnose: 100% "));
  nlohmann::json result = nlohmann::json::parse(r.out, nullptr, false);
  ASSERT_TRUE(result.is_object()) << r.out;
  const std::string id = result["id"].get<std::string>();
  EXPECT_EQ(result["spacecraftId"], "RDK-1");
  ASSERT_TRUE(result["report"].is_object()) << "the report is parsed, not a string";
  EXPECT_EQ(result["report"]["verdict"], result["verdict"]);
  EXPECT_TRUE(std::regex_match(result["computeTime"].get<std::string>(), TimeFormat()));
  r = RunEsg(dir, "diagnose --spacecraft RDK-1", env);  // a second one, as a table
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("verdict: "));
  EXPECT_GT(ExpectTimesInFormat(r.out, "diagnose (table)"), 0);

  // list: both, oldest first, over pages of one.
  nlohmann::json list =
      ExpectJson(RunEsg(dir, "diagnoses list --spacecraft RDK-1 --page-size 1 --format json", env),
                 "diagnoses list", esg::v1::ListDiagnosesResponse::descriptor());
  ASSERT_EQ(list["diagnoses"].size(), 2u) << list.dump();
  EXPECT_EQ(list["diagnoses"][0]["id"], id);
  EXPECT_EQ(list["diagnoses"][0]["verdict"], result["verdict"]);
  EXPECT_FALSE(list.contains("nextPageToken"));
  ExpectCsv(RunEsg(dir, "diagnoses list --spacecraft RDK-1 --format csv", env), "diagnoses list",
            "id", 2);
  r = RunEsg(dir, "diagnoses list --spacecraft RDK-1", env);
  EXPECT_THAT(r.out, HasSubstr("#" + id + " RDK-1 "));
  EXPECT_THAT(r.out, HasSubstr("2 diagnoses of RDK-1"));

  // show: the full report of the first.
  r = RunEsg(dir, "diagnoses show --spacecraft RDK-1 --json --id " + id, env);
  nlohmann::json shown = ExpectJson(r, "diagnoses show", nullptr);
  EXPECT_EQ(shown["id"], id);
  EXPECT_EQ(shown["report"], result["report"]);
  ExpectCsv(RunEsg(dir, "diagnoses show --spacecraft RDK-1 --format csv --id " + id, env),
            "diagnoses show", "id", 1);
  r = RunEsg(dir, "diagnoses show --spacecraft RDK-1 --id 999", env);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("esg diagnoses show: NOT_FOUND: "));
  r = RunEsg(dir, "diagnose --spacecraft RDK-1 --recording x.csv", env);
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("--spacecraft: "));
}

// $ESG_TOKEN is the token without --token, the flag wins over it, on every verb: the streaming
// and listing ones (diagnose, diagnoses, export) go through the same client (EsgClient) as the
// others. esgd with a token file, started through the shell.
TEST(CliConventions, TokenFlagWinsOverEsgTokenOnEveryVerb) {
  TempDir dir;
  testing::WriteFile(dir.File("tokens"),
                     "w-token-0123456789 read,write\nr-token-0123456789 read\n");
  ASSERT_EQ(std::system(("chmod 600 " + Quote(dir.File("tokens"))).c_str()), 0);
  const std::string start = absl::StrCat(
      Quote(ESGD_BINARY), " --listen 127.0.0.1:0 --workers 2 --db ", Quote(dir.File("esg.db")),
      " --tokens ", Quote(dir.File("tokens")), " > ", Quote(dir.File("esgd.out")), " 2> ",
      Quote(dir.File("esgd.log")), " & echo $! > ", Quote(dir.File("esgd.pid")));
  ASSERT_EQ(std::system(start.c_str()), 0);
  const pid_t pid = std::stoi(testing::ReadFile(dir.File("esgd.pid")));
  absl::Cleanup stop = [pid] {
    kill(pid, SIGTERM);
    for (int i = 0; i < 250 && kill(pid, 0) == 0; ++i) usleep(20000);
  };
  std::string out;
  for (int i = 0; i < 300 && out.find('\n') == std::string::npos; ++i) {
    usleep(20000);
    out = testing::ReadFile(dir.File("esgd.out"));
  }
  const size_t at = out.find("port ");
  ASSERT_NE(at, std::string::npos) << out << testing::ReadFile(dir.File("esgd.log"));
  const std::string server = "--server 127.0.0.1:" + std::to_string(std::stoi(out.substr(at + 5)));

  RunResult r = RunEsg(dir, server + " status --token nope", "ESG_TOKEN=r-token-0123456789");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("UNAUTHENTICATED")) << "the flag is used, not the variable";
  r = RunEsg(dir, server + " configure --config " + Quote(Rdk1()), "ESG_TOKEN=w-token-0123456789");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  r = RunEsg(dir, server + " diagnoses list --spacecraft RDK-1", "env -u ESG_TOKEN");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("esg diagnoses list: UNAUTHENTICATED"));
  r = RunEsg(dir, server + " diagnoses list --spacecraft RDK-1", "ESG_TOKEN=r-token-0123456789");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("0 diagnoses of RDK-1"));
  r = RunEsg(dir, server + " diagnoses list --spacecraft RDK-1 --token r-token-0123456789", "ESG_TOKEN=nope");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  // The streams: without a token refused, with the variable's token served (no telemetry yet,
  // so the diagnosis is refused by the service itself and the export is empty).
  for (const std::string& verb : std::vector<std::string>{
           "diagnose --spacecraft RDK-1", "export history --spacecraft RDK-1",
           "export telemetry --spacecraft RDK-1 --out " + Quote(dir.File("t.csv"))}) {
    const std::string name = verb.substr(0, verb.find(" --"));
    r = RunEsg(dir, server + " " + verb, "env -u ESG_TOKEN");
    EXPECT_EQ(r.exit_code, 1) << verb;
    EXPECT_THAT(r.err, HasSubstr("esg " + name + ": UNAUTHENTICATED")) << verb;
    r = RunEsg(dir, server + " " + verb, "ESG_TOKEN=r-token-0123456789");
    EXPECT_THAT(r.err, ::testing::Not(HasSubstr("UNAUTHENTICATED"))) << verb;
  }
  r = RunEsg(dir, server + " diagnose --spacecraft RDK-1", "ESG_TOKEN=r-token-0123456789");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err,
              HasSubstr("esg diagnose: FAILED_PRECONDITION: spacecraft_id: no archived telemetry"));
  r = RunEsg(dir, server + " export history --spacecraft RDK-1", "ESG_TOKEN=r-token-0123456789");
  EXPECT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, ::testing::StartsWith("time_utc,gyro,k0_deg_h,"));
}

TEST(CliConventions, OfflineVerbsPrintJsonAndCsvWithMillisecondTimes) {
  TempDir dir;
  const std::string rec = Quote(dir.File("rec.csv"));
  RunResult r = RunEsg(
      dir, "simulate --format json --config " + Quote(Rdk1()) + " --hours 4 --seed 2 --out " + rec);
  nlohmann::json doc = ExpectJson(r, "simulate", nullptr);
  EXPECT_EQ(doc["frames"], 241);
  ExpectCsv(RunEsg(dir, "simulate --format csv --config " + Quote(Rdk1()) +
                            " --hours 4 --seed 2 --out " + rec),
            "simulate", "out", 1);
  const std::string inputs = " --config " + Quote(Rdk1()) + " --recording " + rec;
  doc = ExpectJson(RunEsg(dir, "calibrate --format json" + inputs), "calibrate", nullptr);
  EXPECT_EQ(doc["gyros"].size(), 3u);
  // The calibrated drift model as the configuration writes it: every coefficient keyed
  // (docs/formats.md), k0 first, and no field of the release before.
  for (const char* model : {"model", "modelSigma"}) {
    const nlohmann::json& m = doc["gyros"][0][model];
    ASSERT_EQ(m.size(), 1u) << m.dump();
    ASSERT_EQ(m["coefficients"].size(), 13u) << m.dump();
    EXPECT_EQ(m["coefficients"][0]["term"], "k0");
    EXPECT_TRUE(m["coefficients"][0]["valueDegH"].is_number());
  }
  EXPECT_GT(doc["gyros"][0]["modelSigma"]["coefficients"][0]["valueDegH"].get<double>(), 0.0);
  ExpectCsv(RunEsg(dir, "calibrate --format csv" + inputs), "calibrate", "spacecraftId", 3);
  ExpectJson(RunEsg(dir, "gap --format json --gap-start 3" + inputs), "gap", nullptr);
  EXPECT_GT(ExpectTimesInFormat(RunEsg(dir, "gap --gap-start 3" + inputs).out, "gap (table)"), 0);
  ExpectCsv(RunEsg(dir, "gap --format csv --gap-start 3" + inputs), "gap", "time", 10);
  doc = ExpectJson(RunEsg(dir, "diagnose --json --effects random_walk_drift" + inputs), "diagnose",
                   nullptr);
  ExpectCsv(RunEsg(dir, "diagnose --format csv --effects random_walk_drift" + inputs), "diagnose",
            "verdict", 1);
}

}  // namespace
}  // namespace esg::client
