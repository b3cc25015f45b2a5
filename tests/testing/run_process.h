// Running a real binary of the project from a test: its exit code and what it printed, captured
// in files of a TempDir; and small file helpers.
#ifndef ESG_TESTS_TESTING_RUN_PROCESS_H_
#define ESG_TESTS_TESTING_RUN_PROCESS_H_

#include <sys/wait.h>

#include <cstdlib>
#include <fstream>
#include <sstream>
#include <string>

#include "tests/testing/temp_dir.h"

namespace esg::testing {

struct RunResult {
  int exit_code = -1;
  std::string out;
  std::string err;
};

inline std::string ReadFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream s;
  s << in.rdbuf();
  return s.str();
}

inline void WriteFile(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

// Runs `binary args` through the shell (args are shell words; `env`, if given, is a prefix such
// as "ESG_TOKEN=x"), with stdout and stderr captured in files of dir.
inline RunResult RunBinary(const TempDir& dir, const std::string& binary, const std::string& args,
                           const std::string& env = "") {
  const std::string out = dir.File("stdout.txt"), err = dir.File("stderr.txt");
  const std::string command = (env.empty() ? std::string() : env + " ") + "'" + binary + "' " +
                              args + " > '" + out + "' 2> '" + err + "'";
  const int status = std::system(command.c_str());
  RunResult r;
  r.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = ReadFile(out);
  r.err = ReadFile(err);
  return r;
}

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_RUN_PROCESS_H_
