// Progress on stderr for long runs (the one printer of every verb): a percentage updated in place
// on a terminal, otherwise one line every 10%; or a line per named stage.
#ifndef ESG_CLIENT_PROGRESS_H_
#define ESG_CLIENT_PROGRESS_H_

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <string>
#include <utility>

namespace esg::client {

class Progress {
 public:
  explicit Progress(std::string label) : label_(std::move(label)), tty_(::isatty(STDERR_FILENO) == 1) {}
  void operator()(double fraction) {
    const int percent = static_cast<int>(std::floor(100.0 * fraction));
    if (tty_) {
      if (percent == last_) return;
      std::fprintf(stderr, "\r%s: %3d%%", label_.c_str(), percent);
      if (percent >= 100) std::fprintf(stderr, "\n");
      last_ = percent;
    } else {
      const int decile = percent / 10 * 10;
      if (decile == last_ || decile == 0) return;
      std::fprintf(stderr, "%s: %d%%\n", label_.c_str(), decile);
      last_ = decile;
    }
    std::fflush(stderr);
  }

 private:
  std::string label_;
  bool tty_;
  int last_ = -1;
};

// Progress by stage on stderr: "diagnose:  42% round 1: rotor_displacement[2] fitted (3/12)", a
// line per stage (in place on a terminal); empty stages and repeats are not printed.
class StageProgress {
 public:
  explicit StageProgress(std::string label)
      : label_(std::move(label)), tty_(::isatty(STDERR_FILENO) == 1) {}
  void operator()(double fraction, const std::string& stage) {
    if (stage.empty() || stage == last_) return;
    last_ = stage;
    if (tty_) {
      std::fprintf(stderr, "\r\033[K%s: %3.0f%% %s", label_.c_str(), 100.0 * fraction,
                   stage.c_str());
      line_open_ = fraction < 1.0;
      if (!line_open_) std::fprintf(stderr, "\n");
    } else {
      std::fprintf(stderr, "%s: %3.0f%% %s\n", label_.c_str(), 100.0 * fraction, stage.c_str());
    }
    std::fflush(stderr);
  }
  // Ends the line a terminal was updating in place (a run that stopped before 100%).
  void End() {
    if (line_open_) std::fprintf(stderr, "\n");
    line_open_ = false;
  }

 private:
  std::string label_;
  bool tty_;
  bool line_open_ = false;
  std::string last_;
};

}  // namespace esg::client

#endif  // ESG_CLIENT_PROGRESS_H_
