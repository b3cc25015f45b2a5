// The CLI habits of kubectl and gh (docs/cli.md "Verbs"), with `esg` run as a real process: a
// mistyped verb gets a did-you-mean and exit 2, `esg help VERB` is `esg VERB --help`, `esg
// version` is `esg --version`, `esg completion bash` prints the installed completion script, which
// bash accepts and which completes verbs and a verb's options, and `-o` is `--format`.
#include <string>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/client/cli_test_support.h"
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

}  // namespace
}  // namespace esg::client
