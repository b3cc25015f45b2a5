// client/diagnosis_plots.h on reports built by hand: every plot is drawn even when a series is
// empty (gnuplot stops a script at a plot without data), legends name only what is drawn, the
// time axis is hours from the start with the UTC start in the title, and onset.png / trend.png
// appear only for a finding that has them.
#include "client/diagnosis_plots.h"

#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "absl/time/time.h"
#include "client/diagnosis_markdown.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

namespace disc = estimator::discovery;
using ::esg::testing::ReadFile;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;
using ::testing::Not;

bool GnuplotInstalled() { return std::system("gnuplot --version > /dev/null 2>&1") == 0; }

std::vector<std::string> Pngs(const std::vector<DiagnosisPlot>& plots) {
  std::vector<std::string> out;
  for (const DiagnosisPlot& p : plots) out.push_back(p.png);
  return out;
}

disc::DiagnosisReport EmptyReport() {
  disc::DiagnosisReport r;
  r.verdict = disc::kVerdictNone;
  r.first_frame_time = absl::FromUnixSeconds(1551398400);  // 2019-03-01T00:00:00Z
  r.gyros = {1, 2};
  r.before.model = "configured model 1";
  r.after.model = "configured model 1";
  return r;
}

TEST(DiagnosisPlots, AReportWithoutSeriesStillDrawsEveryPlotWithoutLegendEntries) {
  TempDir dir;
  const disc::DiagnosisReport r = EmptyReport();
  auto plots = WriteDiagnosisPlots(r, dir.path());
  ASSERT_TRUE(plots.ok()) << plots.status();
  EXPECT_THAT(Pngs(*plots), ::testing::ElementsAre("residuals.png", "held_out.png", "regimes.png"));
  const std::string gp = ReadFile(dir.File("plots.gp"));
  EXPECT_THAT(gp, HasSubstr("(start 2019-03-01T00:00:00.000Z)"));
  EXPECT_THAT(gp, HasSubstr("set xlabel 'hours from the start'"));
  EXPECT_THAT(gp, Not(HasSubstr("keyentry")));  // no regime, span or mismatch to name
  EXPECT_THAT(gp, Not(HasSubstr("title 'before")));
  if (!GnuplotInstalled()) GTEST_SKIP() << "gnuplot not installed";
  ASSERT_TRUE(RunGnuplot(dir.path())) << ReadFile(dir.File("gnuplot.log"));
  for (const std::string& png : Pngs(*plots)) {
    EXPECT_GT(std::filesystem::file_size(dir.File(png)), 1000u) << png;
  }
}

TEST(DiagnosisPlots, ADriftStepAndADisplacementTrendGetTheirPlots) {
  TempDir dir;
  disc::DiagnosisReport r = EmptyReport();
  r.verdict = "drift_step";
  for (int k = 0; k < 200; ++k) {
    const double h = 0.03 * k;
    for (int id : r.gyros) {
      r.residuals_before.push_back({h, id, id == 2 && h > 3 ? 100.0 * (h - 3) + 5 : 5.0, 4.0});
      r.residuals_after.push_back({h, id, 5.0, 4.0});
    }
  }
  disc::Finding step;
  step.effect = "drift_step";
  step.gyro = 2;
  step.time.kind = "step";
  step.time.onset_hours = 3.0;
  step.time.onset_lower_hours = 2.95;
  step.time.onset_upper_hours = 3.05;
  step.time.onset_profile = {{1.0, 300.0}, {2.0, 100.0}, {2.9, 8.0},
                             {3.0, 0.0},   {3.1, 9.0},   {4.0, 200.0}};
  r.findings.push_back(step);
  disc::Finding rotor;
  rotor.effect = "rotor_displacement";
  rotor.gyro = 1;
  for (int k = 0; k < 50; ++k) {
    rotor.displacement_trend.samples.push_back({0.12 * k, {0.8 + 0.001 * k, -1.0, 0.6}});
  }
  rotor.displacement_trend.intercept_um = {0.8, -1.0, 0.6};
  rotor.displacement_trend.rate_um_h = {0.0083, 0.0, 0.0};
  r.findings.push_back(rotor);
  auto plots = WriteDiagnosisPlots(r, dir.path());
  ASSERT_TRUE(plots.ok()) << plots.status();
  EXPECT_THAT(Pngs(*plots), ::testing::ElementsAre("residuals.png", "held_out.png", "regimes.png",
                                                   "onset.png", "trend.png"));
  const std::string md = DiagnosisMarkdown(r, *plots, true);
  for (const DiagnosisPlot& p : *plots) {
    EXPECT_THAT(md, HasSubstr("](" + p.png + ")\n\n" + p.caption)) << p.png;
  }
  const std::string gp = ReadFile(dir.File("plots.gp"));
  EXPECT_THAT(gp, HasSubstr("onset 3.000 h (95%: 2.950-3.050 h)"));
  EXPECT_THAT(gp, HasSubstr("robust line: +0.0083 µm/h"));
  if (!GnuplotInstalled()) GTEST_SKIP() << "gnuplot not installed";
  ASSERT_TRUE(RunGnuplot(dir.path())) << ReadFile(dir.File("gnuplot.log"));
  for (const std::string& png : Pngs(*plots)) {
    EXPECT_GT(std::filesystem::file_size(dir.File(png)), 1000u) << png;
  }
}

}  // namespace
}  // namespace esg::client
