#include "estimator/discovery/location.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <map>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/statistics.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"

namespace esg::estimator::discovery {

namespace {

// Per (gyro, regime span) residual excess of a run. The unit is one gyro at one step:
// w = min(u1^2, c) + min(u2^2, c), u the star-tracker differences normalised by their filter
// sigma and c = 9 (3 sigma): star-tracker outliers that stay below the step's chi-square cap
// (a 1 arcmin outlier about the 30 arcsec boresight) would otherwise dominate a span. A span is
// compared with the reference model's own mean and variance of w over the whole recording, so
// the test asks "is this span worse than the rest", robust to a common mis-scaling of the
// noise and to the correlation of the two components.
constexpr double kResidualClip = 9.0;

struct Cell {
  int gyro = 0;
  int span = 0;
  double sum_w = 0.0;
  int n = 0;                             // gyro-steps
  double sum_z2 = 0.0;                   // [rad^2]
  double sum_s2 = 0.0;                   // [rad^2]
  std::array<std::vector<double>, 2> u;  // normalised innovations per component, time order
  std::vector<double> hours;
};

struct CellReference {
  double mean = 2.0;
  double variance = 4.0;
};

// Frames whose star-tracker sample is an outlier for the best model found (nis beyond the cap):
// left out of the residual cells of every model.
std::vector<bool> OutlierFrames(const ModelRun& best, int frames) {
  std::vector<bool> out(frames, false);
  for (const StepRecord& r : best.steps) {
    if (r.nis_formed && r.nis >= ChiSquareQuantile(1.0 - kOutlierP, r.m)) out[r.frame] = true;
  }
  return out;
}

std::map<std::pair<int, int>, Cell> Cells(const ModelRun& run, const std::vector<RegimeSpan>& spans,
                                          const std::vector<TelemetryFrame>& frames,
                                          const std::vector<bool>& outlier) {
  std::map<std::pair<int, int>, Cell> cells;
  const absl::Time t0 = frames.front().time;
  for (const StepRecord& r : run.steps) {
    if (!r.nis_formed || r.withheld || outlier[r.frame]) continue;
    const int span = SpanOfFrame(spans, r.frame);
    for (const GyroInnovation& g : r.innovations) {
      if (!(g.sigma(0) > 0) || !(g.sigma(1) > 0)) continue;
      Cell& c = cells[{g.id, span}];
      c.gyro = g.id;
      c.span = span;
      double w = 0.0;
      for (int i = 0; i < 2; ++i) {
        const double u = g.z(i) / g.sigma(i);
        w += std::min(u * u, kResidualClip);
        c.sum_z2 += g.z(i) * g.z(i);
        c.sum_s2 += g.sigma(i) * g.sigma(i);
        c.u[i].push_back(u);
      }
      c.sum_w += w;
      ++c.n;
      c.hours.push_back(HoursSince(frames[r.frame].time, t0));
    }
  }
  return cells;
}

CellReference Reference(const std::map<std::pair<int, int>, Cell>& cells) {
  CellReference ref;
  double s = 0.0, s2 = 0.0;
  int n = 0;
  for (const auto& [key, c] : cells) {
    for (size_t k = 0; k < c.hours.size(); ++k) {
      double w = 0.0;
      for (int i = 0; i < 2; ++i) w += std::min(c.u[i][k] * c.u[i][k], kResidualClip);
      s += w;
      s2 += w * w;
      ++n;
    }
  }
  if (n > 10) {
    ref.mean = s / n;
    ref.variance = std::max(s2 / n - ref.mean * ref.mean, 1e-6);
  }
  return ref;
}

// The (gyro, span) cell whose residuals exceed the reference most; `found` when a cell's excess
// is significant at a Bonferroni level over the cells and material (kMaterialResidualRatio):
// then the most significant such cell.
Mismatch Locate(const ModelRun& run, const std::vector<RegimeSpan>& spans,
                const std::vector<TelemetryFrame>& frames, const std::vector<bool>& outlier,
                const CellReference& ref, double alpha) {
  Mismatch m;
  const auto cells = Cells(run, spans, frames, outlier);
  if (cells.empty()) return m;
  const Cell* worst = nullptr;
  double worst_z = -1e300;
  const Cell* material = nullptr;  // the most significant cell with a material excess
  double material_z = -1e300;
  std::map<int, double> excess_by_gyro;
  double excess_total = 0.0;
  int tested = 0;
  for (const auto& [key, c] : cells) {
    if (c.n < 5) continue;
    ++tested;
    const double excess = c.sum_w - c.n * ref.mean;
    const double z = excess / std::sqrt(c.n * ref.variance);
    excess_by_gyro[c.gyro] += std::max(0.0, excess);
    excess_total += std::max(0.0, excess);
    if (z > worst_z) {
      worst_z = z;
      worst = &c;
    }
    if (z > material_z && c.sum_z2 > kMaterialResidualRatio * kMaterialResidualRatio * c.sum_s2) {
      material_z = z;
      material = &c;
    }
  }
  if (worst == nullptr) return m;
  if (material != nullptr && NormalSurvival(material_z) < alpha / std::max(1, tested)) {
    worst = material;
    worst_z = material_z;
    m.found = true;
  }
  m.p_value = NormalSurvival(worst_z);
  // One gyro when it carries most of the excess; otherwise the mismatch is common.
  m.gyro = (excess_total > 0 && excess_by_gyro[worst->gyro] > 0.5 * excess_total) ? worst->gyro : 0;
  m.span = worst->span;
  if (worst->span >= 0) {
    m.start = spans[worst->span].start;
    m.end = spans[worst->span].end;
    m.regime = RegimeName(spans[worst->span].regime);
  }
  m.size_arcsec = RadToArcsec(std::sqrt(worst->sum_z2 / (2.0 * worst->n)));
  m.expected_arcsec = RadToArcsec(std::sqrt(worst->sum_s2 / (2.0 * worst->n)));
  m.excess_deviance = worst->sum_w - worst->n * ref.mean;
  m.lag1_autocorrelation =
      0.5 * (Lag1Autocorrelation(worst->u[0]) + Lag1Autocorrelation(worst->u[1]));
  // Mean of two lag-1 estimates, each ~ N(0, 1/n) for white residuals.
  m.whiteness_p_value =
      2.0 * NormalSurvival(std::abs(m.lag1_autocorrelation) * std::sqrt(2.0 * worst->n));
  double e0 = 0.0, e1 = 0.0;
  for (int k = 0; k < worst->n; ++k) {
    e0 += worst->u[0][k] * worst->u[0][k];
    e1 += worst->u[1][k] * worst->u[1][k];
  }
  if (m.gyro > 0) m.axis = e0 >= e1 ? 1 : 2;
  std::vector<double> w(worst->n);
  for (int k = 0; k < worst->n; ++k) {
    w[k] = std::min(worst->u[0][k] * worst->u[0][k], kResidualClip) +
           std::min(worst->u[1][k] * worst->u[1][k], kResidualClip);
  }
  m.trend_per_hour = FitRobustLine(worst->hours, w).slope;
  m.source = "in-sample residuals";
  return m;
}

}  // namespace

double ResidualRmsArcsec(const ModelRun& run) {
  double s = 0.0;
  int n = 0;
  for (const StepRecord& r : run.steps) {
    if (!r.accepted || r.withheld) continue;
    for (const GyroInnovation& g : r.innovations) {
      s += g.z.squaredNorm();
      n += 2;
    }
  }
  return n > 0 ? RadToArcsec(std::sqrt(s / n)) : 0.0;
}

std::vector<ResidualPoint> ResidualSeries(const ModelRun& run,
                                          const std::vector<TelemetryFrame>& frames) {
  std::vector<ResidualPoint> out;
  const absl::Time t0 = frames.front().time;
  for (const StepRecord& r : run.steps) {
    if (!r.nis_formed || r.withheld) continue;
    for (const GyroInnovation& g : r.innovations) {
      out.push_back({HoursSince(frames[r.frame].time, t0), g.id, RadToArcsec(g.z.norm()),
                     RadToArcsec(std::sqrt(0.5 * g.sigma.squaredNorm()))});
    }
  }
  return out;
}

Mismatches LocateMismatches(const ModelRun& base, const ModelRun& extended,
                            const std::vector<RegimeSpan>& spans,
                            const std::vector<TelemetryFrame>& frames, double alpha) {
  const std::vector<bool> outlier = OutlierFrames(extended, static_cast<int>(frames.size()));
  const CellReference reference = Reference(Cells(extended, spans, frames, outlier));
  Mismatches out;
  out.base = Locate(base, spans, frames, outlier, reference, alpha);
  out.remaining = Locate(extended, spans, frames, outlier, reference, alpha);
  return out;
}

Mismatch HeldOutMismatch(const HeldOutResult& held_out) {
  Mismatch where;
  const GapSummary* worst = nullptr;
  for (const GapSummary& g : held_out.gaps) {
    if (g.dof > 0 && (worst == nullptr || g.nees / g.dof > worst->nees / worst->dof)) worst = &g;
  }
  if (worst == nullptr) return where;
  where.found = true;
  where.start = worst->start;
  where.end = worst->end;
  where.regime = worst->regime;
  where.span = worst->span;
  where.source = "held-out prediction";
  where.p_value = held_out.dof > 0 ? ChiSquareSurvival(held_out.nees, held_out.dof) : 1.0;
  double top = 0;
  for (const auto& [id, rate] : worst->gyro_drift_rate_deg_h) {
    if (rate > top) {
      top = rate;
      where.gyro = id;
    }
  }
  return where;
}

std::optional<Unexplained> FindUnexplained(const Mismatch& remaining,
                                           const std::string& unresolved, int unresolved_gyro,
                                           const Mismatch& unresolved_where,
                                           const HeldOutResult& held_out,
                                           const ProfiledDeviance& fit, bool after_findings,
                                           double alpha) {
  const double held_out_p =
      held_out.dof > 0 ? ChiSquareSurvival(held_out.nees, held_out.dof) : 1.0;
  // The held-out statistic leans on the filter's own prediction sigma, so it must also be
  // material (MispredictsHeldOut).
  const bool held_out_misfit = MispredictsHeldOut(held_out, alpha);
  const bool residual_misfit = remaining.found || !unresolved.empty();
  // Noise beyond the configured one everywhere (no span stands out): material when the
  // star-tracker differences are kMaterialDispersion times their predicted variance.
  const double dispersion_z = (fit.dispersion - 1.0) * std::sqrt(0.5 * std::max(1, fit.components));
  const bool noise_misfit =
      fit.dispersion > kMaterialDispersion && Significant(NormalSurvival(dispersion_z), alpha, 2);
  if (!held_out_misfit && !residual_misfit && !noise_misfit) return std::nullopt;
  Unexplained out;
  Finding& u = out.finding;
  u.effect = kVerdictUnexplained;
  Mismatch& where = out.where;
  where = remaining;
  if (held_out_misfit && !residual_misfit) {
    if (const Mismatch held = HeldOutMismatch(held_out); held.found) where = held;
  }
  if (!remaining.found && !unresolved.empty() && unresolved_gyro > 0) where.gyro = unresolved_gyro;
  if (!remaining.found && !unresolved.empty() && unresolved_where.found) where = unresolved_where;
  u.gyro = where.gyro;
  // What the mismatch is: the residual excess of its span; else the reason the candidates were
  // not taken (it says what it is); else the held-out prediction or the noise.
  const std::string what =
      remaining.found
          ? absl::StrFormat("residual RMS %.1f arcsec against %.1f expected (p = %.2g)",
                            where.size_arcsec, where.expected_arcsec, where.p_value)
      : !unresolved.empty() ? std::string("the candidates that fit it were not taken")
      : held_out_misfit
          ? absl::StrFormat("held-out prediction error NEES %.1f on %d dof (p = %.2g)",
                            held_out.nees, held_out.dof, held_out_p)
          : absl::StrFormat("star-tracker differences %.2f times their predicted variance "
                            "throughout: the recording's noise exceeds the configured one",
                            fit.dispersion);
  u.explanation = absl::StrFormat(
      "%s: a mismatch no candidate effect explains remains %s%s, %s to %s (%s span): %s%s",
      after_findings ? "after adding the findings"
                     : "the configured model does not fit the recording",
      where.gyro > 0 ? absl::StrCat("in gyro ", where.gyro) : std::string("in all gyros"),
      where.source.empty() ? "" : absl::StrCat(" (", where.source, ")"), FormatUtc(where.start),
      FormatUtc(where.end), where.regime, what,
      unresolved.empty() ? "" : absl::StrCat("; ", unresolved));
  u.evidence.held_out_nees_after = held_out.nees;
  u.evidence.held_out_dof = held_out.dof;
  u.evidence.p_value = residual_misfit ? where.p_value : (held_out_misfit ? held_out_p : 0.0);
  return out;
}

}  // namespace esg::estimator::discovery
