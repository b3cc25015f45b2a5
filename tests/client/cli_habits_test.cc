// The CLI habits of kubectl and gh (docs/cli.md "Verbs"), with `esg` run as a real process: a
// mistyped verb gets a did-you-mean and exit 2, `esg help VERB` is `esg VERB --help`, `esg
// version` is `esg --version`, `esg completion bash` prints the installed completion script, which
// bash accepts and which completes verbs and a verb's options, and `-o` is `--format`. Against a
// real esgd on loopback: `alerts --active` and `--severity MIN`, `predict` without --from, --to
// and --step (now, 6 h, 60 s), spacecraft ids completed from the server (nothing, within 1 s,
// from a closed port or with a refused token), and tables in users' words, never the proto's
// enum value names (which --format json keeps).
#include <algorithm>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/strings/str_split.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/client/cli_test_support.h"
#include "tests/testing/free_port.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using ::esg::testing::RunBinary;
using ::esg::testing::RunResult;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;

RunResult Esg(const TempDir& dir, const std::string& args) {
  return RunBinary(dir, ESG_BINARY, args);
}

TEST(CliHabits, AMistypedVerbIsAnsweredWithTheNearestOne) {
  TempDir dir;
  RunResult r = Esg(dir, "stauts");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("esg: unknown verb 'stauts'; did you mean 'status'?"));
  r = Esg(dir, "--server 127.0.0.1:1 calibrat --recording x.csv");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("did you mean 'calibrate'?"));
  r = Esg(dir, "frobnicate");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("esg: unknown verb 'frobnicate' (esg help lists the verbs)"));
  EXPECT_THAT(r.err, ::testing::Not(HasSubstr("did you mean")));
}

TEST(CliHabits, HelpVerbAndVersionAreTheFlagsAnswers) {
  TempDir dir;
  const RunResult help = Esg(dir, "help predict");
  const RunResult flag = Esg(dir, "predict --help");
  EXPECT_EQ(help.exit_code, 0);
  // The same text; the usage line names the program as typed (`esg`) rather than argv[0].
  const auto usage = [](std::string text) {
    const size_t at = text.find("Usage: ");
    const size_t end = text.find(" predict", at);
    if (at != std::string::npos && end != std::string::npos) text.erase(at + 7, end - at - 7);
    return text;
  };
  EXPECT_EQ(usage(help.out), usage(flag.out));
  EXPECT_THAT(help.out, HasSubstr("Usage: esg predict [OPTIONS]"));
  EXPECT_THAT(help.out, HasSubstr("--spacecraft"));
  const RunResult all = Esg(dir, "help");
  EXPECT_EQ(all.exit_code, 0);
  EXPECT_THAT(all.out, HasSubstr("calibrate"));
  const RunResult bad = Esg(dir, "help stauts");
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_THAT(bad.err, HasSubstr("help: unknown verb 'stauts'; did you mean 'status'?"));
  const RunResult version = Esg(dir, "version");
  EXPECT_EQ(version.exit_code, 0);
  EXPECT_EQ(version.out, Esg(dir, "--version").out);
  EXPECT_THAT(version.out, ::testing::StartsWith("esg "));
}

// The script is sourced by a real bash, which then completes as a user's shell would.
TEST(CliHabits, CompletionBashCompletesVerbsAndAVerbsOptions) {
  TempDir dir;
  RunResult r = Esg(dir, "completion bash");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  esg::testing::WriteFile(dir.File("esg.bash"), r.out);
  const std::string complete = dir.File("complete.sh");
  esg::testing::WriteFile(
      complete,
      "source '" + dir.File("esg.bash") +
          "'\n"
          "COMP_WORDS=(esg sta); COMP_CWORD=1; _esg; echo \"verbs: ${COMPREPLY[*]}\"\n"
          "COMP_WORDS=(esg alerts --spa); COMP_CWORD=2; _esg; echo \"alerts: ${COMPREPLY[*]}\"\n"
          "COMP_WORDS=(esg status -); COMP_CWORD=2; _esg; echo \"status: ${COMPREPLY[*]}\"\n");
  const RunResult bash = RunBinary(dir, "/bin/bash", "'" + complete + "'");
  ASSERT_EQ(bash.exit_code, 0) << bash.err;
  EXPECT_THAT(bash.out, HasSubstr("verbs: status\n"));
  EXPECT_THAT(bash.out, HasSubstr("alerts: --spacecraft\n"));
  EXPECT_THAT(bash.out, HasSubstr("--format"));
  EXPECT_THAT(bash.out, HasSubstr(" -o"));
  // The script printed is the one installed (deploy/completion/esg.bash), byte for byte.
  EXPECT_EQ(r.out, esg::testing::ReadFile(std::string(ESG_SOURCE_DIR) +
                                          "/deploy/completion/esg.bash"));
  r = Esg(dir, "completion zsh");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("expected `esg completion bash`"));
}

TEST(CliHabits, ShortOIsFormat) {
  TempDir dir;
  const std::string rec = dir.File("rec.csv");
  ASSERT_EQ(Esg(dir, "simulate --config " + Quote(Rdk1()) + " --hours 2 --seed 3 --out " +
                         Quote(rec))
                .exit_code,
            0);
  const RunResult a = Esg(dir, "gap --config " + Quote(Rdk1()) + " --recording " + Quote(rec) +
                                   " --gap-start 1.5 -o json");
  const RunResult b = Esg(dir, "gap --config " + Quote(Rdk1()) + " --recording " + Quote(rec) +
                                   " --gap-start 1.5 --format json");
  ASSERT_EQ(a.exit_code, 0) << a.err;
  EXPECT_EQ(a.out, b.out);
  EXPECT_THAT(a.out, ::testing::StartsWith("{"));
}

// A suite against one esgd with RDK-1 configured and 6 h of deploy/examples/scenarios/
// gyro_faults.json (seed 5) replayed, ending about now (so that "now" is within the prediction
// horizon, 48 h after the last frame): gyro 1's readout jump at 5 h raises a WARNING
// (FAULT_AMBIGUOUS, cleared half an hour later) and a DISTRESS (WORKING_PAIR_FAULT, never
// cleared), so each filter leaves one out.
class CliHabitsAgainstServer : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir;
    const std::string rec = dir_->File("faults.csv");
    start_ = absl::FromUnixSeconds(absl::ToUnixSeconds(absl::Now() - absl::Hours(6)) / 60 * 60);
    RunResult r = RunBinary(*dir_, ESG_BINARY,
                            "simulate --config " + Quote(Rdk1()) + " --scenario " +
                                Quote(std::string(ESG_SOURCE_DIR) +
                                      "/deploy/examples/scenarios/gyro_faults.json") +
                                " --hours 6 --seed 5 --start " + Utc(start_) + " --out " +
                                Quote(rec));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    daemon_ = new esg::testing::Daemon(dir_->File("esg.db"), dir_->File("esgd.log"));
    ASSERT_GT(daemon_->port(), 0);
    r = ::esg::client::Esg(*dir_, *daemon_, "configure --config " + Quote(Rdk1()));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    r = ::esg::client::Esg(*dir_, *daemon_, "replay --recording " + Quote(rec) + " --wait");
    ASSERT_EQ(r.exit_code, 0) << r.err;
  }
  static void TearDownTestSuite() {
    delete daemon_;
    daemon_ = nullptr;
    delete dir_;
    dir_ = nullptr;
  }
  static RunResult EsgAt(const std::string& args) { return ::esg::client::Esg(*dir_, *daemon_, args); }
  // The "alerts" of `esg alerts ... -o json`.
  static nlohmann::json AlertsJson(const std::string& args) {
    const RunResult r = EsgAt("alerts --spacecraft RDK-1 -o json " + args);
    EXPECT_EQ(r.exit_code, 0) << r.err;
    return nlohmann::json::parse(r.out, nullptr, false)["alerts"];
  }

  static std::string Utc(absl::Time t) {
    return absl::FormatTime("%Y-%m-%dT%H:%M:%SZ", t, absl::UTCTimeZone());
  }

  static inline TempDir* dir_ = nullptr;
  static inline esg::testing::Daemon* daemon_ = nullptr;
  static inline absl::Time start_;  // of the recording, a whole minute
};

TEST_F(CliHabitsAgainstServer, AlertsFilterActiveAndMinimumSeverity) {
  const nlohmann::json all = AlertsJson("");
  ASSERT_EQ(all.size(), 2u) << all.dump();
  int cleared = 0, distress = 0;
  for (const nlohmann::json& a : all) {
    cleared += a["cleared"].get<bool>() ? 1 : 0;
    distress += a["severity"] == "ALERT_SEVERITY_DISTRESS" ? 1 : 0;
  }
  ASSERT_EQ(cleared, 1) << all.dump();
  ASSERT_EQ(distress, 1) << all.dump();

  const nlohmann::json active = AlertsJson("--active");
  ASSERT_EQ(active.size(), 1u) << active.dump();
  EXPECT_FALSE(active[0]["cleared"].get<bool>());
  const nlohmann::json severe = AlertsJson("--severity distress");
  ASSERT_EQ(severe.size(), 1u) << severe.dump();
  EXPECT_EQ(severe[0]["severity"], "ALERT_SEVERITY_DISTRESS");
  EXPECT_EQ(AlertsJson("--severity WARNING").size(), 2u) << "WARNING and worse";
  EXPECT_EQ(AlertsJson("--severity CRITICAL").size(), 0u);
  EXPECT_EQ(AlertsJson("--severity ALERT_SEVERITY_INFO").size(), 2u);

  // The table: the count line counts what is shown; each alert a sentence.
  RunResult r = EsgAt("alerts --spacecraft RDK-1 --active --severity warning");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("1 alerts (1 active, 1 unacknowledged)"));
  EXPECT_THAT(r.out, HasSubstr(" DISTRESS working pair fault on gyro_1: "));
  EXPECT_THAT(r.out, ::testing::ContainsRegex(
                         ": [0-9.]+ arcsec, above the threshold [0-9.]+ arcsec, once at 20[0-9][0-9]-"));

  r = EsgAt("alerts --severity severe");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("esg alerts: --severity 'severe': expected INFO, WARNING, "
                               "DISTRESS or CRITICAL"));
}

TEST_F(CliHabitsAgainstServer, PredictDefaultsToSixHoursFromNowEvery60Seconds) {
  const absl::Time before = absl::Now();
  RunResult r = EsgAt("predict --spacecraft RDK-1 -o json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json doc = nlohmann::json::parse(r.out);
  const nlohmann::json& samples = doc["samples"];
  ASSERT_EQ(samples.size(), 361u) << "6 h at 60 s, both ends";
  absl::Time first, last;
  std::string error;
  ASSERT_TRUE(absl::ParseTime(absl::RFC3339_full, samples[0]["time"].get<std::string>(), &first,
                              &error));
  ASSERT_TRUE(absl::ParseTime(absl::RFC3339_full, samples[360]["time"].get<std::string>(), &last,
                              &error));
  EXPECT_GE(first, before - absl::Seconds(1));
  EXPECT_LE(first, absl::Now());
  EXPECT_EQ(last - first, absl::Hours(6));
  // --from alone: 6 h from it.
  r = EsgAt("predict --spacecraft RDK-1 --from " + Utc(start_ + absl::Hours(7)) +
            " --step 3600 -o csv");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("\n" + absl::FormatTime("%Y-%m-%dT%H:%M:%S.000Z",
                                                        start_ + absl::Hours(13),
                                                        absl::UTCTimeZone()) +
                               ","));
  EXPECT_EQ(std::count(r.out.begin(), r.out.end(), '\n'), 1 + 7);
  // The help says so.
  r = EsgAt("help predict");
  EXPECT_THAT(r.out, HasSubstr("(default: now)"));
  EXPECT_THAT(r.out, HasSubstr("(default: 6 h after --from)"));
  EXPECT_THAT(r.out, HasSubstr("(default: 60)"));
}

// Tables speak the users' words: no proto enum value name (SESSION_STATE_..., ALERT_SEVERITY_...,
// ALERT_REASON_..., ATTITUDE_SOURCE_...) in any table; --format json keeps them (docs/cli.md).
TEST_F(CliHabitsAgainstServer, TablesNameEnumsInWordsAndJsonKeepsTheProtoNames) {
  const std::vector<std::string> verbs = {
      "status",
      "status --spacecraft RDK-1",
      "alerts",
      "alerts --spacecraft RDK-1 --include-revised",
      "predict --spacecraft RDK-1 --from " + Utc(start_ + absl::Hours(5)) + " --step 1800",
      "history --spacecraft RDK-1 --gyro 2 --from " + Utc(start_ + absl::Hours(5)),
      "estimates --spacecraft RDK-1 --from " + Utc(start_ + absl::Hours(5)) + " --to " +
          Utc(start_ + absl::Minutes(310)),
      "diagnoses list --spacecraft RDK-1"};
  for (const std::string& verb : verbs) {
    const RunResult r = EsgAt(verb);
    ASSERT_EQ(r.exit_code, 0) << verb << ": " << r.err;
    for (const char* prefix :
         {"SESSION_STATE_", "ALERT_SEVERITY_", "ALERT_REASON_", "ATTITUDE_SOURCE_"}) {
      EXPECT_THAT(r.out, ::testing::Not(HasSubstr(prefix))) << "esg " << verb;
    }
  }
  RunResult r = EsgAt("predict --spacecraft RDK-1 --from " + Utc(start_ + absl::Hours(5)) +
                      " --to " + Utc(start_ + absl::Hours(8)) + " --step 1800");
  EXPECT_THAT(r.out, HasSubstr("  recorded "));
  EXPECT_THAT(r.out, HasSubstr("  inertial hold "));
  r = EsgAt("status --spacecraft RDK-1");
  EXPECT_THAT(r.out, HasSubstr("  gyro 1 excluded (reading jump): "));
  r = EsgAt("status --spacecraft RDK-1 -o json");
  EXPECT_THAT(r.out, ::testing::ContainsRegex("\"state\": \"SESSION_STATE_[A-Z]+\""));
  r = EsgAt("alerts --spacecraft RDK-1 -o json");
  EXPECT_THAT(r.out, HasSubstr("\"reason\": \"ALERT_REASON_WORKING_PAIR_FAULT\""));
}

// Completion of spacecraft ids asks the server; with nothing listening, or the token refused, it
// prints nothing and returns within 1 s (it runs at every Tab).
TEST(CliHabits, SpacecraftIdsAreCompletedFromTheServerOrNothingWithinASecond) {
  TempDir dir;
  // A real closed port: bound by the OS, then released.
  const int closed = esg::testing::FreeLoopbackPort();
  absl::Time start = absl::Now();
  RunResult r = Esg(dir, "--server 127.0.0.1:" + std::to_string(closed) + " __complete spacecraft");
  EXPECT_LT(absl::Now() - start, absl::Seconds(1));
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(r.err, "");

  // A real esgd that knows RDK-1 and wants a token.
  esg::testing::WriteFile(dir.File("tokens"), "r-token-0123456789 read,write ops\n");
  std::filesystem::permissions(
      dir.File("tokens"), std::filesystem::perms::owner_read | std::filesystem::perms::owner_write,
      std::filesystem::perm_options::replace);
  esg::testing::Daemon daemon(dir.File("esg.db"), dir.File("esgd.log"), {},
                              {"--tokens", dir.File("tokens")});
  ASSERT_GT(daemon.port(), 0);
  const std::string at = "--server " + daemon.address() + " ";
  r = Esg(dir, at + "--token r-token-0123456789 configure --config " + Quote(Rdk1()));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  start = absl::Now();
  r = Esg(dir, at + "--token wrong-token-0123456789 __complete spacecraft");
  EXPECT_LT(absl::Now() - start, absl::Seconds(1));
  EXPECT_EQ(r.exit_code, 0);
  EXPECT_EQ(r.out, "");
  EXPECT_EQ(r.err, "");
  r = Esg(dir, at + "--token r-token-0123456789 __complete spacecraft");
  EXPECT_EQ(r.out, "RDK-1\n");

  // Through the completion script, with the --server and --token of the line.
  const std::string script = std::string(ESG_SOURCE_DIR) + "/deploy/completion/esg.bash";
  const auto complete = [&](const std::string& line, int cword) {
    esg::testing::WriteFile(dir.File("complete.sh"),
                            "source '" + script + "'\nCOMP_WORDS=('" + ESG_BINARY + "' " + line +
                                "); COMP_CWORD=" + std::to_string(cword) +
                                "; _esg; echo \"ids: ${COMPREPLY[*]}\"\n");
    return RunBinary(dir, "/bin/bash", "'" + dir.File("complete.sh") + "'");
  };
  r = complete(at + "--token r-token-0123456789 status --spacecraft R", 7);
  EXPECT_EQ(r.out, "ids: RDK-1\n") << r.err;
  // As bash calls it: COMP_WORDS split at the address's ':' (COMP_WORDBREAKS), COMP_LINE whole.
  const std::string line = std::string(ESG_BINARY) + " " + at + "status --spacecraft R";
  esg::testing::WriteFile(
      dir.File("complete.sh"),
      "source '" + script + "'\nCOMP_LINE='" + line + "'; COMP_POINT=${#COMP_LINE}\n" +
          "COMP_WORDS=('" + ESG_BINARY + "' --server 127.0.0.1 : " +
          std::to_string(daemon.port()) + " status --spacecraft R); COMP_CWORD=7\n" +
          "ESG_TOKEN=r-token-0123456789 _esg; echo \"ids: ${COMPREPLY[*]}\"\n");
  r = RunBinary(dir, "/bin/bash", "'" + dir.File("complete.sh") + "'");
  EXPECT_EQ(r.out, "ids: RDK-1\n") << r.err;
  start = absl::Now();
  r = complete(at + "--token nope-0123456789 status --spacecraft ''", 7);
  EXPECT_LT(absl::Now() - start, absl::Seconds(1));
  EXPECT_EQ(r.out, "ids: \n") << r.err;
  // `esg help` does not list the hidden verb.
  EXPECT_THAT(Esg(dir, "help").out, ::testing::Not(HasSubstr("__complete")));
}

}  // namespace
}  // namespace esg::client
