#include "estimator/discovery/open_ended.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <map>
#include <memory>
#include <tuple>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/discovery/deviation_filter.h"
#include "estimator/drift_model.h"
#include "estimator/model_terms.h"
#include "estimator/spacecraft_config.h"
#include "estimator/statistics.h"
#include "estimator/utc_time.h"

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
  GyroBasis basis;
  std::vector<std::vector<Vector2d>> signature;  // raw, per column
  std::vector<VectorXd> x_w;                     // whitened, per column
  VectorXd prior;                                // per column
  std::vector<int> active;                       // selected groups
  RegressionFit fit;
};

// The columns of `groups`, in order.
std::vector<int> ColumnsOf(const GyroData& g, const std::vector<int>& groups) {
  std::vector<int> cols;
  for (int k : groups) {
    const std::vector<int>& c = g.basis.groups[k].columns;
    cols.insert(cols.end(), c.begin(), c.end());
  }
  return cols;
}

RegressionFit Fit(const GyroData& g, const std::vector<int>& groups) {
  const std::vector<int> cols = ColumnsOf(g, groups);
  std::vector<const VectorXd*> X;
  VectorXd prior(cols.size());
  for (size_t i = 0; i < cols.size(); ++i) {
    X.push_back(&g.x_w[cols[i]]);
    prior(i) = g.prior(cols[i]);
  }
  return FitRegression(g.y_w, X, prior);
}

bool Contains(const std::vector<int>& v, int x) {
  return std::find(v.begin(), v.end(), x) != v.end();
}

// A sun column's regressor at every substep of the gyro's series; nullptr for other columns.
const std::vector<double>* SunValues(const OpenEndedOptions& options, int gyro,
                                     const BasisColumn& c) {
  if (c.sun_face < 0) return nullptr;
  const SunRegressors* sun = FindSunRegressors(options.sun, gyro);
  if (sun == nullptr || c.sun_face >= static_cast<int>(sun->values.size()) ||
      c.sun_lag >= static_cast<int>(sun->values[c.sun_face].size())) {
    return nullptr;
  }
  return &sun->values[c.sun_face][c.sun_lag];
}

// A candidate of a round: one group, or a face's family of sun groups (the lags of the grid),
// fitted on top of the gyro's active groups; its evidence 2 ln B (a family's averaged over the
// lags, sun_terms.h AverageEvidence), the group taken if it is selected (a family's best lag) and
// that group's fit.
struct RoundCandidate {
  int group = -1;
  double evidence = -std::numeric_limits<double>::infinity();
  RegressionFit fit;
  std::vector<double> lag_evidence;  // a family: 2 ln B at each lag
  // A family: the drift at full illumination [rad/s, case axes] and its covariance averaged over
  // the lags with their posterior weights.
  Vector3d averaged_k = Vector3d::Zero();
  Matrix3d averaged_covariance_k = Matrix3d::Zero();
};

// The sun group's drift (case axes) and covariance in `fit`, a fit whose last columns are the
// group's `cols`.
std::pair<Vector3d, Matrix3d> SunDriftOf(const GyroData& d, const std::vector<int>& cols,
                                         const RegressionFit& fit) {
  Vector3d a = Vector3d::Zero();
  Matrix3d P = Matrix3d::Zero();
  const int n = static_cast<int>(fit.mean.size()), first = n - static_cast<int>(cols.size());
  for (int i = 0; i < static_cast<int>(cols.size()); ++i) {
    const int m = d.basis.columns[cols[i]].term.axis - 1;
    a(m) += fit.mean(first + i);
    for (int j = 0; j < static_cast<int>(cols.size()); ++j) {
      P(m, d.basis.columns[cols[j]].term.axis - 1) += fit.covariance(first + i, first + j);
    }
  }
  return {a, P};
}

RoundCandidate FitFamily(const GyroData& d, const std::vector<int>& family) {
  RoundCandidate out;
  double best = -std::numeric_limits<double>::infinity();
  std::vector<std::pair<Vector3d, Matrix3d>> drifts;
  for (int k : family) {
    std::vector<int> groups = d.active;
    groups.push_back(k);
    RegressionFit f = Fit(d, groups);
    const double evidence = d.fit.deviance - f.deviance;
    out.lag_evidence.push_back(evidence);
    drifts.push_back(SunDriftOf(d, d.basis.groups[k].columns, f));
    if (evidence > best) {
      best = evidence;
      out.group = k;
      out.fit = std::move(f);
    }
  }
  out.evidence = AverageEvidence(out.lag_evidence);
  // Posterior weights of the lags (equal prior): w_l proportional to exp(e_l / 2).
  std::vector<double> w;
  double total = 0.0;
  for (double e : out.lag_evidence) {
    w.push_back(std::exp(0.5 * (e - best)));
    total += w.back();
  }
  for (size_t l = 0; l < w.size(); ++l) out.averaged_k += w[l] / total * drifts[l].first;
  for (size_t l = 0; l < w.size(); ++l) {
    const Vector3d dev = drifts[l].first - out.averaged_k;
    out.averaged_covariance_k += w[l] / total * (drifts[l].second + dev * dev.transpose());
  }
  return out;
}

// Whether a group of face `face` is active in the gyro's model.
bool FaceActive(const GyroData& d, int face) {
  return std::any_of(d.active.begin(), d.active.end(),
                     [&](int k) { return d.basis.groups[k].sun_face == face; });
}

// The scalar regressor of a drift column at a substep.
double ColumnScalar(const BasisColumn& c, const BasisInputs& in) {
  if (c.nuisance) return in.time < c.before ? 1.0 : 0.0;
  return BasisScalar(c.term, in);
}

// The column's scalar regressor at each substep of the series.
std::shared_ptr<const std::vector<double>> ScalarTable(const DeviationSeries& s,
                                                       const BasisColumn& c) {
  auto table = std::make_shared<std::vector<double>>();
  table->reserve(s.steps.size());
  for (const TrajectoryStep& st : s.steps) table->push_back(ColumnScalar(c, st.inputs));
  return table;
}

}  // namespace

std::vector<Vector2d> ColumnSignature(const DeviationSeries& s, const BasisColumn& c) {
  if (c.readout) return ReadoutSignature(s, ReadoutPattern(c.readout_index));
  if (c.theta >= 0) {  // eq. (1), (10): d(dw_k)/d(theta_i)
    return Signature(s, [&c](const BasisInputs& in) -> Vector3d {
      return DriftRegressor(in.h_k).col(c.theta);
    });
  }
  const Vector3d e_m = Vector3d::Unit(c.term.axis - 1);
  if (c.scalar_table != nullptr) return TabulatedSignature(s, *c.scalar_table, e_m);
  return Signature(s, [&c, &e_m](const BasisInputs& in) -> Vector3d {
    return ColumnScalar(c, in) * e_m;
  });
}

namespace {

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

// A column's prior 1-sigma: its own (a free coefficient of the model), the readout's, or the
// drift's at the regressor's RMS.
double ColumnPrior(const BasisColumn& col, const OpenEndedOptions& options) {
  if (col.prior_sigma > 0.0) return col.prior_sigma;
  return col.readout ? options.readout_sigma : options.drift_sigma / col.rms;
}

// Whitens the series and the columns of its basis (EnumerateBasis), with their priors, and fits
// the base model (the nuisance groups).
void PrepareGyro(const DeviationSeries& series, double random_walk, double w0_sigma,
                 const OpenEndedOptions& options, GyroData& d) {
  d.series = &series;
  d.random_walk = random_walk;
  d.w0_sigma = w0_sigma;
  const DeviationFilter filter(series, d.random_walk, d.w0_sigma);
  d.y_w = filter.Whiten(series.y);
  d.basis = EnumerateBasis(series, options);
  d.prior.resize(d.basis.columns.size());
  // A tabulated regressor's columns (a term's three axes, a sun face's at one lag) are
  // consecutive: their signatures are computed together, in one pass over the substeps.
  const std::vector<double>* last_table = nullptr;
  std::array<std::vector<Vector2d>, 3> last_signatures;
  for (size_t c = 0; c < d.basis.columns.size(); ++c) {
    const BasisColumn& col = d.basis.columns[c];
    const std::vector<double>* sun = SunValues(options, series.gyro, col);
    const std::vector<double>* table = sun != nullptr ? sun : col.scalar_table.get();
    if (col.readout || col.theta >= 0 || table == nullptr) {
      d.signature.push_back(ColumnSignature(series, col));
    } else {
      if (table != last_table) {
        last_signatures = TabulatedSignatures(series, *table);
        last_table = table;
      }
      d.signature.push_back(last_signatures[col.term.axis - 1]);
    }
    d.x_w.push_back(filter.Whiten(d.signature.back()));
    d.prior(c) = ColumnPrior(col, options);
  }
  for (BasisColumn& col : d.basis.columns) col.scalar_table.reset();
  for (int k = 0; k < static_cast<int>(d.basis.groups.size()); ++k) {
    if (d.basis.groups[k].nuisance) d.active.push_back(k);
  }
  d.fit = Fit(d, d.active);
}

// The group's columns with their posterior from `fit` (a fit over `cols`, in order) and their
// covariance block.
void FillGroup(const GyroData& d, const std::vector<int>& cols, const RegressionFit& fit,
               int group, SelectedGroup& s) {
  std::vector<int> at;
  for (size_t j = 0; j < cols.size(); ++j) {
    if (d.basis.columns[cols[j]].group != group) continue;
    s.columns.push_back(
        FittedColumn{d.basis.columns[cols[j]], fit.mean(j), fit.sigma(j), d.prior(cols[j])});
    at.push_back(static_cast<int>(j));
  }
  s.covariance.resize(static_cast<int>(at.size()), static_cast<int>(at.size()));
  for (size_t a = 0; a < at.size(); ++a) {
    for (size_t b = 0; b < at.size(); ++b) s.covariance(a, b) = fit.covariance(at[a], at[b]);
  }
}

// "(x, y, z)" of v * scale with `digits` decimals (a precision argument, not a format string
// built at run time: absl::StrFormat checks its format at compile time).
std::string Vec(const Vector3d& v, double scale, int digits = 4) {
  return absl::StrFormat("(%.*f, %.*f, %.*f)", digits, v(0) * scale, digits, v(1) * scale, digits,
                         v(2) * scale);
}


// The alternatives to a selected group, as the stage names them: each other group of the basis
// that replaces it at a loss below `ambiguity`, a sun face counted once, at its best lag.
class Alternatives {
 public:
  explicit Alternatives(double ambiguity) : ambiguity_(ambiguity) {}
  // `group` in place of the selected one: `against` is its deviance less the selection's.
  void Add(const BasisGroup& group, double against) {
    if (group.sun_face >= 0) {
      auto it = sun_best_.find(group.sun_face);
      if (it == sun_best_.end() || -against > it->second.second) {
        sun_best_[group.sun_face] = {group.label, -against};
      }
    } else if (-against > -ambiguity_) {
      others_.emplace_back(group.label, -against);
    }
  }
  // Appends them to `out` and sorts it by evidence, largest first.
  void AppendTo(std::vector<std::pair<std::string, double>>& out) const {
    out.insert(out.end(), others_.begin(), others_.end());
    for (const auto& [face, alternative] : sun_best_) {
      if (alternative.second > -ambiguity_) out.push_back(alternative);
    }
    std::sort(out.begin(), out.end(),
              [](const auto& a, const auto& b) { return a.second > b.second; });
  }

 private:
  double ambiguity_;
  std::vector<std::pair<std::string, double>> others_;
  std::map<int, std::pair<std::string, double>> sun_best_;  // face -> its best lag
};

// A gyro's basis as it is built: groups opened one after another, the columns added until the
// next one belonging to the last; a column whose regressor is absent from the recording is left
// out, and so is a group left empty.
class BasisBuilder {
 public:
  BasisBuilder(const DeviationSeries& series, const OpenEndedOptions& options)
      : series_(series), options_(options) {}

  // Opens a group; columns added until the next one belong to it. Empty groups are dropped.
  void OpenGroup(std::string label) {
    DropEmptyGroup();
    out_.groups.push_back(BasisGroup{std::move(label), {}});
  }
  BasisGroup& Group() { return out_.groups.back(); }

  void AddColumn(BasisColumn c) {
    c.group = static_cast<int>(out_.groups.size()) - 1;
    if (!c.readout && c.theta < 0) {
      const std::vector<double>* sun = SunValues(options_, series_.gyro, c);
      if (sun == nullptr && c.scalar_table == nullptr) c.scalar_table = ScalarTable(series_, c);
      c.rms = TabulatedRms(series_, sun != nullptr ? *sun : *c.scalar_table);
      if (!(c.rms > kAbsentRms)) return;
      // A term whose prior (drift_sigma at the regressor's RMS) exceeds the configuration's
      // limit on a term's sigma at its kind's reference size (spacecraft_config.h
      // kConfigLimits.basis_sigma) could only matter at a size the recording never reaches (a
      // body rate of arcseconds per second in an inertial hold), and a model holding it is
      // refused: absent too. Sun columns are held as reading corrections, not basis terms.
      if (sun == nullptr && options_.drift_sigma / c.rms * BasisValueToJson(c.term.kind) *
                                    BasisReferenceSize(c.term.kind) >
                                kConfigLimits.basis_sigma.max) {
        return;
      }
    }
    out_.groups.back().columns.push_back(static_cast<int>(out_.columns.size()));
    out_.columns.push_back(std::move(c));
  }

  // One scalar regressor along each case axis, tabulated once.
  void AddAxes(BasisTerm t) {
    std::shared_ptr<const std::vector<double>> table;
    for (int m = 1; m <= 3; ++m) {
      t.axis = m;
      BasisColumn c;
      c.term = t;
      c.label = BasisTermLabel(t);
      if (table == nullptr) table = ScalarTable(series_, c);
      c.scalar_table = table;
      AddColumn(c);
    }
  }

  // A group of its own (named by the term's scalar) with the term along each case axis.
  void AddScalarGroup(const BasisTerm& t) {
    const std::string label = BasisTermLabel(t);
    OpenGroup(label.substr(0, label.find(" ->")));
    AddAxes(t);
  }

  GyroBasis Take() {
    DropEmptyGroup();
    return std::move(out_);
  }

 private:
  void DropEmptyGroup() {
    if (!out_.groups.empty() && out_.groups.back().columns.empty()) out_.groups.pop_back();
  }

  const DeviationSeries& series_;
  const OpenEndedOptions& options_;
  GyroBasis out_;
};

// The drift terms of the basis: the spin-axis harmonics h1^a h2^b h3^c (c <= 1) up to
// kMaxHarmonicDegree, the body rates and their products, the orbital harmonics (with a period),
// a ramp and a C2-like term growing in time, and the suspension voltages.
void AddDriftGroups(const OpenEndedOptions& options, BasisBuilder& b) {
  BasisTerm t;
  t.epoch = options.epoch;
  t.kind = BasisKind::kSpinAxisHarmonic;
  for (int c = 0; c <= 1; ++c) {
    for (int degree = 0; degree + c <= kMaxHarmonicDegree; ++degree) {
      for (int a = degree; a >= 0; --a) {
        t.exponents = {a, degree - a, c};
        b.AddScalarGroup(t);
      }
    }
  }
  t.kind = BasisKind::kBodyRate;
  for (int i = 1; i <= 3; ++i) {
    t.index = {i, i};
    b.AddScalarGroup(t);
  }
  t.kind = BasisKind::kBodyRateProduct;
  for (int i = 1; i <= 3; ++i) {
    for (int j = i; j <= 3; ++j) {
      t.index = {i, j};
      b.AddScalarGroup(t);
    }
  }
  if (options.orbital_period_s > 0.0) {
    t.kind = BasisKind::kOrbitalHarmonic;
    t.period = options.orbital_period_s;
    for (int n = 1; n <= 2; ++n) {
      b.OpenGroup(absl::StrCat("orbit ", n));
      t.harmonic = n;
      for (bool sine : {false, true}) {
        t.sine = sine;
        b.AddAxes(t);
      }
    }
  }
  t.kind = BasisKind::kRamp;
  b.OpenGroup("ramp");
  b.AddAxes(t);
  // A C2-like term growing in time (eq. (9) with C2 proportional to time): t h_m^2 e_m.
  t.kind = BasisKind::kRampHarmonic;
  b.OpenGroup("ramp*h_m^2");
  for (int m = 1; m <= 3; ++m) {
    t.index = {m, m};
    t.axis = m;
    BasisColumn c;
    c.term = t;
    c.label = BasisTermLabel(t);
    b.AddColumn(c);
  }
  t.kind = BasisKind::kSuspensionVoltage;
  for (int i = 1; i <= 3; ++i) {
    t.index = {i, i};
    b.AddScalarGroup(t);
  }
}

// The readout distortion's patterns (one group), the sun's families (a group per lit face and
// lag; a face held in the model already, sun_terms.h HeldSunFaces, has no regressors), and the
// nuisance groups of the drift steps the model holds for the gyro.
void AddReadoutSunAndStepGroups(const DeviationSeries& series, const OpenEndedOptions& options,
                                BasisBuilder& b) {
  b.OpenGroup("readout");
  for (int i = 0; i < kReadoutPatterns; ++i) {
    BasisColumn col;
    col.readout = true;
    col.readout_index = i;
    col.label = ReadoutPatternLabel(i);
    b.AddColumn(col);
  }
  if (const SunRegressors* sun = FindSunRegressors(options.sun, series.gyro)) {
    for (int face = 0; face < static_cast<int>(sun->values.size()); ++face) {
      if (face >= static_cast<int>(sun->values.size()) || sun->values[face].empty()) continue;
      for (int lag = 0; lag < static_cast<int>(sun->lag_hours.size()); ++lag) {
        const std::string label = SunGroupLabel(face, sun->lag_hours[lag]);
        b.OpenGroup(label);
        b.Group().sun_face = face;
        b.Group().sun_lag = lag;
        for (int m = 1; m <= 3; ++m) {
          BasisColumn c;
          c.sun_face = face;
          c.sun_lag = lag;
          c.term.axis = m;
          c.label = absl::StrCat(label, " -> ", std::string(1, "xyz"[m - 1]));
          b.AddColumn(c);
        }
      }
    }
  }
  bool free_group = false;
  for (const OpenEndedOptions::FreeCoefficient& f : options.free_coefficients) {
    if (f.gyro != series.gyro || f.theta < 0 || f.theta >= kNumDriftCoefficients ||
        !(f.sigma > 0.0)) {
      continue;
    }
    if (!free_group) {
      b.OpenGroup("the model's free coefficients");
      b.Group().nuisance = true;
      free_group = true;
    }
    BasisColumn c;
    c.nuisance = true;
    c.theta = f.theta;
    c.prior_sigma = f.sigma;
    c.label = absl::StrCat("the model's ", kFixedTerms[f.theta].label);
    b.AddColumn(c);
  }
  for (const auto& [gyro, time] : options.steps) {
    if (gyro != series.gyro) continue;
    b.OpenGroup(absl::StrCat("before the drift step at ", FormatUtc(time)));
    b.Group().nuisance = true;
    for (int m = 1; m <= 3; ++m) {
      BasisColumn c;
      c.nuisance = true;
      c.before = time;
      c.term.axis = m;
      c.label = absl::StrCat(b.Group().label, " -> ", std::string(1, "xyz"[m - 1]));
      b.AddColumn(c);
    }
  }
}

// The best group of one round over every gyro: its gyro's index, the group, its 2 ln B, the fit
// with it, and for a sun family its evidence at each lag and its lag-averaged drift; `tested`
// the number of groups (a sun family counts once) compared.
struct RoundBest {
  int tested = 0;
  int gyro = -1;
  int group = -1;
  double evidence = -std::numeric_limits<double>::infinity();
  RegressionFit fit;
  std::vector<double> profile;
  std::pair<Vector3d, Matrix3d> averaged;
};

// The columns gyro `d` may still take: its budget (OpenEndedOptions::column_budget, unlimited
// when absent) less the drift columns of its active groups.
int RemainingBudget(const GyroData& d, const OpenEndedOptions& options) {
  int budget = std::numeric_limits<int>::max();
  for (const auto& [gyro, n] : options.column_budget) {
    if (gyro == d.series->gyro) budget = n;
  }
  for (int k : d.active) {
    for (int c : d.basis.groups[k].columns) {
      budget -= d.basis.columns[c].readout || d.basis.columns[c].nuisance ? 0 : 1;
    }
  }
  return budget;
}

// Every group of gyro `g` not active yet, fitted beside the active ones: each sun family of an
// inactive face as one (FitFamily), each other group within the budget; the best kept in `best`.
void CompareGroupsOf(std::vector<GyroData>& gyros, size_t g, const OpenEndedOptions& options,
                     RoundBest& best) {
  GyroData& d = gyros[g];
  const int budget = RemainingBudget(d, options);
  std::map<int, std::vector<int>> families;  // sun face -> its groups, by lag
  for (int k = 0; k < static_cast<int>(d.basis.groups.size()); ++k) {
    const int face = d.basis.groups[k].sun_face;
    if (face >= 0 && !FaceActive(d, face)) families[face].push_back(k);
  }
  for (const auto& [face, family] : families) {
    ++best.tested;
    RoundCandidate c = FitFamily(d, family);
    if (c.evidence > best.evidence) {
      best.evidence = c.evidence;
      best.gyro = static_cast<int>(g);
      best.group = c.group;
      best.fit = std::move(c.fit);
      best.profile = std::move(c.lag_evidence);
      best.averaged = {c.averaged_k, c.averaged_covariance_k};
    }
  }
  for (int k = 0; k < static_cast<int>(d.basis.groups.size()); ++k) {
    if (Contains(d.active, k) || d.basis.groups[k].nuisance) continue;
    if (d.basis.groups[k].sun_face >= 0) continue;  // in its family above
    int drift_columns = 0;
    for (int c : d.basis.groups[k].columns) drift_columns += d.basis.columns[c].readout ? 0 : 1;
    if (drift_columns > budget) continue;
    ++best.tested;
    std::vector<int> groups = d.active;
    groups.push_back(k);
    RegressionFit f = Fit(d, groups);
    const double evidence = d.fit.deviance - f.deviance;
    if (evidence > best.evidence) {
      best.evidence = evidence;
      best.gyro = static_cast<int>(g);
      best.group = k;
      best.fit = std::move(f);
      best.profile.clear();
    }
  }
}

// The round's best group taken: active in its gyro with its fit, and as a selected group.
SelectedGroup TakeGroup(GyroData& d, RoundBest& best, double threshold,
                        const OpenEndedOptions& options) {
  d.active.push_back(best.group);
  d.fit = best.fit;
  SelectedGroup s;
  s.gyro = d.series->gyro;
  s.label = d.basis.groups[best.group].label;
  s.evidence = best.evidence;
  s.threshold = threshold;
  s.groups_tested = best.tested;
  s.sun_face = d.basis.groups[best.group].sun_face;
  if (s.sun_face >= 0) {
    if (const SunRegressors* sun = FindSunRegressors(options.sun, s.gyro)) {
      s.lag_hours = sun->lag_hours;
    }
    s.lag_evidence = std::move(best.profile);
    s.lag_averaged_k = best.averaged.first;
    s.lag_averaged_covariance_k = best.averaged.second;
  }
  return s;
}

// A gyro's final values: each of its selected groups filled (FillGroup) with its alternatives
// (each inactive group in its place), its deviance after, and its residual drift before and after.
void FinishGyro(GyroData& d, const OpenEndedOptions& options, OpenEndedResult& result) {
  const std::vector<int> cols = ColumnsOf(d, d.active);
  for (size_t i = 0; i < d.active.size(); ++i) {
    if (d.basis.groups[d.active[i]].nuisance) continue;
    for (SelectedGroup& s : result.selected) {
      if (s.gyro != d.series->gyro || s.label != d.basis.groups[d.active[i]].label) continue;
      FillGroup(d, cols, d.fit, d.active[i], s);
      Alternatives alternatives(options.ambiguity);
      for (int k = 0; k < static_cast<int>(d.basis.groups.size()); ++k) {
        if (Contains(d.active, k) || d.basis.groups[k].nuisance) continue;
        const int face = d.basis.groups[k].sun_face;
        if (face >= 0 && (face == s.sun_face || FaceActive(d, face))) continue;
        std::vector<int> groups = d.active;
        groups[i] = k;
        alternatives.Add(d.basis.groups[k], Fit(d, groups).deviance - d.fit.deviance);
      }
      alternatives.AppendTo(s.alternatives);
    }
  }
  result.deviance_after += d.fit.deviance;
  std::vector<Vector2d> z_after = d.series->y;
  for (size_t j = 0; j < cols.size(); ++j) {
    const std::vector<Vector2d>& x = d.signature[cols[j]];
    for (size_t k = 0; k < z_after.size(); ++k) z_after[k] -= d.fit.mean(j) * x[k];
  }
  ResidualDrift r;
  SmoothInCaseAxes(*d.series, d.w0_sigma, d.series->y, z_after, r);
  result.residual_drift.push_back(std::move(r));
}

}  // namespace

std::vector<OpenEndedOptions::FreeCoefficient> FreeCoefficientsOf(const SpacecraftConfig& config) {
  std::vector<OpenEndedOptions::FreeCoefficient> out;
  for (const GyroConfig& g : config.gyros) {
    const DriftVector sigma = g.model_sigma.AsVector();
    for (int i = 0; i < kNumDriftCoefficients; ++i) {
      if (sigma(i) > 0.0) out.push_back({g.id, i, sigma(i)});
    }
  }
  return out;
}

GyroBasis EnumerateBasis(const DeviationSeries& series, const OpenEndedOptions& options) {
  BasisBuilder b(series, options);
  AddDriftGroups(options, b);
  AddReadoutSunAndStepGroups(series, options, b);
  return b.Take();
}

// The stage as a sequence: each gyro's basis and its fit without terms, then rounds while the
// best group of a round clears its threshold, then each gyro's final values.
OpenEndedResult RunOpenEnded(const std::vector<DeviationSeries>& series,
                             const std::vector<double>& random_walk,
                             const std::vector<double>& w0_sigma,
                             const OpenEndedOptions& options) {
  OpenEndedResult result;
  std::vector<GyroData> gyros(series.size());
  for (size_t g = 0; g < series.size(); ++g) {
    PrepareGyro(series[g], g < random_walk.size() ? random_walk[g] : 0.0,
                g < w0_sigma.size() ? w0_sigma[g] : 0.0, options, gyros[g]);
    result.deviance_before += gyros[g].fit.deviance;
  }
  for (int round = 0; round < options.max_terms; ++round) {
    RoundBest best;
    for (size_t g = 0; g < gyros.size(); ++g) CompareGroupsOf(gyros, g, options, best);
    if (round == 0) result.groups_tested = best.tested;
    if (best.gyro < 0) break;
    const double threshold = EvidenceThreshold(options.alpha, best.tested);
    GyroData& d = gyros[best.gyro];
    result.best_gyro = d.series->gyro;
    result.best_label = d.basis.groups[best.group].label;
    result.best_evidence = best.evidence;
    result.best_threshold = threshold;
    if (!(best.evidence > threshold)) break;
    result.selected.push_back(TakeGroup(d, best, threshold, options));
  }
  // Final values, the alternatives of each selected group, and the residual drift.
  for (GyroData& d : gyros) FinishGyro(d, options, result);
  return result;
}

Matrix3d ReadoutPattern(int index) {
  Matrix3d B = Matrix3d::Zero();
  switch (index) {
    case 0:
      B.diagonal() << 1.0, -1.0, 0.0;
      return B / std::sqrt(2.0);
    case 1:
      B.diagonal() << 1.0, 1.0, -2.0;
      return B / std::sqrt(6.0);
    default: {
      const int r = index - 2, c = (index - 1) % 3;  // xy, yz, zx
      B(r, c) = B(c, r) = 1.0 / std::sqrt(2.0);
      return B;
    }
  }
}

const char* ReadoutPatternLabel(int index) {
  static constexpr std::array<const char*, kReadoutPatterns> kLabels = {
      "readout xx-yy", "readout xx+yy-2zz", "readout xy", "readout yz", "readout zx"};
  return kLabels[std::clamp(index, 0, kReadoutPatterns - 1)];
}

Matrix3d ReadoutDistortion(const SelectedGroup& group) {
  Matrix3d E = Matrix3d::Zero();
  for (const FittedColumn& c : group.columns) {
    if (c.column.readout) E += c.value * ReadoutPattern(c.column.readout_index);
  }
  return E;
}

Matrix3d ReadoutDistortionSigma(const SelectedGroup& group) {
  Matrix3d sigma = Matrix3d::Zero();
  const int n = static_cast<int>(group.columns.size());
  if (group.covariance.rows() != n) return sigma;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) {
      VectorXd b = VectorXd::Zero(n);  // E(r, c) = b^T a
      for (int i = 0; i < n; ++i) {
        if (group.columns[i].column.readout)
          b(i) = ReadoutPattern(group.columns[i].column.readout_index)(r, c);
      }
      sigma(r, c) = std::sqrt(std::max(0.0, b.dot(group.covariance * b)));
    }
  }
  return sigma;
}

ReadoutFit FitReadoutDistortion(const DeviationSeries& series, double random_walk,
                                double w0_sigma, const OpenEndedOptions& options) {
  ReadoutFit out;
  GyroData d;
  PrepareGyro(series, random_walk, w0_sigma, options, d);
  int readout = -1;
  for (int k = 0; k < static_cast<int>(d.basis.groups.size()); ++k) {
    if (d.basis.groups[k].label == "readout") readout = k;
  }
  out.group.gyro = series.gyro;
  out.group.label = "readout";
  out.group.groups_tested = 1;
  if (readout < 0) return out;
  std::vector<int> groups = d.active;
  groups.push_back(readout);
  const std::vector<int> cols = ColumnsOf(d, groups);
  const RegressionFit fit = Fit(d, groups);
  out.group.evidence = d.fit.deviance - fit.deviance;
  FillGroup(d, cols, fit, readout, out.group);
  return out;
}

SunFamilyFit FitSunFamilies(const DeviationSeries& series, double random_walk, double w0_sigma,
                            const OpenEndedOptions& options, const std::vector<int>& held_faces) {
  SunFamilyFit out;
  out.group.gyro = series.gyro;
  const SunRegressors* sun = FindSunRegressors(options.sun, series.gyro);
  if (sun == nullptr) return out;
  GyroData d;
  PrepareGyro(series, random_walk, w0_sigma, options, d);
  std::map<int, std::vector<int>> families;  // sun face -> its groups, by lag
  for (int k = 0; k < static_cast<int>(d.basis.groups.size()); ++k) {
    const int face = d.basis.groups[k].sun_face;
    if (face >= 0 && !Contains(held_faces, face)) families[face].push_back(k);
  }
  RoundCandidate best;
  int best_face = -1;
  for (const auto& [face, family] : families) {
    RoundCandidate c = FitFamily(d, family);
    if (best_face < 0 || c.evidence > best.evidence) {
      best = std::move(c);
      best_face = face;
    }
  }
  if (best_face < 0) return out;
  SelectedGroup& s = out.group;
  s.label = d.basis.groups[best.group].label;
  s.evidence = best.evidence;
  s.groups_tested = static_cast<int>(families.size());
  s.sun_face = best_face;
  s.lag_hours = sun->lag_hours;
  s.lag_evidence = best.lag_evidence;
  s.lag_averaged_k = best.averaged_k;
  s.lag_averaged_covariance_k = best.averaged_covariance_k;
  out.best_lag_evidence = d.fit.deviance - best.fit.deviance;
  std::vector<int> groups = d.active;
  groups.push_back(best.group);
  FillGroup(d, ColumnsOf(d, groups), best.fit, best.group, s);
  // The alternatives, as the stage names them: any other group of the basis, and each other face
  // at its best lag, that replaces the face's group at a loss below options.ambiguity.
  Alternatives alternatives(options.ambiguity);
  for (int k = 0; k < static_cast<int>(d.basis.groups.size()); ++k) {
    if (Contains(d.active, k) || d.basis.groups[k].nuisance) continue;
    const int face = d.basis.groups[k].sun_face;
    if (face == best_face) continue;
    std::vector<int> other = d.active;
    other.push_back(k);
    const double against = Fit(d, other).deviance - best.fit.deviance;
    if (face < 0 && out.best_lag_evidence - against > out.best_other_evidence) {
      out.best_other_evidence = out.best_lag_evidence - against;  // d.fit.deviance - its fit's
      out.best_other_label = d.basis.groups[k].label;
    }
    alternatives.Add(d.basis.groups[k], against);
  }
  alternatives.AppendTo(s.alternatives);
  return out;
}

double ReadoutOccam(const SelectedGroup& group) {
  const int n = static_cast<int>(group.columns.size());
  if (n == 0 || group.covariance.rows() != n) return 0.0;
  VectorXd a(n), prior_sigma(n);
  for (int i = 0; i < n; ++i) {
    a(i) = group.columns[i].value;
    prior_sigma(i) = group.columns[i].prior_sigma;
  }
  return LaplaceOccam(a, group.covariance, prior_sigma);
}

double LaplaceOccam(const VectorXd& a, const Eigen::MatrixXd& P, const VectorXd& prior_sigma) {
  const int n = static_cast<int>(a.size());
  if (n == 0 || P.rows() != n || prior_sigma.size() != n) return 0.0;
  const VectorXd p0 = prior_sigma.array().square();
  const Eigen::LDLT<Eigen::MatrixXd> ldlt(P);
  double log_det_p = 0.0;
  for (int i = 0; i < n; ++i) log_det_p += std::log(std::max(ldlt.vectorD()(i), 1e-300));
  return p0.array().log().sum() - log_det_p + a.cwiseQuotient(p0).dot(a);
}

WhitenedSeries WhitenSeries(const DeviationSeries& series, double random_walk, double w0_sigma,
                            const OpenEndedOptions& options,
                            const std::vector<std::vector<Vector2d>>& extra) {
  return SeriesWhitener(series, random_walk, w0_sigma, options).With(extra);
}

SeriesWhitener::SeriesWhitener(const DeviationSeries& series, double random_walk,
                               double w0_sigma, const OpenEndedOptions& options)
    : filter_(std::make_shared<const DeviationFilter>(series, random_walk, w0_sigma)) {
  base_.y_w = filter_->Whiten(series.y);
  const GyroBasis basis = EnumerateBasis(series, options);
  for (const BasisColumn& col : basis.columns) {
    if (!col.nuisance) continue;
    base_.nuisance_w.push_back(filter_->Whiten(ColumnSignature(series, col)));
    base_.nuisance_prior.push_back(ColumnPrior(col, options));
  }
}

WhitenedSeries SeriesWhitener::With(const std::vector<std::vector<Vector2d>>& extra) const {
  WhitenedSeries out = base_;
  for (const std::vector<Vector2d>& x : extra) out.extra_w.push_back(filter_->Whiten(x));
  return out;
}

std::string DescribeGroup(const SelectedGroup& group, const OpenEndedOptions& options) {
  const double deg_h = RadPerSecToDegPerHour(1.0);
  std::string text;
  if (group.columns.empty()) return text;
  if (group.columns.front().column.readout) {
    const Matrix3d E = ReadoutDistortion(group);
    const Matrix3d sigma = ReadoutDistortionSigma(group);
    std::vector<std::string> entries;
    static constexpr std::array<std::pair<int, int>, 6> kEntries = {
        {{0, 0}, {1, 1}, {2, 2}, {0, 1}, {1, 2}, {2, 0}}};
    for (const auto& [r, c] : kEntries) {
      entries.push_back(absl::StrFormat("E_%c%c %.0f +- %.0f", "xyz"[r], "xyz"[c], E(r, c) * 1e6,
                                        sigma(r, c) * 1e6));
    }
    text = absl::StrFormat(
        "readout distortion of the direction cosines (scale-factor errors of the channels on the "
        "diagonal, non-orthogonality off it: the reading is (I + E) h normalised; a scale factor "
        "common to the three channels does not change it and is not observable, so E is "
        "traceless), E in ppm: %s",
        absl::StrJoin(entries, ", "));
  } else {
    const BasisTerm& t0 = group.columns.front().column.term;
    const double to_json = BasisValueToJson(t0.kind);
    Vector3d v = Vector3d::Zero(), cos_v = Vector3d::Zero(), sin_v = Vector3d::Zero();
    for (const FittedColumn& c : group.columns) {
      const int m = c.column.term.axis - 1;
      v(m) += c.value;
      (c.column.term.sine ? sin_v : cos_v)(m) += c.value;
    }
    switch (t0.kind) {
      case BasisKind::kSpinAxisHarmonic: {
        const int degree = t0.exponents[0] + t0.exponents[1] + t0.exponents[2];
        text = degree == 0
                   ? absl::StrFormat("case-fixed drift along %s (case axes), %.4f deg/h",
                                     Vec(v.normalized(), 1.0, 2), v.norm() * deg_h)
                   : absl::StrFormat(
                         "drift that depends on the spin-axis direction in case axes as %s (a "
                         "harmonic of degree %d), along %s, %.4f deg/h at h = 1",
                         group.label, degree, Vec(v.normalized(), 1.0, 2), v.norm() * deg_h);
        break;
      }
      case BasisKind::kOrbitalHarmonic: {
        // d(t) = C cos(n phase) + S sin(n phase): its largest size over the orbit.
        double amplitude = 0.0;
        Vector3d peak = Vector3d::UnitX();
        for (int i = 0; i < 360; ++i) {
          const double a = i * kPi / 180.0;
          const Vector3d d = cos_v * std::cos(a) + sin_v * std::sin(a);
          if (d.norm() > amplitude) {
            amplitude = d.norm();
            peak = d.normalized();
          }
        }
        text = absl::StrFormat(
            "case-fixed drift along %s (case axes) varying with the orbital phase (period %.1f "
            "min, harmonic %d), amplitude %.4f deg/h: %s cos + %s sin deg/h",
            Vec(peak, 1.0, 2), options.orbital_period_s / 60.0, t0.harmonic,
            amplitude * deg_h, Vec(cos_v, deg_h), Vec(sin_v, deg_h));
        break;
      }
      case BasisKind::kRamp:
        text = absl::StrFormat(
            "case-fixed drift growing linearly in time along %s (case axes), %.4f deg/h per "
            "hour (zero at the recording's start)",
            Vec(v.normalized(), 1.0, 2), v.norm() * to_json);
        break;
      case BasisKind::kRampHarmonic:
        text = absl::StrFormat(
            "a C2-like drift (eq. (9)) growing linearly in time: C2 changing at %s deg/h per hour",
            Vec(-v, to_json));
        break;
      case BasisKind::kBodyRate:
        text = absl::StrFormat(
            "drift proportional to the body rate about case axis %c, along %s, %.4f deg/h per "
            "deg/s",
            "xyz"[t0.index[0] - 1], Vec(v.normalized(), 1.0, 2), v.norm() * to_json);
        break;
      case BasisKind::kBodyRateProduct:
        text = absl::StrFormat(
            "drift proportional to the product of the body rates about case axes %c and %c, "
            "along %s, %.3g deg/h per (deg/s)^2",
            "xyz"[t0.index[0] - 1], "xyz"[t0.index[1] - 1], Vec(v.normalized(), 1.0, 2),
            v.norm() * to_json);
        break;
      case BasisKind::kSuspensionVoltage:
        text = absl::StrFormat(
            "drift proportional to the suspension offset voltage of case axis %c, along %s, "
            "%.4f deg/h per V",
            "xyz"[t0.index[0] - 1], Vec(v.normalized(), 1.0, 2), v.norm() * to_json);
        break;
      case BasisKind::kExponentialDecay:
        text = absl::StrFormat(
            "case-fixed drift along %s (case axes), %.4f deg/h at its onset, decaying with tau = "
            "%.2f h",
            Vec(v.normalized(), 1.0, 2), v.norm() * to_json,
            t0.time_constant / kSecondsPerHour);
        break;
      case BasisKind::kCyclingHarmonic:  // not a group of the basis (turning_displacement.h)
        text = absl::StrFormat("drift along %s (case axes) as %s, %.4f deg/h",
                               Vec(v.normalized(), 1.0, 2), BasisTermLabel(t0),
                               v.norm() * to_json);
        break;
      case BasisKind::kChannel:  // not a group of the basis (channel_candidate.h); for -Wswitch
        text = absl::StrFormat("drift along %s (case axes) follows %s, %.4f deg/h per unit",
                               Vec(v.normalized(), 1.0, 2), BasisTermLabel(t0),
                               v.norm() * to_json);
        break;
    }
  }
  return absl::StrFormat("gyro %d: %s%s", group.gyro, text, DescribeAlternatives(group));
}

std::string DescribeAlternatives(const SelectedGroup& group) {
  std::vector<std::string> alternatives;
  for (const auto& [label, against] : group.alternatives) {
    if (alternatives.size() == 6) break;
    alternatives.push_back(absl::StrFormat("%s (2 ln B %.1f)", label, against));
  }
  if (alternatives.empty()) return "";
  return absl::StrCat("; on this recording it cannot be told apart from ",
                      absl::StrJoin(alternatives, ", "),
                      " (2 ln B of each against the named term above -6: the data favour the "
                      "named term by a Bayes factor below 20)");
}

}  // namespace esg::estimator::discovery
