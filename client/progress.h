// Progress on stderr for long offline runs: a percentage updated in place on a terminal,
// otherwise one line every 10%.
#ifndef ESG_CLIENT_PROGRESS_H_
#define ESG_CLIENT_PROGRESS_H_

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <string>

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

}  // namespace esg::client

#endif  // ESG_CLIENT_PROGRESS_H_
