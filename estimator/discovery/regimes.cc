#include "estimator/discovery/regimes.h"

#include <algorithm>
#include <cmath>
#include <optional>

#include "estimator/rotation.h"
#include "estimator/triad.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;

namespace {

// Body vectors of the spin axes of every gyro present in the frame (C_b_k h_k), by gyro index.
std::array<std::optional<Vector3d>, kMaxGyros> BodySpinAxes(const SpacecraftConfig& config,
                                                            const TelemetryFrame& frame) {
  std::array<std::optional<Vector3d>, kMaxGyros> v;
  for (const GyroConfig& g : config.gyros) {
    const auto& r = frame.gyros[g.id - 1];
    if (r.has_value() && r->h_k.allFinite() && r->h_k.norm() > 0.5) {
      v[g.id - 1] = (g.C_b_k * r->h_k.normalized()).eval();
    }
  }
  return v;
}

// Rotation vector of q_b1_b2 (body at frame a to body at frame b) from two inertially fixed spin
// axes seen in both frames: v(a) = C_b1_b2 v(b). nullopt without two well separated gyros.
// `without` (a gyro index, or -1) is left out of the pair.
std::optional<Vector3d> GyroStepRotation(const std::array<std::optional<Vector3d>, kMaxGyros>& a,
                                         const std::array<std::optional<Vector3d>, kMaxGyros>& b,
                                         int without = -1) {
  int best_i = -1, best_j = -1;
  double best = 0.1;  // sin of the angle between the axes, at least ~6 deg
  for (int i = 0; i < kMaxGyros; ++i) {
    for (int j = i + 1; j < kMaxGyros; ++j) {
      if (i == without || j == without) continue;
      if (!a[i] || !a[j] || !b[i] || !b[j]) continue;
      const double s = a[i]->cross(*a[j]).norm();
      if (s > best) {
        best = s;
        best_i = i;
        best_j = j;
      }
    }
  }
  if (best_i < 0) return std::nullopt;
  // PairAttitude(u_a, u_b, w_a, w_b) returns q with u = C w; here u = v(a), w = v(b).
  auto q = PairAttitude(*a[best_i], *a[best_j], *b[best_i], *b[best_j]);
  if (!q.ok()) return std::nullopt;
  return LogQuaternion(*q);
}

std::optional<Quaterniond> ValidStarTracker(const TelemetryFrame& f) {
  if (!f.star_tracker.has_value() || !f.star_tracker->valid) return std::nullopt;
  const Quaterniond& q = f.star_tracker->q_in_b;
  if (!q.coeffs().allFinite() || q.norm() < 0.5) return std::nullopt;
  return q.normalized();
}

// Central rate per frame from per-step rotation vectors (step i: frame i -> i+1).
void CentralRates(const std::vector<std::optional<Vector3d>>& step_rotation,
                  const std::vector<TelemetryFrame>& frames, std::vector<Vector3d>& rate,
                  std::vector<bool>& valid) {
  const size_t n = frames.size();
  rate.assign(n, Vector3d::Zero());
  valid.assign(n, false);
  std::vector<std::optional<Vector3d>> step_rate(step_rotation.size());
  for (size_t i = 0; i < step_rotation.size(); ++i) {
    if (!step_rotation[i]) continue;
    const double dt = absl::ToDoubleSeconds(frames[i + 1].time - frames[i].time);
    if (dt > 0) step_rate[i] = (*step_rotation[i] / dt).eval();
  }
  for (size_t i = 0; i < n; ++i) {
    const std::optional<Vector3d>* before = i > 0 ? &step_rate[i - 1] : nullptr;
    const std::optional<Vector3d>* after = i + 1 < n ? &step_rate[i] : nullptr;
    const bool b = before && before->has_value();
    const bool a = after && after->has_value();
    if (a && b) {
      rate[i] = 0.5 * (**before + **after);
    } else if (a) {
      rate[i] = **after;
    } else if (b) {
      rate[i] = **before;
    } else {
      continue;
    }
    valid[i] = true;
  }
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  const size_t mid = v.size() / 2;
  std::nth_element(v.begin(), v.begin() + mid, v.end());
  return v[mid];
}

}  // namespace

const char* RegimeName(Regime r) {
  switch (r) {
    case Regime::kInertialHold:
      return "inertial_hold";
    case Regime::kOrbital:
      return "orbital";
    case Regime::kRotation:
      return "rotation";
    case Regime::kSlew:
      return "slew";
  }
  return "?";
}

BodyRates MeasureBodyRates(const SpacecraftConfig& config,
                           const std::vector<TelemetryFrame>& frames) {
  BodyRates out;
  const size_t n = frames.size();
  std::vector<std::optional<Vector3d>> gyro_steps(n > 0 ? n - 1 : 0), st_steps(n > 0 ? n - 1 : 0);
  std::array<std::optional<Vector3d>, kMaxGyros> prev_axes;
  std::optional<Quaterniond> prev_q;
  out.gyro_step_without.assign(n > 0 ? n - 1 : 0, {});
  for (size_t i = 0; i < n; ++i) {
    const auto axes = BodySpinAxes(config, frames[i]);
    const auto q = ValidStarTracker(frames[i]);
    if (i > 0) {
      gyro_steps[i - 1] = GyroStepRotation(prev_axes, axes);
      for (int k = 0; k < kMaxGyros; ++k) {
        out.gyro_step_without[i - 1][k] = GyroStepRotation(prev_axes, axes, k);
      }
      if (q && prev_q) st_steps[i - 1] = LogQuaternion(prev_q->conjugate() * *q);
    }
    prev_axes = axes;
    prev_q = q;
  }
  CentralRates(gyro_steps, frames, out.gyro, out.gyro_valid);
  out.gyro_step.assign(gyro_steps.size(), Vector3d::Zero());
  out.gyro_step_valid.assign(gyro_steps.size(), false);
  for (size_t i = 0; i < gyro_steps.size(); ++i) {
    if (gyro_steps[i]) {
      out.gyro_step[i] = *gyro_steps[i];
      out.gyro_step_valid[i] = true;
    }
  }
  CentralRates(st_steps, frames, out.star_tracker, out.star_tracker_valid);
  out.best.assign(n, Vector3d::Zero());
  for (size_t i = 0; i < n; ++i) {
    if (out.gyro_valid[i]) {
      out.best[i] = out.gyro[i];
    } else if (out.star_tracker_valid[i]) {
      out.best[i] = out.star_tracker[i];
    }
  }
  return out;
}

namespace {

// Each frame's regime by the window centred on it, with the window's median rate [rad/s] and its
// mean rotation axis (body axes; zero where unknown).
struct FrameClasses {
  std::vector<Regime> label;
  std::vector<double> rate_of;
  std::vector<Vector3d> axis_of;
};

// Rate per frame: star tracker where available, else gyros (docs/discovery.md, "Locate").
std::vector<std::optional<Vector3d>> FrameRates(const BodyRates& rates, int n) {
  std::vector<std::optional<Vector3d>> w(n);
  for (int i = 0; i < n; ++i) {
    if (rates.star_tracker_valid[i]) {
      w[i] = rates.star_tracker[i];
    } else if (rates.gyro_valid[i]) {
      w[i] = rates.gyro[i];
    }
  }
  return w;
}

// Frame i's class from the rates of its window [lo, hi]: a slew (unknown) with fewer than three
// rates, an inertial hold below hold_rate, a slew when the rate is not steady in magnitude or
// axis, else an orbital orientation or a rotation by its period.
void ClassifyFrame(const std::vector<std::optional<Vector3d>>& w, int lo, int hi, int i,
                   const RegimeOptions& options, FrameClasses& c) {
  std::vector<double> mags;
  std::vector<Vector3d> vecs;
  for (int j = lo; j <= hi; ++j) {
    if (!w[j]) continue;
    mags.push_back(w[j]->norm());
    vecs.push_back(*w[j]);
  }
  if (mags.size() < 3) return;  // no rate: slew (unknown) until neighbours decide
  const double med = Median(mags);
  c.rate_of[i] = med;
  if (med < options.hold_rate) {
    c.label[i] = Regime::kInertialHold;
    return;
  }
  // Robust steadiness: the central 80% of magnitudes within +-steady_magnitude of the median,
  // and the mean resultant of the unit axes (outlier steps excluded by magnitude).
  std::vector<double> dev;
  Vector3d resultant = Vector3d::Zero();
  int used = 0;
  for (size_t k = 0; k < mags.size(); ++k) {
    dev.push_back(std::abs(mags[k] - med) / med);
    if (std::abs(mags[k] - med) <= 0.5 * med) {
      resultant += vecs[k] / mags[k];
      ++used;
    }
  }
  std::sort(dev.begin(), dev.end());
  const double spread = dev[static_cast<size_t>(0.8 * (dev.size() - 1))];
  const double steadiness = used > 0 ? resultant.norm() / used : 0.0;
  c.axis_of[i] = used > 0 ? resultant.normalized() : Vector3d::Zero();
  if (spread > options.steady_magnitude || steadiness < options.steady_axis) {
    c.label[i] = Regime::kSlew;
    return;
  }
  const double period = 2.0 * kPi / med;
  c.label[i] = (period >= options.orbital_period_min && period <= options.orbital_period_max)
                   ? Regime::kOrbital
                   : Regime::kRotation;
}

// Classify each frame by the window centred on it (two pointers over time).
FrameClasses ClassifyFrames(const std::vector<TelemetryFrame>& frames,
                            const std::vector<std::optional<Vector3d>>& w,
                            const RegimeOptions& options) {
  const int n = static_cast<int>(frames.size());
  FrameClasses c;
  c.label.assign(n, Regime::kSlew);
  c.rate_of.assign(n, 0.0);
  c.axis_of.assign(n, Vector3d::Zero());
  const absl::Duration half = absl::Seconds(options.window / 2.0);
  int lo = 0, hi = 0;
  for (int i = 0; i < n; ++i) {
    while (frames[lo].time < frames[i].time - half) ++lo;
    while (hi + 1 < n && frames[hi + 1].time <= frames[i].time + half) ++hi;
    ClassifyFrame(w, lo, hi, i, options, c);
  }
  return c;
}

// A run of frames of one regime, [first, last].
struct Run {
  Regime regime;
  int first, last;
};

// Run-length runs of the frames' labels.
std::vector<Run> RunsOf(const std::vector<Regime>& label) {
  std::vector<Run> runs;
  for (int i = 0; i < static_cast<int>(label.size()); ++i) {
    if (runs.empty() || runs.back().regime != label[i]) {
      runs.push_back({label[i], i, i});
    } else {
      runs.back().last = i;
    }
  }
  return runs;
}

// Fold short runs (shorter than min_span): between two runs of one regime into that regime (unless
// the rotation axis changed across it: a slew between two rotations about different body axes),
// otherwise into a slew; neighbours of one regime merged; until nothing moves.
void FoldShortRuns(const std::vector<TelemetryFrame>& frames,
                   const std::vector<Vector3d>& axis_of, const RegimeOptions& options,
                   std::vector<Run>& runs) {
  const int n = static_cast<int>(frames.size());
  auto duration = [&](const Run& r) {
    return absl::ToDoubleSeconds(frames[r.last].time - frames[r.first].time) +
           (r.last + 1 < n ? absl::ToDoubleSeconds(frames[r.last + 1].time - frames[r.last].time)
                           : 0.0);
  };
  auto run_axis = [&](const Run& r) {
    Vector3d a = Vector3d::Zero();
    for (int i = r.first; i <= r.last; ++i) a += axis_of[i];
    return a.norm() > 0 ? a.normalized() : a;
  };
  bool changed = true;
  while (changed && runs.size() > 1) {
    changed = false;
    for (size_t k = 0; k < runs.size(); ++k) {
      if (duration(runs[k]) >= options.min_span) continue;
      const bool has_prev = k > 0, has_next = k + 1 < runs.size();
      Regime to = Regime::kSlew;
      if (has_prev && has_next && runs[k - 1].regime == runs[k + 1].regime &&
          (runs[k - 1].regime == Regime::kInertialHold ||
           run_axis(runs[k - 1]).dot(run_axis(runs[k + 1])) > std::cos(options.max_axis_change))) {
        to = runs[k - 1].regime;
      }
      if (runs[k].regime != to) {
        runs[k].regime = to;
        changed = true;
      }
    }
    // Merge neighbours of one regime.
    std::vector<Run> merged;
    for (const Run& r : runs) {
      if (!merged.empty() && merged.back().regime == r.regime) {
        merged.back().last = r.last;
      } else {
        merged.push_back(r);
      }
    }
    if (merged.size() != runs.size()) changed = true;
    runs = std::move(merged);
    // A short run that stayed a slew next to slews is merged above; stop when nothing moves.
    bool any_short_non_slew = false;
    for (const Run& r : runs) {
      if (duration(r) < options.min_span && r.regime != Regime::kSlew) any_short_non_slew = true;
    }
    if (!any_short_non_slew) break;
  }
}

// A run as a span: its times, median rate and mean axis (none for an inertial hold).
RegimeSpan SpanOf(const Run& r, const std::vector<TelemetryFrame>& frames, const FrameClasses& c) {
  RegimeSpan s;
  s.regime = r.regime;
  s.first_frame = r.first;
  s.last_frame = r.last;
  s.start = frames[r.first].time;
  s.end = frames[r.last].time;
  std::vector<double> mags;
  Vector3d axis = Vector3d::Zero();
  for (int i = r.first; i <= r.last; ++i) {
    if (c.rate_of[i] > 0) mags.push_back(c.rate_of[i]);
    axis += c.axis_of[i];
  }
  s.mean_rate = Median(mags);
  if (s.regime != Regime::kInertialHold && axis.norm() > 0) s.axis_b = axis.normalized();
  return s;
}

}  // namespace

std::vector<RegimeSpan> FindRegimes(const std::vector<TelemetryFrame>& frames,
                                    const BodyRates& rates, const RegimeOptions& options) {
  std::vector<RegimeSpan> spans;
  const int n = static_cast<int>(frames.size());
  if (n == 0) return spans;
  const FrameClasses c = ClassifyFrames(frames, FrameRates(rates, n), options);
  std::vector<Run> runs = RunsOf(c.label);
  FoldShortRuns(frames, c.axis_of, options, runs);
  for (const Run& r : runs) spans.push_back(SpanOf(r, frames, c));
  return spans;
}

int SpanOfFrame(const std::vector<RegimeSpan>& spans, int frame) {
  for (size_t k = 0; k < spans.size(); ++k) {
    if (frame >= spans[k].first_frame && frame <= spans[k].last_frame) return static_cast<int>(k);
  }
  return -1;
}

}  // namespace esg::estimator::discovery
