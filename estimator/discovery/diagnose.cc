#include "estimator/discovery/diagnose.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <map>
#include <mutex>
#include <optional>
#include <thread>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/calibration_model.h"
#include "estimator/discovery/candidates.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/statistics.h"
#include "estimator/rotation.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Vector3d;

const char* EffectId(Effect e) {
  switch (e) {
    case Effect::kRotorDisplacement:
      return "rotor_displacement";
    case Effect::kFourthHarmonic:
      return "fourth_harmonic";
    case Effect::kUnequalStiffness:
      return "unequal_stiffness";
    case Effect::kGyroMisalignment:
      return "gyro_misalignment";
    case Effect::kStarTrackerMisalignment:
      return "star_tracker_misalignment";
    case Effect::kStarTrackerLatency:
      return "star_tracker_latency";
    case Effect::kRandomWalkDrift:
      return "random_walk_drift";
  }
  return "?";
}

namespace {

// Runs job(0..count-1) on up to `threads` threads; returns when all are done.
void ParallelRun(int threads, int count, const std::function<void(int)>& job) {
  const int n = std::max(1, std::min(threads, count));
  if (n == 1) {
    for (int i = 0; i < count; ++i) job(i);
    return;
  }
  std::atomic<int> next{0};
  std::vector<std::thread> pool;
  for (int t = 0; t < n; ++t) {
    pool.emplace_back([&] {
      for (int i = next++; i < count; i = next++) job(i);
    });
  }
  for (std::thread& th : pool) th.join();
}

double Hours(absl::Time t, absl::Time t0) { return absl::ToDoubleHours(t - t0); }

std::string Utc(absl::Time t) {
  return absl::FormatTime("%Y-%m-%dT%H:%M:%SZ", t, absl::UTCTimeZone());
}

// The user's model in the form the discovery extends: every term of eq. (1), (10) is in the
// filter, held at its configured value unless freed; terms outside the user's model are held at
// zero (docs/discovery.md, "The model": a term absent or zero without a sigma is not in it).
absl::StatusOr<ModelState> UserModel(const SpacecraftConfig& config, const DiagnoseOptions& opt) {
  auto spec = ParseModel(opt.model);
  if (!spec.ok()) return spec.status();
  ModelState m;
  m.config = config;
  const bool only_random_walk = !spec->k0 && !spec->c1c2 && !spec->mu_nu;
  const auto mask = spec->TermMask();
  for (GyroConfig& g : m.config.gyros) {
    DriftVector value = g.model.AsVector(), sigma = g.model_sigma.AsVector();
    for (int i = 0; i < kNumDriftCoefficients; ++i) {
      if (only_random_walk) {
        sigma(i) = 0.0;  // model (11) alone: the configured model applied as it is
      } else if (!mask[i]) {
        value(i) = 0.0;
        sigma(i) = 0.0;
      }
    }
    g.model = DriftCoefficients::FromVector(value);
    g.model_sigma = DriftCoefficients::FromVector(sigma);
  }
  m.options.model.k0 = m.options.model.c1c2 = m.options.model.mu_nu = true;
  m.options.model.random_walk = spec->random_walk;
  if (opt.integration_rate_hz > 0.0) m.config.filter.integration_rate_hz = opt.integration_rate_hz;
  // eq. (12) would exclude a gyro whose unmodelled drift makes its pair disagree with the star
  // tracker, and a model would then be scored on fewer data than another: during diagnosis the
  // pair test is off (outliers are still rejected by eq. (14)).
  m.config.filter.fault_threshold = kPi;
  return m;
}

std::string DescribeModel(const ModelState& m, const DiagnoseOptions& opt) {
  std::string text = absl::StrCat("configured model ", opt.model);
  if (!m.added.empty()) absl::StrAppend(&text, " + ", absl::StrJoin(m.added, " + "));
  return text;
}

struct Gap {
  int span = -1;
  int first = 0;
  int last = 0;
};

std::vector<Gap> ChooseGaps(const std::vector<RegimeSpan>& spans,
                            const std::vector<TelemetryFrame>& frames, const DiagnoseOptions& opt) {
  std::vector<Gap> gaps;
  if (frames.empty()) return gaps;
  const absl::Time t0 = frames.front().time, t1 = frames.back().time;
  const double total_h = Hours(t1, t0);
  const double earliest_h = std::max(3.0, 0.15 * total_h);
  auto st_count = [&](int a, int b) {
    int n = 0;
    for (int i = a; i <= b; ++i)
      n += frames[i].star_tracker.has_value() && frames[i].star_tracker->valid;
    return n;
  };
  auto gap_of = [&](int k) -> std::optional<Gap> {
    const RegimeSpan& s = spans[k];
    if (s.regime == Regime::kSlew || s.hours() < 1.0 || Hours(s.start, t0) < earliest_h)
      return std::nullopt;
    Gap g{k, s.first_frame, s.first_frame};
    const absl::Time stop = s.start + absl::Seconds(HoursToSeconds(opt.max_gap_hours));
    while (g.last + 1 <= s.last_frame && frames[g.last + 1].time <= stop) ++g.last;
    if (st_count(g.first, g.last) < 10) return std::nullopt;
    return g;
  };
  // Dominant regime by time.
  std::map<Regime, double> time_in;
  for (const RegimeSpan& s : spans) time_in[s.regime] += s.hours();
  Regime dominant = Regime::kOrbital;
  double most = -1;
  for (const auto& [r, h] : time_in) {
    if (r != Regime::kSlew && h > most) {
      most = h;
      dominant = r;
    }
  }
  std::vector<int> order;
  // One span of every other regime (the longest), then spans of the dominant one, latest first.
  std::map<Regime, int> longest;
  for (int k = 0; k < static_cast<int>(spans.size()); ++k) {
    if (!gap_of(k) || spans[k].regime == dominant) continue;
    auto it = longest.find(spans[k].regime);
    if (it == longest.end() || spans[k].hours() > spans[it->second].hours())
      longest[spans[k].regime] = k;
  }
  for (const auto& [r, k] : longest) order.push_back(k);
  for (int k = static_cast<int>(spans.size()) - 1; k >= 0; --k) {
    if (spans[k].regime == dominant && gap_of(k)) order.push_back(k);
  }
  for (int k : order) {
    if (static_cast<int>(gaps.size()) >= opt.max_gaps) break;
    const Gap g = *gap_of(k);
    bool clear = true;
    for (const Gap& other : gaps) {
      // At least an hour of star-tracker data between gaps to re-calibrate.
      const absl::Time a0 = frames[g.first].time - absl::Hours(1),
                       a1 = frames[g.last].time + absl::Hours(1);
      if (!(frames[other.last].time < a0 || frames[other.first].time > a1)) clear = false;
    }
    if (clear) gaps.push_back(g);
  }
  if (gaps.empty() && total_h >= 4.0) {
    // No regime span to hold out: the last quarter of the recording, as in the paper's Fig. 7/8.
    Gap g;
    g.first = static_cast<int>(frames.size()) - 1;
    while (g.first > 0 && Hours(frames[g.first - 1].time, t0) >= 0.75 * total_h) --g.first;
    g.last = static_cast<int>(frames.size()) - 1;
    g.span = SpanOfFrame(spans, g.first);
    if (st_count(g.first, g.last) >= 10) gaps.push_back(g);
  }
  std::sort(gaps.begin(), gaps.end(), [](const Gap& a, const Gap& b) { return a.first < b.first; });
  return gaps;
}

struct HeldOutResult {
  std::vector<GapSummary> gaps;
  double nees = 0.0;
  int dof = 0;
  double rate_rms_deg_h = 0.0;
  std::vector<HeldOutPoint> points;
};

HeldOutResult SummariseHeldOut(const ModelRun& run, const std::vector<Gap>& gaps,
                               const std::vector<RegimeSpan>& spans,
                               const std::vector<TelemetryFrame>& frames) {
  HeldOutResult out;
  const absl::Time t0 = frames.front().time;
  double rate2 = 0.0;
  int rated = 0;
  for (size_t k = 0; k < gaps.size(); ++k) {
    GapSummary g;
    g.span = gaps[k].span;
    g.regime = gaps[k].span >= 0 ? RegimeName(spans[gaps[k].span].regime) : "";
    g.start = frames[gaps[k].first].time;
    g.end = frames[gaps[k].last].time;
    std::vector<double> t;
    std::array<std::vector<double>, 3> y;
    std::map<int, std::vector<double>> gt;
    std::map<int, std::array<std::vector<double>, 3>> gy;
    std::map<int, std::pair<double, double>> sigma_first_last;
    for (const HeldOutSample& s : run.held_out) {
      if (s.span != static_cast<int>(k)) continue;
      t.push_back(s.seconds);
      for (int i = 0; i < 3; ++i) y[i].push_back(s.error_in(i));
      out.points.push_back(
          {Hours(frames[s.frame].time, t0), static_cast<int>(k), RadToArcsec(s.error_in.norm())});
      g.final_error_arcsec = RadToArcsec(s.error_in.norm());
      for (const HeldOutGyroError& e : s.gyros) {
        gt[e.id].push_back(s.seconds);
        for (int i = 0; i < 3; ++i) gy[e.id][i].push_back(e.error_in(i));
        auto it = sigma_first_last.find(e.id);
        if (it == sigma_first_last.end()) {
          sigma_first_last[e.id] = {e.sigma, e.sigma};
        } else {
          it->second.second = e.sigma;
        }
      }
    }
    if (t.size() < 3) {
      out.gaps.push_back(g);
      continue;
    }
    Vector3d slope;
    for (int i = 0; i < 3; ++i) slope(i) = FitRobustLine(t, y[i]).slope;
    g.drift_rate_deg_h = RadPerSecToDegPerHour(slope.norm());
    rate2 += g.drift_rate_deg_h * g.drift_rate_deg_h;
    ++rated;
    // Spin-axis prediction error growth over the gap against the filter's own uncertainty:
    // growth = slope * T per inertial axis (two effective axes, perpendicular to h), its
    // variance the growth of the filter's spin-axis variance plus the line fit's.
    for (const auto& [id, times] : gt) {
      if (times.size() < 3) continue;
      const double T = times.back() - times.front();
      Vector3d growth;
      double fit_var = 0.0;
      for (int i = 0; i < 3; ++i) {
        const RobustLine line = FitRobustLine(times, gy[id][i]);
        growth(i) = line.slope * T;
        fit_var += line.residual_sigma * line.residual_sigma * 12.0 / std::max(1, line.used) / 3.0;
      }
      const auto [s_first, s_last] = sigma_first_last[id];
      const double var = std::max(s_last * s_last - s_first * s_first, 0.0) + fit_var;
      if (var > 0) {
        g.nees += growth.squaredNorm() / var;
        g.dof += 2;
      }
      g.gyro_drift_rate_deg_h.emplace_back(id,
                                           RadPerSecToDegPerHour(growth.norm() / std::max(T, 1.0)));
    }
    out.nees += g.nees;
    out.dof += g.dof;
    out.gaps.push_back(g);
  }
  out.rate_rms_deg_h = rated > 0 ? std::sqrt(rate2 / rated) : 0.0;
  return out;
}

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
      out.push_back({Hours(frames[r.frame].time, t0), g.id, RadToArcsec(g.z.norm())});
    }
  }
  return out;
}

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
      c.hours.push_back(Hours(frames[r.frame].time, t0));
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

// The (gyro, span) cell whose residuals exceed the reference most; `found` when its excess is
// significant at a Bonferroni level over the cells.
Mismatch Locate(const ModelRun& run, const std::vector<RegimeSpan>& spans,
                const std::vector<TelemetryFrame>& frames, const std::vector<bool>& outlier,
                const CellReference& ref, double alpha) {
  Mismatch m;
  const auto cells = Cells(run, spans, frames, outlier);
  if (cells.empty()) return m;
  const Cell* worst = nullptr;
  double worst_z = -1e300;
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
  }
  if (worst == nullptr) return m;
  m.p_value = NormalSurvival(worst_z);
  m.found = m.p_value < alpha / std::max(1, tested);
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

bool Significant(double p, double alpha, int tests) { return p < alpha / std::max(1, tests); }

// Materiality bounds of the goodness-of-fit checks (docs/discovery.md): with ~10^4 star-tracker
// differences a 3% excess is already "significant"; these ask for a physically material one.
constexpr double kMaterialNeesRatio = 4.0;   // held-out errors beyond 2x the filter's sigma
constexpr double kMaterialDispersion = 1.5;  // star-tracker differences 1.22x their sigma
constexpr int kQuarters = 4;                 // time blocks of the homogeneity test

const Parameter* FindParameter(const std::vector<Parameter>& ps, const std::string& name) {
  for (const Parameter& p : ps) {
    if (p.name == name) return &p;
  }
  return nullptr;
}

std::string VectorText(const std::vector<Parameter>& ps, const std::string& name,
                       const char* format) {
  std::vector<std::string> parts;
  for (int i = 0; i < 3; ++i) {
    const Parameter* p = FindParameter(ps, absl::StrFormat("%s[%d]", name, i));
    if (p == nullptr) return "";
    parts.push_back(p->sigma > 0 ? absl::StrFormat("%s+-%s", absl::StrFormat(format, p->value),
                                                   absl::StrFormat(format, p->sigma))
                                 : absl::StrFormat(format, p->value));
  }
  return absl::StrCat("[", absl::StrJoin(parts, ", "), "]");
}

// The physics of a finding in the units people use (docs/discovery.md, "Physics in the report").
std::string Explain(const Finding& f, const Evidence& e) {
  const std::string stats =
      absl::StrFormat("the likelihood improves by %.1f (-2 log L) for %d parameter%s, p = %.2g",
                      e.delta_deviance, e.parameters, e.parameters == 1 ? "" : "s", e.lr_p_value);
  const auto& ps = f.parameters;
  if (f.effect == "rotor_displacement") {
    const Parameter* angle = FindParameter(ps, "lineAngleDeg");
    const Parameter* size = FindParameter(ps, "displacementSizeUm");
    return absl::StrFormat(
        "gyro %d drifts with odd harmonics of a displaced rotor (eq. (8)-(10)): C1 = %s deg/h, "
        "C2 = %s deg/h, %.0f deg apart as lines%s; %s",
        f.gyro, VectorText(ps, "c1DegH", "%.3f"), VectorText(ps, "c2DegH", "%.3f"),
        angle ? angle->value : 0.0,
        size
            ? absl::StrFormat("; suspension offset voltages imply a %.2f um displacement (eq. (3))",
                              size->value)
            : "",
        stats);
  }
  if (f.effect == "fourth_harmonic") {
    const Parameter* k0 = FindParameter(ps, "k0DegH");
    return absl::StrFormat(
        "gyro %d: the 4th-harmonic coefficient k0 (eq. (1)) is missing or wrong: it "
        "calibrates to %.4f +- %.4f deg/h; %s",
        f.gyro, k0 ? k0->value : 0.0, k0 ? k0->sigma : 0.0, stats);
  }
  if (f.effect == "unequal_stiffness") {
    return absl::StrFormat(
        "gyro %d: unequal suspension stiffness (eq. (1)): mu = %s deg/h, nu = %s deg/h; %s", f.gyro,
        VectorText(ps, "muDegH", "%.3f"), VectorText(ps, "nuDegH", "%.3f"), stats);
  }
  if (f.effect == "gyro_misalignment") {
    return absl::StrFormat(
        "gyro %d case axes are misaligned to the body by %s arcsec (rotation vector, "
        "body axes); %s",
        f.gyro, VectorText(ps, "misalignmentArcsec", "%.1f"), stats);
  }
  if (f.effect == "star_tracker_misalignment") {
    return absl::StrFormat(
        "the star tracker is misaligned to the body by %s arcsec (rotation vector, body "
        "axes), common to all gyros; %s",
        VectorText(ps, "misalignmentArcsec", "%.1f"), stats);
  }
  if (f.effect == "star_tracker_latency") {
    const Parameter* tau = FindParameter(ps, "latencyMs");
    return absl::StrFormat(
        "the star-tracker time tag is %s by %.0f +- %.0f ms (the attitude it reports is "
        "that of %.0f ms %s); %s",
        tau && tau->value < 0 ? "early" : "late", tau ? std::abs(tau->value) : 0.0,
        tau ? tau->sigma : 0.0, tau ? std::abs(tau->value) : 0.0,
        tau && tau->value < 0 ? "later" : "earlier", stats);
  }
  if (f.effect == "random_walk_drift") {
    const Parameter* q = FindParameter(ps, "randomWalkDegHSqrtH");
    const Parameter* q0 = FindParameter(ps, "configuredRandomWalkDegHSqrtH");
    return absl::StrFormat(
        "the drift is less stable than configured: random-walk intensity %.4f "
        "deg/h/sqrt(h) against %.4f configured; %s",
        q ? q->value : 0.0, q0 ? q0->value : 0.0, stats);
  }
  return stats;
}

}  // namespace

absl::StatusOr<DiagnosisReport> Diagnose(const SpacecraftConfig& config,
                                         const std::vector<TelemetryFrame>& frames,
                                         const DiagnoseOptions& options,
                                         const DiagnoseProgressFn& progress) {
  if (absl::Status s = ValidateConfig(config); !s.ok()) return s;
  if (frames.size() < 10) {
    return absl::InvalidArgumentError(
        absl::StrFormat("recording: %d frames, at least 10 needed", frames.size()));
  }
  for (size_t i = 1; i < frames.size(); ++i) {
    if (!(frames[i].time > frames[i - 1].time)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "recording: frame %d (%s) is not after frame %d", i, Utc(frames[i].time), i - 1));
    }
  }
  if (!(options.alpha > 0.0 && options.alpha < 1.0)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("alpha: must be in (0, 1), got %g", options.alpha));
  }
  int st_frames = 0;
  for (const TelemetryFrame& f : frames)
    st_frames += f.star_tracker.has_value() && f.star_tracker->valid;
  if (st_frames < 10) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "recording: %d valid star-tracker samples; the comparison needs at least 10", st_frames));
  }
  auto user = UserModel(config, options);
  if (!user.ok()) return user.status();
  auto say = [&](double f, const std::string& stage) {
    if (progress) progress(std::clamp(f, 0.0, 1.0), stage);
  };
  // Cancellation, latched: once options.cancelled returns true every later check agrees, so a
  // parallel job skipped for it is never mistaken for a finished one.
  std::atomic<bool> stopped{false};
  auto stop = [&]() -> bool {
    if (stopped.load()) return true;
    if (options.cancelled && options.cancelled()) stopped.store(true);
    return stopped.load();
  };
  const auto cancelled = [] { return absl::CancelledError("diagnosis cancelled"); };
  if (stop()) return cancelled();

  DiagnosisReport report;
  report.first_frame_time = frames.front().time;
  report.frames = static_cast<int>(frames.size());
  // Running gyros: configured and reporting in at least half of the frames.
  for (const GyroConfig& g : config.gyros) {
    int n = 0;
    for (const TelemetryFrame& f : frames) n += f.gyros[g.id - 1].has_value();
    if (2 * n >= static_cast<int>(frames.size())) report.gyros.push_back(g.id);
  }
  if (report.gyros.size() < 2) {
    return absl::InvalidArgumentError(
        "recording: fewer than two configured gyros report in half of the frames");
  }
  say(0.0, "regimes");
  const BodyRates rates = MeasureBodyRates(config, frames);
  report.regimes = FindRegimes(frames, rates, options.regimes);
  const std::vector<Gap> gaps = ChooseGaps(report.regimes, frames, options);
  ModelRunOptions held_out_options;
  for (const Gap& g : gaps) held_out_options.withheld.emplace_back(g.first, g.last);

  auto run_full_model = [&](const ModelState& m) -> absl::StatusOr<ModelRun> {
    if (stop()) return cancelled();
    ++report.filter_runs;
    return RunModel(m.config, m.options, CorrectStarTracker(frames, rates, m.correction));
  };
  auto run_held_out = [&](const ModelState& m) -> absl::StatusOr<ModelRun> {
    if (stop()) return cancelled();
    ++report.filter_runs;
    return RunModel(m.config, m.options, CorrectStarTracker(frames, rates, m.correction),
                    held_out_options);
  };

  // The user's model: full run and held-out run in parallel.
  say(0.02, "user model");
  ModelState model = *user;
  std::optional<absl::StatusOr<ModelRun>> base_full, base_held;
  if (stop()) return cancelled();
  ParallelRun(options.threads, 2, [&](int i) {
    if (stop()) return;
    if (i == 0) {
      base_full = RunModel(model.config, model.options,
                           CorrectStarTracker(frames, rates, model.correction));
    } else if (!gaps.empty()) {
      base_held = RunModel(model.config, model.options,
                           CorrectStarTracker(frames, rates, model.correction), held_out_options);
    }
  });
  if (stopped.load()) return cancelled();
  report.filter_runs += gaps.empty() ? 1 : 2;
  if (!base_full->ok()) return base_full->status();
  ModelRun current_run = std::move(**base_full);
  ProfiledDeviance current = Profile(current_run);
  HeldOutResult base_held_out;
  if (base_held.has_value()) {
    if (!base_held->ok()) return base_held->status();
    base_held_out = SummariseHeldOut(**base_held, gaps, report.regimes, frames);
  }
  ModelRun base_run = current_run;
  report.before.model = DescribeModel(model, options);
  report.before.residual_rms_arcsec = ResidualRmsArcsec(current_run);
  report.before.deviance = current.value;
  report.before.dispersion = current.dispersion;
  report.before.gap_drift_rate_deg_h = base_held_out.rate_rms_deg_h;
  report.before.held_out_nees = base_held_out.nees;
  report.before.held_out_dof = base_held_out.dof;
  report.before.gaps = base_held_out.gaps;
  report.residuals_before = ResidualSeries(current_run, frames);
  report.held_out_before = base_held_out.points;
  const double log_n = std::log(std::max(2, current.steps));

  // Forward selection.
  HeldOutResult current_held_out = base_held_out;
  bool held_out_current = true;  // current_held_out belongs to the current model
  bool time_localized = false;   // significant candidates, each only fitting part of the time
  for (int round = 0; round < options.max_effects; ++round) {
    if (stop()) return cancelled();
    const std::vector<Candidate> candidates = ListCandidates(model, report.gyros, options.effects);
    if (candidates.empty()) break;
    say(0.05 + 0.8 * round / options.max_effects,
        absl::StrFormat("round %d: %d candidates", round + 1, candidates.size()));
    FitContext ctx;
    ctx.frames = &frames;
    ctx.rates = &rates;
    ctx.model = &model;
    ctx.model_run = &current_run;
    ctx.options = &options;
    ctx.gyros = report.gyros;
    std::vector<std::optional<absl::StatusOr<CandidateFit>>> fits(candidates.size());
    // Costly candidates first for load balance.
    std::vector<int> order(candidates.size());
    for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
    auto cost = [](const Candidate& c) {
      return c.effect == Effect::kRandomWalkDrift ? 5 : (c.gyro == 0 ? 3 : 1);
    };
    std::stable_sort(order.begin(), order.end(),
                     [&](int a, int b) { return cost(candidates[a]) > cost(candidates[b]); });
    std::atomic<int> done{0};
    std::mutex progress_mu;
    ParallelRun(options.threads, static_cast<int>(order.size()), [&](int j) {
      if (stop()) return;
      const int i = order[j];
      fits[i] = FitCandidate(candidates[i], ctx);
      const int d = ++done;
      std::lock_guard<std::mutex> lock(progress_mu);
      say(0.05 + 0.8 * (round + static_cast<double>(d) / candidates.size()) / options.max_effects,
          absl::StrFormat("round %d: %s fitted (%d/%d)", round + 1, CandidateName(candidates[i]), d,
                          candidates.size()));
    });
    struct Scored {
      int index;
      double delta, penalty, score, p, threshold;
      bool significant;
      std::array<double, kQuarters> quarters{};
      bool homogeneous = true;
    };
    if (stopped.load()) return cancelled();
    const std::vector<double> current_steps = StepDeviance(current_run);
    std::vector<Scored> scored;
    for (size_t i = 0; i < candidates.size(); ++i) {
      if (!fits[i]->ok()) return fits[i]->status();
      const CandidateFit& f = **fits[i];
      report.filter_runs += f.runs;
      const ProfiledDeviance d = Profile(f.run);
      Scored s;
      s.index = static_cast<int>(i);
      s.delta = current.value - d.value;
      s.penalty = f.searched ? f.parameters * log_n : 0.0;
      s.score = s.delta - s.penalty;
      const int k = std::max(1, f.parameters);
      s.p = ChiSquareSurvival(std::max(0.0, s.delta), k);
      s.threshold = ChiSquareQuantile(1.0 - options.alpha / candidates.size(), k);
      s.significant =
          f.parameters > 0 && Significant(s.p, options.alpha, static_cast<int>(candidates.size()));
      // Homogeneity: the effects of the library are constant in time. With its parameters held
      // from the start at their final values, an effect that makes the fit worse in a quarter of
      // the recording by more than its cost there (k ln n_q, plus the chi-square quantile) while
      // improving it elsewhere is fitting a change in time (a fault, a jump), not the physics it
      // names.
      const std::vector<double> cand_steps = StepDeviance(f.fixed_run ? *f.fixed_run : f.run);
      std::array<int, kQuarters> steps_in{};
      for (size_t j = 0; j < std::min(current_steps.size(), cand_steps.size()); ++j) {
        const int q =
            std::min(kQuarters - 1,
                     static_cast<int>(kQuarters * current_run.steps[j].frame / frames.size()));
        s.quarters[q] += current_steps[j] - cand_steps[j];
        ++steps_in[q];
      }
      for (int q = 0; q < kQuarters; ++q) {
        const double cost = k * std::log(std::max(2, steps_in[q])) +
                            ChiSquareQuantile(1.0 - options.alpha / kQuarters, k);
        if (s.quarters[q] < -cost) s.homogeneous = false;
      }
      scored.push_back(s);
    }
    // Deterministic effects first: the random walk is the model's allowance for what no
    // deterministic term explains, raised only when none of them does. The best-scoring
    // significant candidate must be homogeneous in time; when it is not, the mismatch is a change
    // in time (the smaller candidates that pass are its spill-over into the other gyros through
    // the shared star tracker), and the round stops with the mismatch unexplained.
    std::vector<Scored> significant;
    bool inhomogeneous_only = false;
    for (int pass = 0; pass < 2 && significant.empty() && !inhomogeneous_only; ++pass) {
      std::vector<Scored> pool;
      for (const Scored& s : scored) {
        const bool rw = (**fits[s.index]).candidate.effect == Effect::kRandomWalkDrift;
        if (s.significant && rw == (pass == 1)) pool.push_back(s);
      }
      if (pool.empty()) continue;
      const auto top =
          std::max_element(pool.begin(), pool.end(),
                           [](const Scored& a, const Scored& b) { return a.score < b.score; });
      if (!top->homogeneous) {
        inhomogeneous_only = true;
        break;
      }
      for (const Scored& s : pool) {
        if (s.homogeneous) significant.push_back(s);
      }
    }
    std::sort(significant.begin(), significant.end(),
              [](const Scored& a, const Scored& b) { return a.score > b.score; });
    // A drift instability can be partly fitted by a deterministic term. When the random walk is
    // significant too, the best deterministic candidate is tested on top of it (the nested
    // comparison): if it adds nothing significant beyond the raised random walk, the random walk
    // is the explanation.
    std::string rw_note;
    if (!significant.empty() &&
        (**fits[significant.front().index]).candidate.effect != Effect::kRandomWalkDrift) {
      const Scored* rw = nullptr;
      for (const Scored& x : scored) {
        if ((**fits[x.index]).candidate.effect == Effect::kRandomWalkDrift && x.significant &&
            x.homogeneous)
          rw = &x;
      }
      if (rw != nullptr) {
        const CandidateFit& det = **fits[significant.front().index];
        const CandidateFit& walk = **fits[rw->index];
        ModelState both = det.model;
        both.config.random_walk = walk.model.config.random_walk;
        auto run = run_full_model(both);
        if (!run.ok()) return run.status();
        const double gain = Profile(walk.run).value - Profile(*run).value;
        const int k = std::max(1, det.parameters);
        const double p_det = ChiSquareSurvival(std::max(0.0, gain), k);
        rw_note = absl::StrFormat(
            "on top of a random walk raised to %.4f deg/h/sqrt(h) it still improves -2 log L by "
            "%.1f (p = %.2g)",
            SiToDegPerHourSqrtHour(walk.model.config.random_walk), gain, p_det);
        if (!Significant(p_det, options.alpha, static_cast<int>(candidates.size()))) {
          significant.assign(1, *rw);
          rw_note = absl::StrFormat(
              "%s fits part of it but adds nothing significant on top of the raised random walk "
              "(-2 log L %.1f, p = %.2g)",
              CandidateName(det.candidate), gain, p_det);
        }
      }
    }
    int chosen = -1;
    std::vector<std::pair<int, HeldOutResult>> contenders;
    if (!significant.empty()) {
      chosen = significant.front().index;
      // Candidates the likelihood does not tell apart: held-out prediction decides.
      std::vector<int> close;
      for (const Scored& s : significant) {
        if (s.score >= significant.front().score - kDecisiveDeviance) close.push_back(s.index);
      }
      if (close.size() > 1 && !gaps.empty()) {
        say(0.05 + 0.8 * (round + 0.95) / options.max_effects,
            "held-out comparison of close candidates");
        std::vector<std::optional<absl::StatusOr<ModelRun>>> held(close.size());
        ParallelRun(options.threads, static_cast<int>(close.size()), [&](int j) {
          if (stop()) return;
          const ModelState& m = (**fits[close[j]]).model;
          held[j] = RunModel(m.config, m.options, CorrectStarTracker(frames, rates, m.correction),
                             held_out_options);
        });
        if (stopped.load()) return cancelled();
        report.filter_runs += static_cast<int>(close.size());
        double best = 1e300;
        for (size_t j = 0; j < close.size(); ++j) {
          if (!held[j]->ok()) return held[j]->status();
          HeldOutResult r = SummariseHeldOut(**held[j], gaps, report.regimes, frames);
          if (r.nees < best) {
            best = r.nees;
            chosen = close[j];
          }
          contenders.emplace_back(close[j], std::move(r));
        }
      }
    }
    // Concealed effects: nothing significant in-sample (the residual-drift states absorb the
    // effect where it was calibrated), yet the model mispredicts the held-out regimes. Then the
    // candidates are scored by held-out prediction: the one whose held-out NEES falls the most,
    // by more than the chi-square(k) quantile at the round's Bonferroni level, is taken.
    bool held_out_selected = false;
    if (chosen < 0 && !inhomogeneous_only && !held_out_current && !gaps.empty()) {
      auto held = run_held_out(model);
      if (!held.ok()) return held.status();
      current_held_out = SummariseHeldOut(*held, gaps, report.regimes, frames);
      held_out_current = true;
    }
    if (chosen < 0 && !inhomogeneous_only && current_held_out.dof > 0 &&
        Significant(ChiSquareSurvival(current_held_out.nees, current_held_out.dof), options.alpha,
                    2) &&
        current_held_out.nees > kMaterialNeesRatio * current_held_out.dof) {
      say(0.05 + 0.8 * (round + 0.95) / options.max_effects,
          "held-out scoring of the candidates (concealed mismatch)");
      std::vector<std::optional<absl::StatusOr<ModelRun>>> held(scored.size());
      ParallelRun(options.threads, static_cast<int>(scored.size()), [&](int j) {
        if (stop()) return;
        const CandidateFit& f = **fits[scored[j].index];
        if (f.parameters == 0) return;
        held[j] = RunModel(f.model.config, f.model.options,
                           CorrectStarTracker(frames, rates, f.model.correction), held_out_options);
      });
      if (stopped.load()) return cancelled();
      double best_drop = 0.0;
      for (size_t j = 0; j < scored.size(); ++j) {
        if (!held[j].has_value()) continue;
        ++report.filter_runs;
        if (!held[j]->ok()) return held[j]->status();
        HeldOutResult r = SummariseHeldOut(**held[j], gaps, report.regimes, frames);
        const int k = std::max(1, (**fits[scored[j].index]).parameters);
        const double drop = current_held_out.nees - r.nees;
        const double needed = ChiSquareQuantile(1.0 - options.alpha / scored.size(), k);
        if (drop > needed && drop > best_drop && scored[j].homogeneous) {
          best_drop = drop;
          chosen = scored[j].index;
        }
        contenders.emplace_back(scored[j].index, std::move(r));
      }
      held_out_selected = chosen >= 0;
      if (!held_out_selected) contenders.clear();
    }
    for (const Scored& s : scored) {
      const CandidateFit& f = **fits[s.index];
      CandidateScore row;
      row.effect = EffectId(f.candidate.effect);
      row.gyro = f.candidate.gyro;
      row.round = round;
      row.parameters = f.parameters;
      row.delta_deviance = s.delta;
      row.penalty = s.penalty;
      row.score = s.score;
      row.p_value = s.p;
      row.significant = s.significant;
      row.homogeneous = s.homogeneous;
      row.selected = s.index == chosen;
      report.candidates.push_back(row);
    }
    if (chosen < 0) {
      time_localized = inhomogeneous_only;
      break;
    }
    CandidateFit& f = **fits[chosen];
    const Scored& s = *std::find_if(scored.begin(), scored.end(),
                                    [&](const Scored& x) { return x.index == chosen; });
    Finding finding;
    finding.effect = EffectId(f.candidate.effect);
    finding.gyro = f.candidate.gyro;
    finding.parameters = f.fitted;
    finding.evidence.delta_deviance = s.delta;
    finding.evidence.penalty = s.penalty;
    finding.evidence.parameters = f.parameters;
    finding.evidence.lr_p_value = s.p;
    finding.evidence.threshold = s.threshold;
    finding.evidence.round = round;
    finding.evidence.notes = f.notes;
    finding.explanation = Explain(finding, finding.evidence);
    if (!rw_note.empty()) finding.evidence.notes.push_back(rw_note);
    if (held_out_selected) {
      finding.evidence.notes.insert(
          finding.evidence.notes.begin(),
          "concealed: not significant in-sample (absorbed where calibrated), found by "
          "held-out prediction across regimes");
    }
    for (const auto& [index, r] : contenders) {
      if (index == chosen) {
        finding.evidence.held_out_nees_before = current_held_out.nees;
        finding.evidence.held_out_nees_after = r.nees;
        finding.evidence.held_out_dof = r.dof;
        current_held_out = r;
      } else if (!held_out_selected) {
        finding.evidence.notes.push_back(absl::StrFormat(
            "%s fits the star tracker almost as well (score within %.0f) but predicts the held-out "
            "spans worse: held-out NEES %.1f against %.1f",
            CandidateName((**fits[index]).candidate), kDecisiveDeviance, r.nees,
            std::find_if(contenders.begin(), contenders.end(), [&](const auto& c) {
              return c.first == chosen;
            })->second.nees));
      }
    }
    finding.evidence.notes.push_back(
        absl::StrFormat("improvement per quarter of the recording (-2 log L): %.1f, %.1f, %.1f, "
                        "%.1f (constant in time, "
                        "as a physical effect of the library is)",
                        s.quarters[0], s.quarters[1], s.quarters[2], s.quarters[3]));
    held_out_current = std::any_of(contenders.begin(), contenders.end(),
                                   [&](const auto& c) { return c.first == chosen; });
    report.findings.push_back(std::move(finding));
    model = f.model;
    current_run = std::move(f.run);
    current = Profile(current_run);
  }

  // The extended model: held-out run (the full run is current_run).
  if (stop()) return cancelled();
  say(0.9, "held-out prediction with the findings");
  HeldOutResult final_held_out = base_held_out;
  if (held_out_current) {
    final_held_out = current_held_out;
  } else if (!report.findings.empty() && !gaps.empty()) {
    auto held = run_held_out(model);
    if (!held.ok()) return held.status();
    final_held_out = SummariseHeldOut(*held, gaps, report.regimes, frames);
  }
  report.after.model = DescribeModel(model, options);
  report.after.residual_rms_arcsec = ResidualRmsArcsec(current_run);
  report.after.deviance = current.value;
  report.after.dispersion = current.dispersion;
  report.after.gap_drift_rate_deg_h = final_held_out.rate_rms_deg_h;
  report.after.held_out_nees = final_held_out.nees;
  report.after.held_out_dof = final_held_out.dof;
  report.after.gaps = final_held_out.gaps;
  report.residuals_after = ResidualSeries(current_run, frames);
  report.held_out_after = final_held_out.points;
  for (Finding& f : report.findings) {
    if (f.evidence.held_out_nees_after < 0 && report.findings.size() == 1) {
      f.evidence.held_out_nees_before = base_held_out.nees;
      f.evidence.held_out_nees_after = final_held_out.nees;
      f.evidence.held_out_dof = final_held_out.dof;
    }
  }

  // What remains: held-out prediction beyond the filter's uncertainty, or a span whose residual
  // excess stands out, with the extended model.
  const std::vector<bool> outlier = OutlierFrames(current_run, static_cast<int>(frames.size()));
  const CellReference reference = Reference(Cells(current_run, report.regimes, frames, outlier));
  report.mismatch = Locate(base_run, report.regimes, frames, outlier, reference, options.alpha);
  const Mismatch remaining =
      Locate(current_run, report.regimes, frames, outlier, reference, options.alpha);
  const double held_out_p =
      final_held_out.dof > 0 ? ChiSquareSurvival(final_held_out.nees, final_held_out.dof) : 1.0;
  // The held-out statistic leans on the filter's own prediction sigma, so it must also be
  // material: errors beyond twice the claimed 1-sigma (NEES per degree of freedom above 4).
  const bool held_out_misfit = Significant(held_out_p, options.alpha, 2) &&
                               final_held_out.nees > kMaterialNeesRatio * final_held_out.dof;
  const bool residual_misfit = remaining.found || time_localized;
  // Noise beyond the configured one everywhere (no span stands out): material when the
  // star-tracker differences are kMaterialDispersion times their predicted variance.
  const double dispersion_z =
      (current.dispersion - 1.0) * std::sqrt(0.5 * std::max(1, current.components));
  const bool noise_misfit = current.dispersion > kMaterialDispersion &&
                            Significant(NormalSurvival(dispersion_z), options.alpha, 2);
  if (held_out_misfit || residual_misfit || noise_misfit) {
    Finding u;
    u.effect = kVerdictUnexplained;
    Mismatch where = remaining;
    if (held_out_misfit && !residual_misfit) {
      // The held-out span that misses most.
      const GapSummary* worst = nullptr;
      for (const GapSummary& g : final_held_out.gaps) {
        if (g.dof > 0 && (worst == nullptr || g.nees / g.dof > worst->nees / worst->dof))
          worst = &g;
      }
      if (worst != nullptr) {
        where.found = true;
        where.start = worst->start;
        where.end = worst->end;
        where.regime = worst->regime;
        where.span = worst->span;
        where.source = "held-out prediction";
        where.p_value = held_out_p;
        where.gyro = 0;
        double top = 0;
        for (const auto& [id, rate] : worst->gyro_drift_rate_deg_h) {
          if (rate > top) {
            top = rate;
            where.gyro = id;
          }
        }
      }
    }
    u.gyro = where.gyro;
    u.explanation = absl::StrFormat(
        "%s: a mismatch no candidate effect explains remains %s%s, %s to %s (%s span): %s%s",
        report.findings.empty() ? "the configured model does not fit the recording"
                                : "after adding the findings",
        where.gyro > 0 ? absl::StrCat("in gyro ", where.gyro) : std::string("in all gyros"),
        where.source.empty() ? "" : absl::StrCat(" (", where.source, ")"), Utc(where.start),
        Utc(where.end), where.regime,
        residual_misfit
            ? absl::StrFormat("residual RMS %.1f arcsec against %.1f expected (p = %.2g)",
                              where.size_arcsec, where.expected_arcsec, where.p_value)
        : held_out_misfit
            ? absl::StrFormat("held-out prediction error NEES %.1f on %d dof (p = %.2g)",
                              final_held_out.nees, final_held_out.dof, held_out_p)
            : absl::StrFormat("star-tracker differences %.2f times their predicted variance "
                              "throughout: the recording's noise exceeds the configured one",
                              current.dispersion),
        time_localized
            ? "; the candidates that fit it improve only part of the recording and worsen "
              "the rest (a change in time such as a fault, not a constant effect)"
            : "");
    u.evidence.held_out_nees_after = final_held_out.nees;
    u.evidence.held_out_dof = final_held_out.dof;
    u.evidence.lr_p_value = residual_misfit ? where.p_value : (held_out_misfit ? held_out_p : 0.0);
    report.findings.push_back(u);
    if (report.findings.size() == 1) report.mismatch = where;
  }
  if (report.findings.empty()) {
    report.verdict = kVerdictNone;
  } else {
    report.verdict = report.findings.front().effect;
  }
  say(1.0, "done");
  return report;
}

}  // namespace esg::estimator::discovery
