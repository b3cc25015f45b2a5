// The plots of `esg diagnose --out DIR` (docs/discovery.md, "The report"): gnuplot data files and
// one script, plots.gp, that draws pngcairo PNGs into DIR. Every time axis is hours from the
// recording's first frame, whose UTC time each title gives; legends name only what is drawn.
//   residuals.png  each gyro's star-tracker residual before and after, with the band the filter
//                  predicts for it
//   held_out.png   attitude error where the star tracker was withheld, before and after
//   regimes.png    the attitude regimes, the held-out spans and the mismatch
//   onset.png      for a drift step: the likelihood over its onset and the gyro's residual at it
//   trend.png      for a rotor displacement with suspension voltages: the voltage-implied
//                  displacement over time and its fitted line
#ifndef ESG_CLIENT_DIAGNOSIS_PLOTS_H_
#define ESG_CLIENT_DIAGNOSIS_PLOTS_H_

#include <filesystem>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "estimator/discovery/report.h"

namespace esg::client {

struct DiagnosisPlot {
  std::string png;      // file name in the directory, e.g. "residuals.png"
  std::string alt;      // a few words (the Markdown image's alt text)
  std::string caption;  // one sentence: what to look at
};

// Writes the data files and plots.gp into `dir` (an existing directory) and returns the plots
// the script draws, in the order above (onset.png and trend.png only when there is a finding to
// show). Errors: Unknown, naming the file, when a file cannot be written.
absl::StatusOr<std::vector<DiagnosisPlot>> WriteDiagnosisPlots(
    const estimator::discovery::DiagnosisReport& report, const std::filesystem::path& dir);

// Runs gnuplot on plots.gp in `dir`, its messages in dir/gnuplot.log; false when gnuplot is
// missing or failed.
bool RunGnuplot(const std::filesystem::path& dir);

}  // namespace esg::client

#endif  // ESG_CLIENT_DIAGNOSIS_PLOTS_H_
