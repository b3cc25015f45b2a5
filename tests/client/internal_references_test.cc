// User-facing text cites only what a user has: the --help of `esg`, of every verb and sub-verb
// (found by walking the "Subcommands:" lists) and of `esgd`, the docs (docs/*.md, README.md), the
// shipped protos and example files, and what `esg calibrate --json` and `esg diagnose --out`
// write, never an internal document (a design note or style guide by name or by "§" section).
#include <filesystem>
#include <set>
#include <string>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using ::esg::testing::ReadFile;
using ::esg::testing::RunBinary;
using ::esg::testing::RunResult;
using ::esg::testing::TempDir;

// What marks a reference to a document the user does not have.
const std::vector<std::string>& InternalMarkers() {
  static const auto* markers =
      new std::vector<std::string>{"DESIGN",       "\xC2\xA7" /* the section sign */,
                                   "STYLE.md",     "STYLE ",
                                   "/work/shared", "/work/notes",
                                   "briefs/"};
  return *markers;
}

// "<what>:<line>: <text>" for every line of `text` with a marker.
std::vector<std::string> InternalReferences(const std::string& what, const std::string& text) {
  std::vector<std::string> found;
  int line_no = 0;
  for (absl::string_view line : absl::StrSplit(text, '\n')) {
    ++line_no;
    for (const std::string& marker : InternalMarkers()) {
      if (absl::StrContains(line, marker)) {
        found.push_back(absl::StrCat(what, ":", line_no, ": ", line));
        break;
      }
    }
  }
  return found;
}

// The names listed under "Subcommands:" in a CLI11 help text.
std::vector<std::string> Subcommands(const std::string& help) {
  std::vector<std::string> names;
  bool in_list = false;
  for (absl::string_view line : absl::StrSplit(help, '\n')) {
    if (absl::StartsWith(line, "Subcommands:") || absl::StartsWith(line, "SUBCOMMANDS:")) {
      in_list = true;
      continue;
    }
    if (!in_list) continue;
    if (line.empty() || !absl::StartsWith(line, "  ")) {
      if (!names.empty()) break;
      continue;
    }
    const absl::string_view rest = absl::StripLeadingAsciiWhitespace(line);
    if (line.size() - rest.size() != 2) continue;  // a wrapped description line
    names.emplace_back(rest.substr(0, rest.find(' ')));
  }
  return names;
}

TEST(InternalReferences, HelpOfEveryVerbAndOfEsgdCitesNone) {
  TempDir dir;
  std::vector<std::string> found;
  int helps = 0;
  // Breadth-first over "esg", "esg VERB", "esg VERB SUBVERB".
  std::vector<std::string> queue = {""};
  std::set<std::string> seen;
  while (!queue.empty()) {
    const std::string prefix = queue.back();
    queue.pop_back();
    if (!seen.insert(prefix).second) continue;
    const RunResult r = RunBinary(dir, ESG_BINARY, prefix + " --help");
    ASSERT_EQ(r.exit_code, 0) << "esg" << prefix << " --help: " << r.err;
    ++helps;
    for (const std::string& f : InternalReferences("esg" + prefix + " --help", r.out + r.err)) {
      found.push_back(f);
    }
    for (const std::string& sub : Subcommands(r.out)) queue.push_back(prefix + " " + sub);
  }
  EXPECT_GE(helps, 12) << "esg, its verbs and sub-verbs";
  EXPECT_TRUE(seen.count(" calibrate") && seen.count(" replay") && seen.count(" diagnose"));
  EXPECT_TRUE(seen.count(" export") && seen.count(" export history") &&
              seen.count(" export telemetry"));
  const RunResult esgd = RunBinary(dir, ESGD_BINARY, "--help");
  ASSERT_EQ(esgd.exit_code, 0) << esgd.err;
  for (const std::string& f : InternalReferences("esgd --help", esgd.out + esgd.err)) {
    found.push_back(f);
  }
  EXPECT_THAT(found, ::testing::IsEmpty());
}

TEST(InternalReferences, DocsProtosAndExamplesCiteNone) {
  namespace fs = std::filesystem;
  const fs::path root(ESG_SOURCE_DIR);
  std::vector<fs::path> files = {root / "README.md"};
  for (const char* dir : {"docs", "proto/esg/v1", "deploy"}) {
    for (const fs::directory_entry& e : fs::recursive_directory_iterator(root / dir)) {
      const std::string ext = e.path().extension().string();
      if (e.is_regular_file() && (ext == ".md" || ext == ".proto" || ext == ".json" ||
                                  ext == ".service" || ext == ".sh" || ext == ".bash")) {
        files.push_back(e.path());
      }
    }
  }
  std::vector<std::string> found;
  int docs = 0;
  for (const fs::path& path : files) {
    docs += path.extension() == ".md";
    const std::string name = fs::relative(path, root).string();
    for (const std::string& f : InternalReferences(name, ReadFile(path.string()))) {
      found.push_back(f);
    }
  }
  EXPECT_GE(docs, 8) << "docs/*.md and README.md";
  EXPECT_THAT(found, ::testing::IsEmpty());
}

TEST(InternalReferences, ReportsAndJsonOfTheOfflineVerbsCiteNone) {
  TempDir dir;
  const std::string config = std::string(ESG_SOURCE_DIR) + "/deploy/examples/rdk1.json";
  RunResult r = RunBinary(
      dir, ESG_BINARY,
      "simulate --config '" + config + "' --hours 3 --seed 5 --out '" + dir.File("rec.csv") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  std::vector<std::string> found;
  for (const std::string& f : InternalReferences("rec.csv", ReadFile(dir.File("rec.csv")))) {
    found.push_back(f);
  }
  r = RunBinary(dir, ESG_BINARY,
                "calibrate --config '" + config + "' --recording '" + dir.File("rec.csv") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const std::string& f : InternalReferences("calibrate", r.out + r.err)) found.push_back(f);
  r = RunBinary(
      dir, ESG_BINARY,
      "calibrate --config '" + config + "' --recording '" + dir.File("rec.csv") + "' --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  for (const std::string& f : InternalReferences("calibrate --json", r.out)) found.push_back(f);
  r = RunBinary(dir, ESG_BINARY,
                "diagnose --config '" + config + "' --recording '" + dir.File("rec.csv") +
                    "' --max-effects 1 --out '" + dir.File("report") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  int outputs = 0;
  for (const auto& e : std::filesystem::directory_iterator(dir.File("report"))) {
    if (e.path().extension() == ".png") continue;  // images: no text
    ++outputs;
    for (const std::string& f :
         InternalReferences(e.path().filename().string(), ReadFile(e.path().string()))) {
      found.push_back(f);
    }
  }
  EXPECT_GE(outputs, 2) << "report.md, diagnosis.json, plot scripts";
  EXPECT_THAT(found, ::testing::IsEmpty());
}

}  // namespace
}  // namespace esg::client
