#include "estimator/discovery/open_ended.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <tuple>
#include <array>
#include <limits>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/discovery/deviation_filter.h"
#include "estimator/discovery/statistics.h"

namespace esg::estimator::discovery {

using Eigen::Matrix3d;
using Eigen::Vector2d;
using Eigen::Vector3d;
using Eigen::VectorXd;

namespace {

// A regressor whose RMS over the recording is below this is absent (a body rate of 0.02 arcsec/s
// in an inertial hold; a voltage column without voltages).
constexpr double kAbsentRms = 1e-7;

// Walk intensities the residual-drift smoother chooses from by likelihood
// [deg/h/sqrt(h)]: 1e-4 .. 1e-1 in half decades.
constexpr std::array<double, 7> kSmoothingIntensities = {1e-4, 3e-4, 1e-3, 3e-3,
                                                         1e-2, 3e-2, 1e-1};

struct GyroData {
  const DeviationSeries* series = nullptr;
  double random_walk = 0.0;
  double w0_sigma = 0.0;
  VectorXd y_w;
  std::vector<BasisColumn> columns;
  std::vector<std::vector<Vector2d>> signature;  // raw, per column
  std::vector<VectorXd> x_w;                     // whitened, per column
  VectorXd prior;                                // per column
  std::vector<int> active;                       // selected columns
  RegressionFit fit;
};

RegressionFit Fit(const GyroData& g, const std::vector<int>& cols) {
  std::vector<const VectorXd*> X;
  VectorXd prior(cols.size());
  for (size_t i = 0; i < cols.size(); ++i) {
    X.push_back(&g.x_w[cols[i]]);
    prior(i) = g.prior(cols[i]);
  }
  return FitRegression(g.y_w, X, prior);
}

double ScalarRms(const DeviationSeries& s, const BasisColumn& c) {
  double sum = 0.0, time = 0.0;
  for (const TrajectoryStep& st : s.steps) {
    const double v = BasisScalar(c.term, st.inputs);
    sum += v * v * st.dt;
    time += st.dt;
  }
  return time > 0.0 ? std::sqrt(sum / time) : 0.0;
}

std::vector<Vector2d> ColumnSignature(const DeviationSeries& s, const BasisColumn& c) {
  if (c.readout) {
    Matrix3d E = Matrix3d::Zero();
    E(c.row, c.col) = 1.0;
    E(c.col, c.row) = 1.0;
    return ReadoutSignature(s, E);
  }
  const BasisTerm term = c.term;
  return Signature(s, [&term](const BasisInputs& in) { return BasisRegressor_k(term, in); });
}

// The smoothed drift of z in case axes at each sample [rad/s], the walk intensity chosen by
// likelihood among kSmoothingIntensities.
void SmoothInCaseAxes(const DeviationSeries& s, double w0_sigma,
                      const std::vector<Vector2d>& z_before,
                      const std::vector<Vector2d>& z_after, ResidualDrift& out) {
  double best = std::numeric_limits<double>::infinity(), q_best = 0.0;
  for (double q_deg : kSmoothingIntensities) {
    const double q = DegPerHourSqrtHourToSi(q_deg);
    const DeviationFilter f(s, q, w0_sigma);
    const VectorXd e = f.Whiten(z_after);
    const double m = static_cast<double>(e.size());
    const double d = f.log_det() + m * std::log(e.squaredNorm() / m);  // dispersion profiled
    if (d < best) {
      best = d;
      q_best = q;
    }
  }
  out.smoothing_intensity = q_best;
  const DeviationFilter f(s, q_best, w0_sigma);
  std::vector<Vector2d> w_before, w_after, sd_before, sd_after;
  f.SmoothDrift(z_before, w_before, sd_before);
  f.SmoothDrift(z_after, w_after, sd_after);
  out.gyro = s.gyro;
  out.hours = s.hours;
  for (size_t k = 0; k < s.y.size(); ++k) {
    const Vector3d W_before = s.u1 * w_before[k](0) + s.u2 * w_before[k](1);
    const Vector3d W_after = s.u1 * w_after[k](0) + s.u2 * w_after[k](1);
    out.before_k.push_back(s.C_k_in[k] * W_before);
    out.after_k.push_back(s.C_k_in[k] * W_after);
    out.sigma.push_back(std::sqrt(0.5 * sd_after[k].squaredNorm()));
  }
}

std::string Vec(const Vector3d& v, double scale, const char* fmt = "%.4f") {
  return absl::StrCat("(", absl::StrFormat(fmt, v(0) * scale), ", ",
                      absl::StrFormat(fmt, v(1) * scale), ", ", absl::StrFormat(fmt, v(2) * scale),
                      ")");
}

}  // namespace

std::vector<BasisColumn> EnumerateBasis(const DeviationSeries& series,
                                        const OpenEndedOptions& options) {
  std::vector<BasisColumn> out;
  auto add = [&](BasisTerm t) {
    for (int m = 1; m <= 3; ++m) {
      t.axis = m;
      BasisColumn c;
      c.term = t;
      c.label = BasisTermLabel(t);
      if (ScalarRms(series, c) > kAbsentRms) out.push_back(c);
    }
  };
  BasisTerm t;
  t.epoch = options.epoch;
  t.kind = BasisKind::kSpinAxisHarmonic;
  for (int c = 0; c <= 1; ++c) {
    for (int degree = 0; degree + c <= kMaxHarmonicDegree; ++degree) {
      for (int a = degree; a >= 0; --a) {
        t.exponents = {a, degree - a, c};
        add(t);
      }
    }
  }
  t.kind = BasisKind::kBodyRate;
  for (int i = 1; i <= 3; ++i) {
    t.index = {i, i};
    add(t);
  }
  t.kind = BasisKind::kBodyRateProduct;
  for (int i = 1; i <= 3; ++i) {
    for (int j = i; j <= 3; ++j) {
      t.index = {i, j};
      add(t);
    }
  }
  if (options.orbital_period_s > 0.0) {
    t.kind = BasisKind::kOrbitalHarmonic;
    t.period = options.orbital_period_s;
    for (int n = 1; n <= 2; ++n) {
      for (bool sine : {false, true}) {
        t.harmonic = n;
        t.sine = sine;
        add(t);
      }
    }
  }
  t.kind = BasisKind::kRamp;
  add(t);
  t.kind = BasisKind::kRampHarmonic;
  for (int m = 1; m <= 3; ++m) {
    t.index = {m, m};
    t.axis = m;
    BasisColumn c;
    c.term = t;
    c.label = BasisTermLabel(t);
    if (ScalarRms(series, c) > kAbsentRms) out.push_back(c);
  }
  t.kind = BasisKind::kSuspensionVoltage;
  for (int i = 1; i <= 3; ++i) {
    t.index = {i, i};
    add(t);
  }
  static constexpr std::array<std::pair<int, int>, 6> kEntries = {
      {{0, 0}, {1, 1}, {2, 2}, {0, 1}, {1, 2}, {2, 0}}};
  for (const auto& [r, c] : kEntries) {
    BasisColumn col;
    col.readout = true;
    col.row = r;
    col.col = c;
    col.label = absl::StrCat("readout E_", std::string(1, "xyz"[r]), std::string(1, "xyz"[c]));
    out.push_back(col);
  }
  return out;
}

OpenEndedResult RunOpenEnded(const std::vector<DeviationSeries>& series,
                             const std::vector<double>& random_walk,
                             const std::vector<double>& w0_sigma,
                             const OpenEndedOptions& options) {
  OpenEndedResult result;
  std::vector<GyroData> gyros(series.size());
  for (size_t g = 0; g < series.size(); ++g) {
    GyroData& d = gyros[g];
    d.series = &series[g];
    d.random_walk = g < random_walk.size() ? random_walk[g] : 0.0;
    d.w0_sigma = g < w0_sigma.size() ? w0_sigma[g] : 0.0;
    const DeviationFilter filter(series[g], d.random_walk, d.w0_sigma);
    d.y_w = filter.Whiten(series[g].y);
    d.columns = EnumerateBasis(series[g], options);
    d.prior.resize(d.columns.size());
    for (size_t c = 0; c < d.columns.size(); ++c) {
      d.signature.push_back(ColumnSignature(series[g], d.columns[c]));
      d.x_w.push_back(filter.Whiten(d.signature.back()));
      d.prior(c) = d.columns[c].readout ? options.readout_sigma
                                        : options.drift_sigma / ScalarRms(series[g], d.columns[c]);
    }
    d.fit = Fit(d, {});
    result.deviance_before += d.fit.deviance;
  }
  for (int round = 0; round < options.max_terms; ++round) {
    int M = 0, best_g = -1, best_c = -1;
    double best = -std::numeric_limits<double>::infinity();
    RegressionFit best_fit;
    for (size_t g = 0; g < gyros.size(); ++g) {
      GyroData& d = gyros[g];
      for (size_t c = 0; c < d.columns.size(); ++c) {
        if (std::find(d.active.begin(), d.active.end(), static_cast<int>(c)) != d.active.end()) {
          continue;
        }
        ++M;
        std::vector<int> cols = d.active;
        cols.push_back(static_cast<int>(c));
        RegressionFit f = Fit(d, cols);
        const double evidence = d.fit.deviance - f.deviance;
        if (evidence > best) {
          best = evidence;
          best_g = static_cast<int>(g);
          best_c = static_cast<int>(c);
          best_fit = std::move(f);
        }
      }
    }
    if (round == 0) result.columns_tested = M;
    if (best_g < 0) break;
    const double threshold = EvidenceThreshold(options.alpha, M);
    GyroData& d = gyros[best_g];
    result.best_gyro = d.series->gyro;
    result.best_label = d.columns[best_c].label;
    result.best_evidence = best;
    result.best_threshold = threshold;
    if (!(best > threshold)) break;
    d.active.push_back(best_c);
    d.fit = best_fit;
    SelectedTerm s;
    s.gyro = d.series->gyro;
    s.column = d.columns[best_c];
    s.prior_sigma = d.prior(best_c);
    s.evidence = best;
    s.threshold = threshold;
    s.columns_tested = M;
    result.terms.push_back(s);
  }
  // Final values, the alternatives of each selected regressor, and the residual drift.
  for (GyroData& d : gyros) {
    for (size_t i = 0; i < d.active.size(); ++i) {
      for (SelectedTerm& s : result.terms) {
        if (s.gyro != d.series->gyro || s.column.label != d.columns[d.active[i]].label) continue;
        s.value = d.fit.mean(i);
        s.sigma = d.fit.sigma(i);
        for (size_t c = 0; c < d.columns.size(); ++c) {
          if (std::find(d.active.begin(), d.active.end(), static_cast<int>(c)) != d.active.end()) {
            continue;
          }
          std::vector<int> cols = d.active;
          cols[i] = static_cast<int>(c);
          const double against = d.fit.deviance - Fit(d, cols).deviance;
          if (against > -options.ambiguity) s.alternatives.emplace_back(d.columns[c].label, against);
        }
        std::sort(s.alternatives.begin(), s.alternatives.end(),
                  [](const auto& a, const auto& b) { return a.second > b.second; });
      }
    }
    result.deviance_after += d.fit.deviance;
    std::vector<Vector2d> z_after = d.series->y;
    for (size_t i = 0; i < d.active.size(); ++i) {
      const std::vector<Vector2d>& x = d.signature[d.active[i]];
      for (size_t k = 0; k < z_after.size(); ++k) z_after[k] -= d.fit.mean(i) * x[k];
    }
    ResidualDrift r;
    SmoothInCaseAxes(*d.series, d.w0_sigma, d.series->y, z_after, r);
    result.residual_drift.push_back(std::move(r));
  }
  return result;
}

std::vector<std::string> DescribeTerms(const std::vector<SelectedTerm>& terms,
                                       const OpenEndedOptions& options) {
  // Group the drift terms of a gyro by their scalar regressor (all but the axis; cos and sin of
  // one orbital harmonic together): one group is one vector drift along a direction in case axes.
  using Key = std::tuple<int, int, std::array<int, 3>, std::array<int, 2>, int>;
  std::map<Key, std::vector<const SelectedTerm*>> groups;
  std::vector<std::string> out;
  for (const SelectedTerm& s : terms) {
    if (s.column.readout) {
      out.push_back(absl::StrFormat(
          "gyro %d: readout distortion %s = %.0f +- %.0f ppm (a scale-factor or non-orthogonality "
          "error of the direction-cosine readout: the reading is (I + E) h normalised)",
          s.gyro, s.column.label.substr(8), s.value * 1e6, s.sigma * 1e6));
      continue;
    }
    const BasisTerm& t = s.column.term;
    groups[{s.gyro, static_cast<int>(t.kind), t.exponents, t.index, t.harmonic}].push_back(&s);
  }
  const double deg_h = RadPerSecToDegPerHour(1.0);
  for (const auto& [key, members] : groups) {
    const int gyro = std::get<0>(key);
    const BasisTerm& t0 = members.front()->column.term;
    const double to_json = BasisValueToJson(t0.kind);
    Vector3d v = Vector3d::Zero(), v_sigma = Vector3d::Zero(), cos_v = Vector3d::Zero(),
             sin_v = Vector3d::Zero();
    for (const SelectedTerm* s : members) {
      const int m = s->column.term.axis - 1;
      v(m) += s->value;
      v_sigma(m) = std::hypot(v_sigma(m), s->sigma);
      (s->column.term.sine ? sin_v : cos_v)(m) += s->value;
    }
    std::string text;
    switch (t0.kind) {
      case BasisKind::kSpinAxisHarmonic: {
        const int degree = t0.exponents[0] + t0.exponents[1] + t0.exponents[2];
        const Vector3d dir = v.normalized();
        text = degree == 0
                   ? absl::StrFormat("case-fixed drift along %s (case axes), %.4f deg/h",
                                     Vec(dir, 1.0, "%.2f"), v.norm() * deg_h)
                   : absl::StrFormat(
                         "drift depending on the spin-axis direction, %s times %s deg/h (case "
                         "axes; a harmonic of degree %d of the spin axis)",
                         members.front()->column.label.substr(
                             0, members.front()->column.label.find(" ->")),
                         Vec(v, deg_h), degree);
        break;
      }
      case BasisKind::kOrbitalHarmonic: {
        // d(t) = C cos(n phase) + S sin(n phase): its largest size over the orbit.
        double amplitude = 0.0;
        for (int i = 0; i < 360; ++i) {
          const double a = i * kPi / 180.0;
          amplitude = std::max(amplitude, (cos_v * std::cos(a) + sin_v * std::sin(a)).norm());
        }
        const Vector3d dir = (cos_v.norm() >= sin_v.norm() ? cos_v : sin_v).normalized();
        text = absl::StrFormat(
            "case-fixed drift along %s (case axes) varying with the orbital phase (period %.1f "
            "min, harmonic %d), amplitude %.4f deg/h: %s cos + %s sin deg/h",
            Vec(dir, 1.0, "%.2f"), options.orbital_period_s / 60.0, t0.harmonic,
            amplitude * deg_h, Vec(cos_v, deg_h), Vec(sin_v, deg_h));
        break;
      }
      case BasisKind::kRamp:
        text = absl::StrFormat(
            "case-fixed drift growing linearly in time along %s (case axes), %.4f deg/h per hour "
            "(zero at the recording's start)",
            Vec(v.normalized(), 1.0, "%.2f"), v.norm() * to_json);
        break;
      case BasisKind::kRampHarmonic:
        text = absl::StrFormat(
            "a C2-like drift (eq. (9)) growing linearly in time, h%d^2 times %s deg/h per hour",
            t0.index[0], Vec(v, to_json));
        break;
      case BasisKind::kBodyRate:
        text = absl::StrFormat(
            "drift proportional to the body rate about case axis %c, %s deg/h per deg/s",
            "xyz"[t0.index[0] - 1], Vec(v, to_json));
        break;
      case BasisKind::kBodyRateProduct:
        text = absl::StrFormat(
            "drift proportional to the product of the body rates about case axes %c and %c, %s "
            "deg/h per (deg/s)^2",
            "xyz"[t0.index[0] - 1], "xyz"[t0.index[1] - 1], Vec(v, to_json, "%.3g"));
        break;
      case BasisKind::kSuspensionVoltage:
        text = absl::StrFormat(
            "drift proportional to the suspension offset voltage of case axis %c, %s deg/h per V",
            "xyz"[t0.index[0] - 1], Vec(v, to_json));
        break;
    }
    std::vector<std::string> alternatives;
    for (const SelectedTerm* s : members) {
      for (const auto& [label, against] : s->alternatives) {
        alternatives.push_back(absl::StrFormat("%s (2 ln B %.1f)", label, against));
      }
    }
    if (!alternatives.empty()) {
      if (alternatives.size() > 6) alternatives.resize(6);
      absl::StrAppend(&text, "; on this recording it cannot be told apart from ",
                      absl::StrJoin(alternatives, ", "),
                      " (the data favour the named term by a Bayes factor below 20)");
    }
    out.push_back(absl::StrFormat("gyro %d: %s", gyro, text));
  }
  return out;
}

}  // namespace esg::estimator::discovery
