#include "client/diagnosis_markdown.h"

#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "client/output_format.h"
#include "estimator/units.h"

namespace esg::client {

namespace {

namespace disc = estimator::discovery;

// The image and its sentence, or nothing when the plot was not drawn.
std::string PlotBlock(const std::vector<DiagnosisPlot>& plots, const std::string& png) {
  for (const DiagnosisPlot& p : plots) {
    if (p.png == png) return absl::StrCat("![", p.alt, "](", p.png, ")\n\n", p.caption, "\n\n");
  }
  return "";
}

}  // namespace

std::string DiagnosisMarkdown(const disc::DiagnosisReport& r,
                              const std::vector<DiagnosisPlot>& plots, bool plotted) {
  std::string md = absl::StrCat("# Diagnosis: ", r.verdict, "\n\n");
  absl::StrAppend(
      &md, absl::StrFormat("Recording: %d frames from %s; running gyros %s; %d filter runs. "
                           "Times in the plots are hours from %s.\n\n",
                           r.frames, FormatUtc(r.first_frame_time), absl::StrJoin(r.gyros, ", "),
                           r.filter_runs, FormatUtc(r.first_frame_time)));
  if (!plotted) {
    absl::StrAppend(&md,
                    "(gnuplot failed or is missing: see gnuplot.log; the data files and plots.gp "
                    "are beside this report.)\n\n");
  }
  if (!r.consistency.summary.empty()) {
    absl::StrAppend(&md, "Partly explained: ", r.consistency.summary, ".\n\n");
  }
  absl::StrAppend(&md, "## Findings\n\n");
  if (r.findings.empty())
    absl::StrAppend(&md, "None: the configured model explains the recording.\n\n");
  for (size_t i = 0; i < r.findings.size(); ++i) {
    const disc::Finding& f = r.findings[i];
    absl::StrAppend(&md, absl::StrFormat("%d. **%s**%s: %s\n", i + 1, f.effect,
                                         f.gyro > 0 ? absl::StrCat(" (gyro ", f.gyro, ")") : "",
                                         f.explanation));
    for (const std::string& n : f.evidence.notes) absl::StrAppend(&md, "   - ", n, "\n");
    if (!f.parameters.empty()) {
      absl::StrAppend(&md, "\n   | parameter | value | 1-sigma | unit |\n   |---|---|---|---|\n");
      for (const auto& p : f.parameters) {
        absl::StrAppend(
            &md, absl::StrFormat("   | %s | %.5g | %s | %s |\n", p.name, p.value,
                                 p.sigma > 0 ? absl::StrFormat("%.2g", p.sigma) : "", p.unit));
      }
    }
    absl::StrAppend(&md, "\n");
  }
  absl::StrAppend(&md, PlotBlock(plots, "onset.png"), PlotBlock(plots, "trend.png"));
  const disc::Mismatch& m = r.mismatch;
  absl::StrAppend(&md, "## Where the configured model and the recording disagree\n\n");
  if (m.span >= 0) {
    absl::StrAppend(
        &md, absl::StrFormat("%s, %s to %s (%s span): star-tracker residual RMS %.1f arcsec "
                             "against %.1f arcsec expected "
                             "(p = %.2g, from %s); lag-1 autocorrelation %.2f.\n\n",
                             m.gyro > 0 ? absl::StrCat("Gyro ", m.gyro) : "All gyros",
                             FormatUtc(m.start), FormatUtc(m.end), m.regime, m.size_arcsec,
                             m.expected_arcsec, m.p_value, m.source, m.lag1_autocorrelation));
  }
  absl::StrAppend(&md, PlotBlock(plots, "regimes.png"), "## Fit before and after\n\n",
                  "| | model | residual RMS, arcsec | held-out drift rate, deg/h | dispersion | "
                  "held-out NEES | held-out -2 log predictive density |\n",
                  "|---|---|---|---|---|---|---|\n");
  for (const auto& [name, f] :
       {std::pair<const char*, const disc::FitSummary*>{"before", &r.before},
        {"after", &r.after}}) {
    absl::StrAppend(&md, absl::StrFormat("| %s | %s | %.2f | %.4f | %.3f | %.1f / %d | %.1f |\n",
                                         name, f->model, f->residual_rms_arcsec,
                                         f->gap_drift_rate_deg_h, f->dispersion, f->held_out_nees,
                                         f->held_out_dof, f->held_out_deviance));
  }
  absl::StrAppend(&md, "\n", PlotBlock(plots, "residuals.png"),
                  "Held-out spans (star tracker withheld, model predicting):\n\n",
                  "| span | hours from the start | regime | drift rate before, deg/h | after, "
                  "deg/h |\n|---|---|---|---|---|\n");
  for (size_t k = 0; k < r.before.gaps.size(); ++k) {
    const auto& b = r.before.gaps[k];
    const double after = k < r.after.gaps.size() ? r.after.gaps[k].drift_rate_deg_h : 0.0;
    absl::StrAppend(
        &md, absl::StrFormat("| %s - %s | %.2f - %.2f | %s | %.4f | %.4f |\n", FormatUtc(b.start),
                             FormatUtc(b.end), disc::HoursSince(b.start, r.first_frame_time),
                             disc::HoursSince(b.end, r.first_frame_time), b.regime,
                             b.drift_rate_deg_h, after));
  }
  absl::StrAppend(&md, "\n", PlotBlock(plots, "held_out.png"), "## Candidates tried\n\n",
                  "| round | effect | gyro | time behaviour | k | delta -2 log L | prior cost | "
                  "evidence 2 ln B "
                  "| 1/B | significant | selected |\n",
                  "|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (const auto& c : r.candidates) {
    const std::string behaviour =
        c.onset_hours >= 0 ? absl::StrFormat("step at %.2f h", c.onset_hours) : c.time_behaviour;
    absl::StrAppend(
        &md, absl::StrFormat("| %d | %s | %s | %s | %d | %.1f | %.1f | %.1f | %.2g | %s | %s |\n",
                             c.round + 1, c.effect, c.gyro > 0 ? absl::StrCat(c.gyro) : "",
                             behaviour, c.parameters, c.delta_deviance, c.penalty, c.score,
                             c.p_value, c.significant ? "yes" : "", c.selected ? "**yes**" : ""));
  }
  bool refused_heading = false;
  for (const auto& c : r.candidates) {
    if (c.not_fitted.empty()) continue;
    if (!refused_heading) absl::StrAppend(&md, "\nNot fitted:\n\n");
    refused_heading = true;
    absl::StrAppend(&md, absl::StrFormat("- round %d, %s%s: %s\n", c.round + 1, c.effect,
                                         c.gyro > 0 ? absl::StrCat(" of gyro ", c.gyro) : "",
                                         c.not_fitted));
  }
  absl::StrAppend(&md,
                  "\n## Regimes\n\n| start | end | hours from the start | regime | rate, "
                  "deg/s |\n|---|---|---|---|---|\n");
  for (const auto& s : r.regimes) {
    absl::StrAppend(&md,
                    absl::StrFormat("| %s | %s | %.2f - %.2f | %s | %.4f |\n", FormatUtc(s.start),
                                    FormatUtc(s.end), disc::HoursSince(s.start, r.first_frame_time),
                                    disc::HoursSince(s.end, r.first_frame_time),
                                    disc::RegimeName(s.regime), estimator::RadToDeg(s.mean_rate)));
  }
  return md;
}

}  // namespace esg::client
