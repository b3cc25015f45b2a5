// Reading faults told from drifts by each gyro's track (reading_fault_monitor.h).
#include "estimator/reading_fault_monitor.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <optional>
#include <utility>

#include "Eigen/Cholesky"
#include "Eigen/Geometry"
#include "Eigen/LU"
#include "absl/container/inlined_vector.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/statistics.h"

namespace esg::estimator {

using Eigen::Matrix2d;
using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Vector2d;
using Eigen::Vector3d;
using Eigen::VectorXd;

namespace {

// A verdict's figures, finite: a rate change or a jump so far beyond its bound that its norm or
// chi-square overflows (a corrupt state, not a sensor) saturates at the largest double, so the
// verdict stands and the session's checkpoint, which refuses a non-finite real, still restores
// (docs/fuzzing.md, finding 9). A NaN never makes a verdict (every test compares with >=).
ReadingFaultMonitor::Result Saturated(ReadingFaultMonitor::Result r) {
  constexpr double kMax = std::numeric_limits<double>::max();
  for (double* x : {&r.value, &r.threshold, &r.statistic}) *x = std::clamp(*x, -kMax, kMax);
  return r;
}

// Regressors of the line, optionally with a jump at point `jump_at` or a rate change at time
// `onset` (relative to the last point), or with a quadratic term: k (2 or 3) per point, no
// allocation for a window of up to 32 points (the default is 21).
struct Regressors {
  int k = 2;
  absl::InlinedVector<std::array<double, 3>, 32> f;
  Regressors(const ReadingFaultMonitor::Projected& p, int jump_at, std::optional<double> onset,
             bool quadratic) {
    k = 2 + (quadratic || jump_at >= 0 || onset.has_value() ? 1 : 0);
    f.resize(p.tau.size());
    for (size_t j = 0; j < p.tau.size(); ++j) {
      f[j] = {1.0, p.tau[j], 0.0};
      if (quadratic) f[j][2] = p.tau[j] * p.tau[j];
      if (jump_at >= 0) f[j][2] = static_cast<int>(j) >= jump_at ? 1.0 : 0.0;
      if (onset.has_value()) f[j][2] = std::max(0.0, p.tau[j] - *onset);
    }
  }
};

// Weighted least squares of y_j = (f_j^T (x) I_2) beta over the points (the first `count` of
// them when given), f_j the scalar regressors of point j (k of them, at most 3): beta (2k), its
// covariance and the weighted residual sum. The normal equations are summed block by block (N_ml = sum f_m f_l W_j,
// r_m = sum f_m W_j y_j) and RSS = sum y^T W y - r^T beta, so a fit costs O(n k^2) 2 x 2 products
// and no allocation: the monitor fits about 2 W of them per gyro and step.
using FitMatrix = Eigen::Matrix<double, Eigen::Dynamic, Eigen::Dynamic, 0, 6, 6>;
using FitVector = Eigen::Matrix<double, Eigen::Dynamic, 1, 0, 6, 1>;
struct Fit {
  FitVector beta;
  FitMatrix cov;
  double rss = std::numeric_limits<double>::infinity();
};

Fit WeightedFit(const ReadingFaultMonitor::Projected& p, const Regressors& regs,
                std::optional<size_t> count = std::nullopt) {
  const int k = regs.k;
  const auto& f = regs.f;
  FitMatrix N = FitMatrix::Zero(2 * k, 2 * k);
  FitVector r = FitVector::Zero(2 * k);
  double yWy = 0.0;
  const size_t points = count.value_or(p.y.size());
  for (size_t j = 0; j < points; ++j) {
    const Vector2d Wy = p.W[j] * p.y[j];
    yWy += p.y[j].dot(Wy);
    for (int m = 0; m < k; ++m) {
      r.segment<2>(2 * m) += f[j][m] * Wy;
      for (int l = 0; l <= m; ++l) N.block<2, 2>(2 * m, 2 * l) += (f[j][m] * f[j][l]) * p.W[j];
    }
  }
  for (int m = 0; m < k; ++m) {
    for (int l = m + 1; l < k; ++l) N.block<2, 2>(2 * m, 2 * l) = N.block<2, 2>(2 * l, 2 * m).transpose();
  }
  Fit out;
  Eigen::FullPivLU<FitMatrix> lu(N);
  if (lu.rank() < 2 * k) return out;  // regressors not independent over these points
  out.cov = lu.inverse();
  out.beta = out.cov * r;
  // Rounding can leave a tiny negative sum for a perfect fit.
  out.rss = std::max(yWy - r.dot(out.beta), 0.0);
  return out;
}

// Lower bound of min over |v| <= r of (c - v)^T S^-1 (c - v): the part of |c| beyond r along
// c's own direction, over the variance along it (any v in the ball leaves at least |c| - r
// along c, and x^T S^-1 x >= (u^T x)^2 / (u^T S u) for a unit u): a test never stronger than
// the exact one.
double BeyondBallChi2(const Vector2d& c, const Matrix2d& S, double r) {
  const double n = c.norm();
  if (!(n > r) || n == 0.0) return 0.0;
  const Vector2d u = c / n;
  const double var = u.dot(S * u);
  if (!(var > 0.0)) return std::numeric_limits<double>::infinity();
  return (n - r) * (n - r) / var;
}

}  // namespace

const char* ReadingVerdictName(ReadingVerdict v) {
  switch (v) {
    case ReadingVerdict::kNone:
      return "none";
    case ReadingVerdict::kJump:
      return "jump";
    case ReadingVerdict::kBeyond:
      return "beyond";
    case ReadingVerdict::kErratic:
      return "erratic";
  }
  return "?";
}

ReadingFaultMonitor::ReadingFaultMonitor(ReadingFaultOptions options) : options_(options) {
  const int max_points = options_.window_steps + 1;
  erratic_threshold_.assign(max_points + 1, 0.0);
  for (int n = 4; n <= max_points; ++n) {
    // 2 n components, 6 parameters of the quadratic. Significant, and far beyond the noise: a
    // scatter of options_.erratic_scale times the stated noise, its chi-square scale^2 per
    // degree of freedom (a drift's smooth curve that none of the fitted ones follows closely, as
    // in a slew, is significant long before that).
    const double dof = 2.0 * n - 6.0;
    erratic_threshold_[n] =
        std::max(ChiSquareQuantile(1.0 - options_.erratic_alpha, dof),
                 options_.erratic_scale * options_.erratic_scale * dof);
  }
}

void ReadingFaultMonitor::Clear() { tracks_.clear(); }

std::vector<ReadingFaultMonitor::Result> ReadingFaultMonitor::AddStep(
    absl::Time t, const std::vector<Sample>& samples) {
  std::map<int, Track> next;
  for (const Sample& s : samples) {
    const int key = Key(s.gyro_id, s.source);
    Track track;
    auto it = tracks_.find(key);
    // The increment needs the posterior of the previous measurement step.
    if (it != tracks_.end() && it->second.has_posterior && it->second.posterior_time == last_step_) {
      track = std::move(it->second);
    }
    Point p;
    p.time = t;
    p.noise_in = s.noise_in;
    p.drift_bound = s.drift_bound;
    p.turn = s.turn;
    p.turn_in = s.turn_in;
    p.turn_in_known = s.turn_in_known;
    if (track.points.empty() || !track.has_posterior || track.drivers_ref.size() != s.drivers.size() ||
        (s.drivers.size() > 0 && (s.motion_jacobian_in.rows() != 3 ||
                                  s.motion_jacobian_in.cols() != s.drivers.size()))) {
      p.x_in = s.prior_residual_in;
      track.points.clear();
      track.drivers_ref = s.drivers;
    } else {
      p.x_in = track.points.back().x_in + (s.prior_residual_in - track.posterior_in);
      if (s.drivers.size() > 0 && s.motion_jacobian_in.rows() == 3) {
        p.x_in += s.motion_jacobian_in * (s.drivers - track.drivers_ref);
      }
    }
    track.points.push_back(p);
    while (static_cast<int>(track.points.size()) > options_.window_steps + 1) {
      track.points.pop_front();
    }
    track.T = s.T;
    track.has_posterior = false;
    next[key] = std::move(track);
  }
  tracks_ = std::move(next);
  last_step_ = t;

  std::vector<Result> out;
  for (const auto& [key, track] : tracks_) {
    out.push_back(Saturated(Judge(key / 2, static_cast<Source>(key % 2), track)));
  }
  // The star tracker's rule: a verdict that another gyro shares at this step is nobody's.
  int st_verdicts = 0;
  for (const Result& r : out) {
    if (r.source == Source::kStarTracker && r.verdict != ReadingVerdict::kNone) ++st_verdicts;
  }
  if (st_verdicts > 1) {
    for (Result& r : out) {
      if (r.source == Source::kStarTracker) r.verdict = ReadingVerdict::kNone;
    }
  }
  return out;
}

void ReadingFaultMonitor::SetPosterior(int gyro_id, Source source,
                                       const Vector3d& posterior_residual_in) {
  auto it = tracks_.find(Key(gyro_id, source));
  if (it == tracks_.end() || it->second.points.empty() || it->second.points.back().time != last_step_) {
    return;
  }
  it->second.posterior_in = posterior_residual_in;
  it->second.has_posterior = true;
  it->second.posterior_time = last_step_;
}

ReadingFaultMonitor::Projected ReadingFaultMonitor::Project(const Track& track) {
  Projected p;
  const absl::Time last = track.points.back().time;
  // Relative to the last point (every model has an intercept): the track itself grows without
  // bound over a long flight, the residual sums should not lose digits to it.
  const Eigen::Vector3d origin = track.points.back().x_in;
  // A floor keeps the weight finite (0.01 arcsec): a configured noise of zero.
  static const double kFloorVariance = std::pow(0.01 * kRadPerArcsec, 2);
  for (const Point& q : track.points) {
    p.y.push_back(track.T.transpose() * (q.x_in - origin));
    Matrix2d cov = track.T.transpose() * q.noise_in * track.T;
    cov = 0.5 * (cov + cov.transpose()) + kFloorVariance * Matrix2d::Identity();
    p.cov.push_back(cov);
    p.W.push_back(cov.inverse());
    p.tau.push_back(absl::ToDoubleSeconds(q.time - last));
  }
  return p;
}

namespace {

// The smallest weighted residual sum of a family of fits, computed one fit at a time and only as
// far as a question needs: whether the family's minimum is small enough for a test is answered as
// soon as one fit makes the running minimum so (it only falls), and what has been fitted is kept
// for the next question. `fit(i)` gives member i's residual sum (a fit of rank too low:
// infinity). The running minimum folds as std::min does, in the members' order, so the full
// minimum is the same value, bit for bit, as a loop over all of them gives.
class LazyMinimum {
 public:
  LazyMinimum(int members, double start) : members_(members), minimum_(start) {}
  // Whether `holds` is true of min(start, members); fits members until it knows. `holds` must stay
  // true for any smaller minimum (a test that the minimum is at most something).
  template <typename Holds, typename Fit>
  bool Reaches(const Holds& holds, const Fit& fit) {
    while (!holds(minimum_) && next_ < members_) minimum_ = std::min(minimum_, fit(next_++));
    return holds(minimum_);
  }
  // min(start, every member).
  template <typename Fit>
  double All(const Fit& fit) {
    while (next_ < members_) minimum_ = std::min(minimum_, fit(next_++));
    return minimum_;
  }

 private:
  int members_;
  int next_ = 0;
  double minimum_;
};

}  // namespace

// One window's judgement (Judge), in its order: beyond any drift, a jump, erratic. The drift
// alternatives the jump and the erratic tests compare with are fitted when first needed, each
// once, and only as many as decide: a jump is declared only when every alternative fits worse
// than it by k_d^2, so the first alternative within k_d^2 of it ends the comparison (the verdict
// and, when a jump is declared, its statistic are what fitting all of them gives).
struct ReadingFaultMonitor::Judgement {
  const ReadingFaultOptions& options;
  const std::vector<double>& erratic_threshold;
  const Track& track;
  Projected p;
  int n = 0;
  Fit line;
  // The smooth curves a drift gives (Smooth): the quadratic, then a rate change at sample j = 1
  // .. n - 2; and the lines with a step within its allowance (SlewSteps), at j = 1 .. n - 1.
  std::optional<LazyMinimum> smooth;
  std::optional<LazyMinimum> slew;

  // kBeyond: the last increment against the rate of the points before it. `dt` > 0 is the last
  // interval.
  std::optional<Result> Beyond(double dt) const {
    Vector2d b = Vector2d::Zero();
    Matrix2d cov_b = Matrix2d::Zero();
    if (n >= 3) {
      // The line through every point but the last (its times still relative to the last).
      const Fit before_line = WeightedFit(p, Regressors(p, -1, std::nullopt, false), n - 1);
      if (std::isfinite(before_line.rss)) {
        b = before_line.beta.segment<2>(2);
        cov_b = before_line.cov.block<2, 2>(2, 2);
      }
    }
    const Vector2d c = ((p.y[n - 1] - p.y[n - 2]) - b * dt) / dt;
    const Matrix2d S = (p.cov[n - 1] + p.cov[n - 2]) / (dt * dt) + cov_b;
    const Point& last_point = track.points.back();
    const double bound = last_point.drift_bound + kSlowReadingErrorRad * last_point.turn / dt;
    const double chi2 = BeyondBallChi2(c, S, bound);
    if (!(chi2 >= options.decision_chi2)) return std::nullopt;
    Result r;
    r.verdict = ReadingVerdict::kBeyond;
    r.value = c.norm();
    r.threshold = bound;
    r.statistic = chi2;
    return r;
  }

  // Every drift alternative over the window: a steady change (quadratic) and a rate change at
  // any sample time. The best of them is the smooth curve a drift gives. They cost a fit per
  // sample and decide only when the line leaves something to explain (a jump that beats it, or
  // scatter about it beyond the noise; each alternative contains the line, so fits at least as
  // well): fitted then, and only as far as the question asked needs.
  LazyMinimum& Smooth() {
    if (!smooth.has_value()) {
      smooth.emplace(n - 2, WeightedFit(p, Regressors(p, -1, std::nullopt, true)).rss);
    }
    return *smooth;
  }
  double SmoothKink(int i) const {  // member i: the rate change at sample i + 1
    return WeightedFit(p, Regressors(p, -1, p.tau[i + 1], false)).rss;
  }

  // A slow reading error delta (kSlowReadingErrorRad: an unconfigured misalignment, a scale
  // error, the filter's own misalignment error) displaces a rebuild by (R delta) x h, R the
  // attitude: over an interval in which the reading turns by theta it moves the rebuild by at
  // most |delta| |R_j - R_(j-1)| <= |delta| min(theta, 2), at once during a fast slew (3.5 deg/s
  // turns a reading 3.6 rad between two measurement steps), and the displacement stays. So a
  // drift may come with a step at any point j of the window no larger than that allowance: the
  // best line with a step whose size is within its allowance (its part beyond the allowance
  // along its own direction below k_d^2, BeyondBallChi2) joins the drift alternatives. A step
  // beyond every allowance is left to the jump test (infinity: not an alternative).
  double SlewStep(const Projected& q, int j) const {
    const double allowance = kSlowReadingErrorRad * std::min(track.points[j].turn, 2.0);
    if (!(allowance > 0.0)) return std::numeric_limits<double>::infinity();
    const Fit step = WeightedFit(q, Regressors(q, j, std::nullopt, false));
    if (!std::isfinite(step.rss)) return std::numeric_limits<double>::infinity();
    if (BeyondBallChi2(step.beta.segment<2>(4), step.cov.block<2, 2>(4, 4), allowance) <
        options.decision_chi2) {
      return step.rss;
    }
    return std::numeric_limits<double>::infinity();
  }
  LazyMinimum SlewSteps() const {
    return LazyMinimum(n - 1, std::numeric_limits<double>::infinity());
  }

  // kJump: a jump at point jump_at (two or three points after it) against every drift
  // alternative, with the onset also inside the interval before the jump; at least two points
  // before it for the line. Declared when every alternative's residual sum exceeds the jump's
  // by k_d^2: the first one within it ends the comparison for that jump point.
  std::optional<Result> Jump() {
    const auto kink = [this](int i) { return SmoothKink(i); };
    const auto slew_step = [this](int i) { return SlewStep(p, i + 1); };
    for (int jump_at = n - 2; jump_at >= std::max(2, n - 3) && std::isfinite(line.rss); --jump_at) {
      const Fit jump = WeightedFit(p, Regressors(p, jump_at, std::nullopt, false));
      if (!std::isfinite(jump.rss)) continue;
      const double over_line = line.rss - jump.rss;
      if (!(over_line >= options.decision_chi2)) continue;
      // Not declared once an alternative is within k_d^2 of the jump: the minimum only falls,
      // and so does its difference from jump.rss (a NaN minimum is never within, and never
      // declared).
      const auto within = [&](double rss) { return rss - jump.rss < options.decision_chi2; };
      if (Smooth().Reaches(within, kink)) continue;
      double drift_rss = Smooth().All(kink);
      for (int m = 1; m <= 3 && !within(drift_rss); ++m) {
        const double onset = p.tau[jump_at - 1] + (p.tau[jump_at] - p.tau[jump_at - 1]) * m / 4.0;
        drift_rss = std::min(drift_rss, WeightedFit(p, Regressors(p, -1, onset, false)).rss);
      }
      if (within(drift_rss)) continue;
      if (!slew.has_value()) slew = SlewSteps();  // the same for both jump points
      if (slew->Reaches(within, slew_step)) continue;
      drift_rss = std::min(drift_rss, slew->All(slew_step));
      const double over_drift = drift_rss - jump.rss;
      if (over_drift >= options.decision_chi2) {
        Result r;
        r.verdict = ReadingVerdict::kJump;
        r.value = jump.beta.segment<2>(4).norm();
        r.threshold = options.decision_chi2;
        r.statistic = over_drift;
        return r;
      }
    }
    return std::nullopt;
  }

  // kErratic: scatter about the smooth curve, far beyond the noise. A drift change within the
  // window must not read as scatter.
  std::optional<Result> Erratic() {
    const double threshold = erratic_threshold[n];
    if (line.rss <= threshold) return std::nullopt;
    // Every smooth curve above the threshold (any at or below it, or NaN first: none).
    const auto kink = [this](int i) { return SmoothKink(i); };
    const auto at_most = [threshold](double rss) { return rss <= threshold; };
    if (Smooth().Reaches(at_most, kink)) return std::nullopt;
    const double smooth_rss = Smooth().All(kink);
    if (!std::isfinite(smooth_rss) || !(smooth_rss > threshold)) return std::nullopt;
    // A slow reading error (an unconfigured misalignment or scale error, kSlowReadingErrorRad
    // per radian of turn) moves a rebuild along the turn: smooth, but during a slew (the rate
    // rising, holding, falling) none of the fitted curves follows it. Its size over each interval
    // enters as a positional allowance of that point before readings are called erratic.
    Projected q = p;
    for (int j = 0; j < n; ++j) {
      const double a = kSlowReadingErrorRad * track.points[j].turn;
      q.cov[j] += a * a * Matrix2d::Identity();
      q.W[j] = q.cov[j].inverse();
    }
    // The smallest residual sum of the smooth curves and the lines with a step within its
    // allowance on q, fitted until one is at or below the threshold.
    double allowed = WeightedFit(q, Regressors(q, -1, std::nullopt, true)).rss;
    for (int j = 1; j <= n - 2 && allowed > threshold; ++j) {
      allowed = std::min(allowed, WeightedFit(q, Regressors(q, -1, q.tau[j], false)).rss);
    }
    LazyMinimum q_slew = SlewSteps();
    const auto slew_step = [this, &q](int i) { return SlewStep(q, i + 1); };
    if (allowed > threshold && !q_slew.Reaches(at_most, slew_step)) {
      allowed = std::min(allowed, q_slew.All(slew_step));
    } else {
      allowed = std::min(allowed, threshold);
    }
    if (!(allowed > threshold)) return std::nullopt;
    Result r;
    r.verdict = ReadingVerdict::kErratic;
    r.value = allowed;
    r.threshold = threshold;
    r.statistic = allowed;
    return r;
  }
};

ReadingFaultMonitor::Result ReadingFaultMonitor::Judge(int gyro_id, Source source,
                                                       const Track& track) const {
  Result none;
  none.gyro_id = gyro_id;
  none.source = source;
  const int n = static_cast<int>(track.points.size());
  if (n < 2) return none;
  Judgement j{options_, erratic_threshold_, track, Project(track), n};
  const double dt = j.p.tau[n - 1] - j.p.tau[n - 2];
  if (!(dt > 0.0)) return none;
  std::optional<Result> verdict = j.Beyond(dt);
  if (!verdict.has_value() && n >= 4) {
    j.line = WeightedFit(j.p, Regressors(j.p, -1, std::nullopt, false));
    verdict = j.Jump();
    if (!verdict.has_value()) verdict = j.Erratic();
  }
  if (!verdict.has_value()) return none;
  verdict->gyro_id = gyro_id;
  verdict->source = source;
  return *verdict;
}

std::optional<ReadingFaultMonitor::DriftChange> ReadingFaultMonitor::EstimateDriftChange(
    int gyro_id, Source source) const {
  auto it = tracks_.find(Key(gyro_id, source));
  if (it == tracks_.end()) return std::nullopt;
  const Track& track = it->second;
  const int n = static_cast<int>(track.points.size());
  if (n < 4) return std::nullopt;
  const Projected p = Project(track);
  // The window's own rate (the change began before the window) against a rate change at one
  // of its points or a quarter, a half or three quarters into an interval (an onset between two
  // samples: at the sample before it the change's slope would come out short); the rate change
  // when it fits better by chi2inv(0.99, 2).
  std::optional<DriftChange> best;
  auto make = [&](const Fit& f, double onset_tau, int first_after) {
    DriftChange d;
    const int at = onset_tau == -std::numeric_limits<double>::infinity() ? 2 : 4;
    d.c = f.beta.segment<2>(at);
    d.cov = f.cov.block<2, 2>(at, at);
    d.magnitude = d.c.norm();
    d.onset = track.points.back().time + absl::Seconds(std::max(onset_tau, p.tau[0]));
    for (int k = std::max(first_after, 1); k < n; ++k) {
      const double dt = p.tau[k] - p.tau[k - 1];
      d.bound = std::max(d.bound, track.points[k].drift_bound +
                                      (dt > 0.0 ? kSlowReadingErrorRad * track.points[k].turn / dt
                                                : 0.0));
    }
    d.beyond_chi2 = BeyondBallChi2(d.c, d.cov, d.bound);
    d.beyond = d.beyond_chi2 >= options_.decision_chi2;
    // Below: the bound exceeds |c| by three sigma along c (one-sided 0.13%).
    const double var = d.magnitude > 0.0 ? (d.c / d.magnitude).dot(d.cov * (d.c / d.magnitude))
                                         : d.cov.trace() / 2.0;
    d.below = d.bound - d.magnitude > 3.0 * std::sqrt(std::max(var, 0.0));
    // The turns on either side of the onset: an interval ending at or before it is before.
    double turn_before = 0.0, time_before = 0.0, turn_after = 0.0, time_after = 0.0;
    Vector3d turn_in_before = Vector3d::Zero(), turn_in_after = Vector3d::Zero();
    bool axes_known = true;
    for (int k = 1; k < n; ++k) {
      const double dt = p.tau[k] - p.tau[k - 1];
      if (!(dt > 0.0)) continue;
      const bool before = p.tau[k] <= onset_tau;
      (before ? turn_before : turn_after) += track.points[k].turn;
      (before ? turn_in_before : turn_in_after) += track.points[k].turn_in;
      (before ? time_before : time_after) += dt;
      axes_known = axes_known && track.points[k].turn_in_known;
    }
    d.turn_rate_after = time_after > 0.0 ? turn_after / time_after : 0.0;
    d.turn_rate_before = time_before > 0.0 ? turn_before / time_before : d.turn_rate_after;
    const Vector3d w_after_in = time_after > 0.0 ? Vector3d(turn_in_after / time_after) : Vector3d::Zero();
    const Vector3d w_before_in =
        time_before > 0.0 ? Vector3d(turn_in_before / time_before) : w_after_in;
    if (axes_known) {
      // The fitted rates on either side are weighted means of the intervals' rates, so their
      // change is at most the largest change between an interval before and one after.
      double largest = 0.0;
      for (int k = 1; k < n; ++k) {
        const double dtk = p.tau[k] - p.tau[k - 1];
        if (!(dtk > 0.0) || p.tau[k] > onset_tau) continue;
        for (int m = 1; m < n; ++m) {
          const double dtm = p.tau[m] - p.tau[m - 1];
          if (!(dtm > 0.0) || p.tau[m] <= onset_tau) continue;
          largest = std::max(largest,
                             (track.points[m].turn_in / dtm - track.points[k].turn_in / dtk).norm());
        }
      }
      d.slow_reading_change = kSlowReadingErrorRad * largest;
      const double sin_axes = w_before_in.cross(w_after_in).norm();
      d.turn_axis_change = w_before_in.norm() > 0.0 && w_after_in.norm() > 0.0
                               ? std::atan2(sin_axes, w_before_in.dot(w_after_in))
                               : 0.0;
    } else {
      d.slow_reading_change =
          kSlowReadingErrorRad * std::abs(d.turn_rate_after - d.turn_rate_before);
    }
    d.may_be_slow_reading_error =
        d.magnitude - 3.0 * std::sqrt(std::max(var, 0.0)) <= d.slow_reading_change;
    return d;
  };
  const Fit line = WeightedFit(p, Regressors(p, -1, std::nullopt, false));
  if (std::isfinite(line.rss)) best = make(line, -std::numeric_limits<double>::infinity(), 1);
  double best_rss = std::isfinite(line.rss) ? line.rss - 9.21 : std::numeric_limits<double>::infinity();
  for (int j = 1; j <= n - 2; ++j) {
    for (int q = 0; q < 4; ++q) {
      const double onset = p.tau[j] - (p.tau[j] - p.tau[j - 1]) * q / 4.0;
      const Fit drift = WeightedFit(p, Regressors(p, -1, onset, false));
      if (!std::isfinite(drift.rss) || drift.rss >= best_rss) continue;
      best_rss = drift.rss;
      best = make(drift, onset, j);
    }
  }
  return best;
}

std::optional<ReadingFaultMonitor::Misfit> ReadingFaultMonitor::ModelMisfit(
    int gyro_id, Source source, const Matrix2d& rate_cov) const {
  auto it = tracks_.find(Key(gyro_id, source));
  if (it == tracks_.end()) return std::nullopt;
  const Track& track = it->second;
  const int n = static_cast<int>(track.points.size());
  if (n < 4) return std::nullopt;
  const Projected p = Project(track);
  // Penalised least squares of y_j = a + b tau_j with the prior b ~ N(0, rate_cov): the normal
  // equations of (a, b) plus rate_cov^-1 on b's block; the minimum is y^T W y - r^T beta. A rate
  // covariance of zero (nothing free) pins b to 0.
  Eigen::Matrix4d N = Eigen::Matrix4d::Zero();
  Eigen::Vector4d r = Eigen::Vector4d::Zero();
  double yWy = 0.0;
  for (int j = 0; j < n; ++j) {
    const Vector2d Wy = p.W[j] * p.y[j];
    yWy += p.y[j].dot(Wy);
    r.head<2>() += Wy;
    r.tail<2>() += p.tau[j] * Wy;
    N.topLeftCorner<2, 2>() += p.W[j];
    N.topRightCorner<2, 2>() += p.tau[j] * p.W[j];
    N.bottomRightCorner<2, 2>() += p.tau[j] * p.tau[j] * p.W[j];
  }
  N.bottomLeftCorner<2, 2>() = N.topRightCorner<2, 2>().transpose();
  Misfit m;
  m.samples = n;
  m.dof = 2 * (n - 1);
  const Matrix2d Q = 0.5 * (rate_cov + rate_cov.transpose());
  const Eigen::LDLT<Matrix2d> q(Q);
  if (q.info() == Eigen::Success && q.isPositive() && Q.determinant() > 0.0) {
    N.bottomRightCorner<2, 2>() += Q.inverse();
    const Eigen::LDLT<Eigen::Matrix4d> solve(N);
    m.chi2 = std::max(yWy - r.dot(solve.solve(r)), 0.0);
  } else {
    const Eigen::LDLT<Matrix2d> solve(N.topLeftCorner<2, 2>());
    m.chi2 = std::max(yWy - r.head<2>().dot(solve.solve(r.head<2>())), 0.0);
  }
  return m;
}

// State: last_step (3: flag, unix seconds, nanoseconds), the track count, then per track: key,
// has_posterior, posterior_in (3), posterior_time (3), T (6, column by column), the count of
// drivers_ref and its values, point count,
// then per point: time (3), x_in (3), noise_in (9, row by row), drift_bound, turn.
namespace {
void PutTime(std::vector<double>& v, absl::Time t) {
  if (t == absl::InfinitePast()) {
    v.insert(v.end(), {-1.0, 0.0, 0.0});
    return;
  }
  // Seconds and nanoseconds apart: a time far from 1970 does not fit int64 nanoseconds.
  const int64_t s = absl::ToUnixSeconds(t);
  v.push_back(1.0);
  v.push_back(static_cast<double>(s));
  v.push_back(static_cast<double>(absl::ToInt64Nanoseconds(t - absl::FromUnixSeconds(s))));
}
}  // namespace

std::vector<double> ReadingFaultMonitor::ExportState() const {
  std::vector<double> v;
  PutTime(v, last_step_);
  v.push_back(static_cast<double>(tracks_.size()));
  for (const auto& [key, t] : tracks_) {
    v.push_back(key);
    v.push_back(t.has_posterior ? 1.0 : 0.0);
    for (int i = 0; i < 3; ++i) v.push_back(t.posterior_in(i));
    PutTime(v, t.posterior_time);
    for (int c = 0; c < 2; ++c) {
      for (int i = 0; i < 3; ++i) v.push_back(t.T(i, c));
    }
    v.push_back(static_cast<double>(t.drivers_ref.size()));
    for (int i = 0; i < t.drivers_ref.size(); ++i) v.push_back(t.drivers_ref(i));
    v.push_back(static_cast<double>(t.points.size()));
    for (const Point& p : t.points) {
      PutTime(v, p.time);
      for (int i = 0; i < 3; ++i) v.push_back(p.x_in(i));
      for (int i = 0; i < 3; ++i) {
        for (int j = 0; j < 3; ++j) v.push_back(p.noise_in(i, j));
      }
      v.push_back(p.drift_bound);
      v.push_back(p.turn);
    }
  }
  return v;
}

absl::Status ReadingFaultMonitor::RestoreState(absl::Span<const double> state) {
  size_t pos = 0;
  auto fail = [](const std::string& what) {
    return absl::DataLossError(absl::StrCat("reading fault monitor: ", what));
  };
  auto take = [&](double& out) {
    if (pos >= state.size()) return false;
    out = state[pos++];
    return true;
  };
  auto take_time = [&](absl::Time& t) -> absl::Status {
    double flag, s, ns;
    if (!take(flag) || !take(s) || !take(ns)) return fail("state truncated");
    if (flag == -1.0 && s == 0.0 && ns == 0.0) {
      t = absl::InfinitePast();
      return absl::OkStatus();
    }
    if (flag != 1.0 || !(std::abs(s) <= 1e12) || s != std::floor(s) || !(ns >= 0.0 && ns < 1e9) ||
        ns != std::floor(ns)) {
      return fail(absl::StrFormat("time (%g, %g, %g) is not one", flag, s, ns));
    }
    t = absl::FromUnixSeconds(static_cast<int64_t>(s)) + absl::Nanoseconds(static_cast<int64_t>(ns));
    return absl::OkStatus();
  };
  auto take_finite = [&](double& out, const char* field) -> absl::Status {
    if (!take(out)) return fail("state truncated");
    if (!std::isfinite(out)) return fail(absl::StrFormat("%s %g is not finite", field, out));
    return absl::OkStatus();
  };
  auto take_count = [&](int& out, int max, const char* field) -> absl::Status {
    double c;
    if (!take(c)) return fail("state truncated");
    if (!(c >= 0.0 && c <= max && c == std::floor(c))) {
      return fail(absl::StrFormat("%s %g outside [0, %d]", field, c, max));
    }
    out = static_cast<int>(c);
    return absl::OkStatus();
  };
  absl::Time last_step;
  if (absl::Status s = take_time(last_step); !s.ok()) return s;
  int count = 0;
  if (absl::Status s = take_count(count, 16, "track count"); !s.ok()) return s;
  std::map<int, Track> tracks;
  for (int k = 0; k < count; ++k) {
    int key = 0;
    if (absl::Status s = take_count(key, 2 * 1000 + 1, "track key"); !s.ok()) return s;
    Track t;
    double flag;
    if (!take(flag)) return fail("state truncated");
    if (flag != 0.0 && flag != 1.0) return fail(absl::StrFormat("posterior flag %g is not 0 or 1", flag));
    t.has_posterior = flag == 1.0;
    for (int i = 0; i < 3; ++i) {
      if (absl::Status s = take_finite(t.posterior_in(i), "posterior"); !s.ok()) return s;
    }
    if (absl::Status s = take_time(t.posterior_time); !s.ok()) return s;
    for (int c = 0; c < 2; ++c) {
      for (int i = 0; i < 3; ++i) {
        if (absl::Status s = take_finite(t.T(i, c), "tangent basis"); !s.ok()) return s;
      }
    }
    int drivers = 0;
    if (absl::Status s = take_count(drivers, 64, "driver count"); !s.ok()) return s;
    t.drivers_ref = Eigen::VectorXd::Zero(drivers);
    for (int i = 0; i < drivers; ++i) {
      if (absl::Status s = take_finite(t.drivers_ref(i), "driver"); !s.ok()) return s;
    }
    int points = 0;
    if (absl::Status s = take_count(points, options_.window_steps + 1, "point count"); !s.ok()) {
      return s;
    }
    for (int j = 0; j < points; ++j) {
      Point p;
      if (absl::Status s = take_time(p.time); !s.ok()) return s;
      for (int i = 0; i < 3; ++i) {
        if (absl::Status s = take_finite(p.x_in(i), "track"); !s.ok()) return s;
      }
      for (int i = 0; i < 3; ++i) {
        for (int m = 0; m < 3; ++m) {
          if (absl::Status s = take_finite(p.noise_in(i, m), "noise"); !s.ok()) return s;
        }
      }
      if (absl::Status s = take_finite(p.drift_bound, "drift bound"); !s.ok()) return s;
      if (absl::Status s = take_finite(p.turn, "turn"); !s.ok()) return s;
      t.points.push_back(p);
    }
    tracks[key] = std::move(t);
  }
  if (pos != state.size()) return fail("state oversized");
  tracks_ = std::move(tracks);
  last_step_ = last_step;
  return absl::OkStatus();
}

std::vector<double> ReadingFaultMonitor::ExportTurnAxes() const {
  std::vector<double> v;
  for (const auto& [key, t] : tracks_) {
    for (const Point& p : t.points) {
      for (int i = 0; i < 3; ++i) v.push_back(p.turn_in(i));
      v.push_back(p.turn_in_known ? 1.0 : 0.0);
    }
  }
  return v;
}

absl::Status ReadingFaultMonitor::RestoreTurnAxes(absl::Span<const double> state) {
  size_t points = 0;
  for (const auto& [key, t] : tracks_) points += t.points.size();
  if (state.size() != 4 * points) {
    return absl::DataLossError(absl::StrFormat(
        "reading fault monitor: %d turn values for %d points (4 each)", state.size(), points));
  }
  // Checked whole before any point changes.
  for (size_t k = 0; k < points; ++k) {
    for (int i = 0; i < 3; ++i) {
      if (!std::isfinite(state[4 * k + i]) || std::abs(state[4 * k + i]) > 1e6) {
        return absl::DataLossError(absl::StrFormat(
            "reading fault monitor: turn axis %g is not a finite rotation", state[4 * k + i]));
      }
    }
    if (state[4 * k + 3] != 0.0 && state[4 * k + 3] != 1.0) {
      return absl::DataLossError(absl::StrFormat(
          "reading fault monitor: turn axis flag %g is not 0 or 1", state[4 * k + 3]));
    }
  }
  size_t k = 0;
  for (auto& [key, t] : tracks_) {
    for (Point& p : t.points) {
      p.turn_in = Vector3d(state[4 * k], state[4 * k + 1], state[4 * k + 2]);
      p.turn_in_known = state[4 * k + 3] == 1.0;
      ++k;
    }
  }
  return absl::OkStatus();
}

}  // namespace esg::estimator
