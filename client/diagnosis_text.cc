#include "client/diagnosis_text.h"

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/output_format.h"

namespace esg::client {

namespace disc = estimator::discovery;

std::string DiagnosisText(const disc::DiagnosisReport& r) {
  std::string out = absl::StrCat("verdict: ", r.verdict, "\n");
  if (!r.consistency.summary.empty()) absl::StrAppend(&out, "  ", r.consistency.summary, "\n");
  for (size_t i = 0; i < r.findings.size(); ++i) {
    const disc::Finding& f = r.findings[i];
    absl::StrAppend(&out, i + 1, ". ", f.effect,
                    f.gyro > 0 ? absl::StrCat(" (gyro ", f.gyro, ")") : "", ": ", f.explanation,
                    "\n");
    for (const std::string& n : f.evidence.notes) absl::StrAppend(&out, "     - ", n, "\n");
  }
  const disc::Mismatch& m = r.mismatch;
  if (m.span >= 0) {
    absl::StrAppend(
        &out, absl::StrFormat("mismatch of the configured model: %s, %s - %s (%s), residual RMS "
                              "%.1f arcsec against %.1f expected (p = %.2g, %s)\n",
                              m.gyro > 0 ? absl::StrCat("gyro ", m.gyro) : "all gyros",
                              FormatUtc(m.start), FormatUtc(m.end), m.regime, m.size_arcsec,
                              m.expected_arcsec, m.p_value, m.source));
  }
  absl::StrAppend(
      &out,
      absl::StrFormat("fit before: residual RMS %.2f arcsec, held-out drift rate %.4f deg/h "
                      "(%s)\n",
                      r.before.residual_rms_arcsec, r.before.gap_drift_rate_deg_h, r.before.model));
  absl::StrAppend(
      &out,
      absl::StrFormat("fit after:  residual RMS %.2f arcsec, held-out drift rate %.4f deg/h "
                      "(%s)\n",
                      r.after.residual_rms_arcsec, r.after.gap_drift_rate_deg_h, r.after.model));
  absl::StrAppend(&out, absl::StrFormat("%d frames, %zu regime spans, %d filter runs\n", r.frames,
                                        r.regimes.size(), r.filter_runs));
  return out;
}

}  // namespace esg::client
