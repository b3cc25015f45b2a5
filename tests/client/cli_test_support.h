// What the CLI tests of client_tests share (the binaries are ESG_BINARY and ESGD_BINARY): quoting
// for the shell, the example configuration RDK-1, the cells of a CSV line, `esg` run against a
// running esgd, and a test suite's esgd with RDK-1 configured and a recording replayed.
#ifndef ESG_TESTS_CLIENT_CLI_TEST_SUPPORT_H_
#define ESG_TESTS_CLIENT_CLI_TEST_SUPPORT_H_

#include <cstddef>
#include <string>
#include <vector>

#include "gtest/gtest.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

#ifndef ESGD_PATH
#define ESGD_PATH ESGD_BINARY
#endif
#include "tests/testing/daemon.h"

namespace esg::client {

inline std::string Quote(const std::string& s) { return "'" + s + "'"; }

// deploy/examples/rdk1.json: the configuration of spacecraft RDK-1.
inline std::string Rdk1() { return std::string(ESG_SOURCE_DIR) + "/deploy/examples/rdk1.json"; }

// The cells of one CSV line (RFC 4180: a quoted cell may hold commas and doubled quotes).
inline std::vector<std::string> CsvCells(const std::string& line) {
  std::vector<std::string> cells(1);
  bool quoted = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted) {
      if (c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
        cells.back() += '"';
        ++i;
      } else if (c == '"') {
        quoted = false;
      } else {
        cells.back() += c;
      }
    } else if (c == '"') {
      quoted = true;
    } else if (c == ',') {
      cells.emplace_back();
    } else {
      cells.back() += c;
    }
  }
  return cells;
}

// `esg --server <daemon's address> <args>` run in `dir`.
inline esg::testing::RunResult Esg(const esg::testing::TempDir& dir,
                                   const esg::testing::Daemon& daemon, const std::string& args) {
  return esg::testing::RunBinary(dir, ESG_BINARY, "--server " + daemon.address() + " " + args);
}

// A test suite against one esgd over a database in a temporary directory, with RDK-1 configured
// and a 6 h recording simulated with seed 5 (361 frames, `recording_`) replayed by `esg replay
// --wait`. `Suite` is the fixture that derives from it, so that each suite has its own esgd.
template <typename Suite>
class ReplayedRdk1Suite : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new esg::testing::TempDir;
    recording_ = dir_->File("rec.csv");
    esg::testing::RunResult r = esg::testing::RunBinary(
        *dir_, ESG_BINARY,
        "simulate --config " + Quote(Rdk1()) + " --hours 6 --seed 5 --out " + Quote(recording_));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    daemon_ = new esg::testing::Daemon(dir_->File("esg.db"), dir_->File("esgd.log"));
    ASSERT_GT(daemon_->port(), 0);
    r = Esg(*dir_, *daemon_, "configure --config " + Quote(Rdk1()));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    r = Esg(*dir_, *daemon_, "replay --recording " + Quote(recording_) + " --wait");
    ASSERT_EQ(r.exit_code, 0) << r.err;
  }
  static void TearDownTestSuite() {
    delete daemon_;
    daemon_ = nullptr;
    delete dir_;
    dir_ = nullptr;
  }

  static inline esg::testing::TempDir* dir_ = nullptr;
  static inline std::string recording_;
  static inline esg::testing::Daemon* daemon_ = nullptr;
};

}  // namespace esg::client

#endif  // ESG_TESTS_CLIENT_CLI_TEST_SUPPORT_H_
