#include "estimator/discovery/sun_regressors.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "absl/strings/str_format.h"
#include "estimator/eclipse.h"
#include "estimator/sun_direction.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Matrix3d;
using Eigen::Vector3d;

namespace {

constexpr double kSunTableStepS = 600.0;
constexpr double kFirstLagHours = 0.1;
constexpr double kLastLagHours = 10.0;
constexpr int kLagsPerDecade = 20;

// A vector of the sun's computed at nodes kSunTableStepS apart from t0, one node past t1, and
// interpolated linearly between them (clamped to the table's ends).
class SunTable {
 public:
  static absl::StatusOr<SunTable> Make(absl::Time t0, absl::Time t1,
                                       absl::StatusOr<Vector3d> (*at)(absl::Time)) {
    SunTable table;
    table.t0_ = t0;
    const int n = 2 + static_cast<int>(absl::ToDoubleSeconds(t1 - t0) / kSunTableStepS);
    for (int i = 0; i < n; ++i) {
      absl::StatusOr<Vector3d> v = at(t0 + absl::Seconds(i * kSunTableStepS));
      if (!v.ok()) return v.status();
      table.nodes_.push_back(*v);
    }
    return table;
  }

  Vector3d At(absl::Time t) const {
    const int n = static_cast<int>(nodes_.size());
    const double x = absl::ToDoubleSeconds(t - t0_) / kSunTableStepS;
    const int i = std::clamp(static_cast<int>(std::floor(x)), 0, n - 2);
    const double f = std::clamp(x - i, 0.0, 1.0);
    return (1.0 - f) * nodes_[i] + f * nodes_[i + 1];
  }

 private:
  absl::Time t0_;
  std::vector<Vector3d> nodes_;
};

}  // namespace

std::string SunFaceName(int face) {
  if (face == kSunlitFamily) return "sunlit";
  return std::string(face % 2 == 0 ? "+" : "-") + std::string(1, "xyz"[std::clamp(face / 2, 0, 2)]);
}

Vector3d SunFaceNormal_b(int face) {
  if (face == kSunlitFamily) return Vector3d::Zero();
  return (face % 2 == 0 ? 1.0 : -1.0) * Vector3d::Unit(std::clamp(face / 2, 0, 2));
}

double FaceIllumination(const Vector3d& s_b, int face) {
  return std::max(0.0, SunFaceNormal_b(face).dot(s_b));
}

std::vector<double> SunLagGridHours() {
  std::vector<double> out;
  const int n = static_cast<int>(
      std::lround(kLagsPerDecade * std::log10(kLastLagHours / kFirstLagHours)));
  for (int i = 0; i <= n; ++i) {
    out.push_back(kFirstLagHours * std::pow(10.0, static_cast<double>(i) / kLagsPerDecade));
  }
  return out;
}

std::vector<double> LaggedIllumination(const std::vector<double>& u, const std::vector<double>& dt,
                                       double tau_s) {
  std::vector<double> y(u.size(), 0.0);
  if (u.empty()) return y;
  double start = u.front();  // y at the start of the substep
  for (size_t i = 0; i < u.size(); ++i) {
    const double h = i < dt.size() ? dt[i] : 0.0;
    y[i] = u[i] + (start - u[i]) * std::exp(-0.5 * h / tau_s);  // at the midpoint
    start = u[i] + (start - u[i]) * std::exp(-h / tau_s);
  }
  return y;
}

absl::StatusOr<std::vector<Vector3d>> SunAlongSeries_in(const DeviationSeries& series) {
  std::vector<Vector3d> out;
  if (series.steps.empty()) return out;
  absl::StatusOr<SunTable> table = SunTable::Make(
      series.steps.front().inputs.time, series.steps.back().inputs.time, &SunDirection_in);
  if (!table.ok()) return table.status();
  for (const TrajectoryStep& step : series.steps) {
    out.push_back(table->At(step.inputs.time).normalized());
  }
  return out;
}

absl::StatusOr<std::vector<double>> SunlitAlongSeries(const DeviationSeries& series,
                                                      const Orbit& orbit) {
  std::vector<double> out;
  if (series.steps.empty()) return out;
  absl::StatusOr<SunTable> sun_km = SunTable::Make(
      series.steps.front().inputs.time - absl::Seconds(0.5 * series.steps.front().dt),
      series.steps.back().inputs.time + absl::Seconds(0.5 * series.steps.back().dt),
      &SunPosition_in_km);
  if (!sun_km.ok()) return sun_km.status();
  auto sunlit = [&](absl::Time t) -> absl::StatusOr<double> {
    absl::StatusOr<OrbitState> state = orbit.StateAt(t);
    if (!state.ok()) return state.status();
    return SunlitFraction(state->r_in_km, sun_km->At(t));
  };
  for (const TrajectoryStep& step : series.steps) {
    const absl::Duration half = absl::Seconds(0.5 * step.dt);
    double sum = 0.0;
    for (const auto& [offset, weight] :
         {std::pair{-half, 1.0}, std::pair{absl::ZeroDuration(), 4.0}, std::pair{half, 1.0}}) {
      absl::StatusOr<double> nu = sunlit(step.inputs.time + offset);
      if (!nu.ok()) return nu.status();
      sum += weight * *nu;
    }
    out.push_back(sum / 6.0);
  }
  return out;
}

absl::StatusOr<SunRegressors> ComputeSunRegressors(const DeviationSeries& series,
                                                   const Matrix3d& C_b_k, const Orbit* orbit) {
  auto sun_in = SunAlongSeries_in(series);
  if (!sun_in.ok()) return sun_in.status();
  std::vector<double> nu(series.steps.size(), 1.0);
  if (orbit != nullptr) {
    absl::StatusOr<std::vector<double>> lit = SunlitAlongSeries(series, *orbit);
    if (!lit.ok()) return lit.status();
    nu = *std::move(lit);
  }
  SunRegressors out;
  out.gyro = series.gyro;
  out.lag_hours = SunLagGridHours();
  std::vector<double> dt;
  std::vector<Vector3d> s_b;
  for (size_t i = 0; i < series.steps.size(); ++i) {
    const TrajectoryStep& step = series.steps[i];
    dt.push_back(step.dt);
    // s_b = C_b_k C_k_in s_in, C_k_in = C_in_k^T.
    s_b.push_back(C_b_k * (step.C_in_k.transpose() * (*sun_in)[i]));
  }
  out.values.resize(orbit != nullptr ? kSunFaces + 1 : kSunFaces);
  for (int face = 0; face < static_cast<int>(out.values.size()); ++face) {
    std::vector<double> u;
    for (size_t i = 0; i < s_b.size(); ++i) {
      u.push_back(face == kSunlitFamily ? nu[i] : nu[i] * FaceIllumination(s_b[i], face));
    }
    for (double lag_h : out.lag_hours) {
      out.values[face].push_back(LaggedIllumination(u, dt, HoursToSeconds(lag_h)));
    }
  }
  return out;
}

const SunRegressors* FindSunRegressors(const std::vector<SunRegressors>& sun, int gyro) {
  for (const SunRegressors& r : sun) {
    if (r.gyro == gyro) return &r;
  }
  return nullptr;
}

std::string SunGroupLabel(int face, double lag_hours) {
  return absl::StrFormat("sun %s lag %.3g h", SunFaceName(face), lag_hours);
}

std::vector<Eigen::Vector2d> TabulatedSignature(const DeviationSeries& series,
                                                const std::vector<double>& s,
                                                const Vector3d& e_m) {
  std::vector<Eigen::Vector2d> out(series.sample_end.size(), Eigen::Vector2d::Zero());
  Vector3d sum = Vector3d::Zero();
  size_t step = 0;
  for (size_t k = 0; k < series.sample_end.size(); ++k) {
    for (; step < static_cast<size_t>(series.sample_end[k]) && step < s.size(); ++step) {
      const TrajectoryStep& st = series.steps[step];
      sum += (st.C_in_k * (s[step] * e_m)).cross(st.h_in) * st.dt;
    }
    out[k] = Eigen::Vector2d(series.u1.dot(sum), series.u2.dot(sum));
  }
  return out;
}

std::array<std::vector<Eigen::Vector2d>, 3> TabulatedSignatures(const DeviationSeries& series,
                                                                const std::vector<double>& s) {
  std::array<std::vector<Eigen::Vector2d>, 3> out;
  for (std::vector<Eigen::Vector2d>& o : out) {
    o.assign(series.sample_end.size(), Eigen::Vector2d::Zero());
  }
  const std::array<Vector3d, 3> e = {Vector3d::UnitX(), Vector3d::UnitY(), Vector3d::UnitZ()};
  std::array<Vector3d, 3> sum = {Vector3d::Zero(), Vector3d::Zero(), Vector3d::Zero()};
  size_t step = 0;
  for (size_t k = 0; k < series.sample_end.size(); ++k) {
    for (; step < static_cast<size_t>(series.sample_end[k]) && step < s.size(); ++step) {
      const TrajectoryStep& st = series.steps[step];
      for (int m = 0; m < 3; ++m) sum[m] += (st.C_in_k * (s[step] * e[m])).cross(st.h_in) * st.dt;
    }
    for (int m = 0; m < 3; ++m) {
      out[m][k] = Eigen::Vector2d(series.u1.dot(sum[m]), series.u2.dot(sum[m]));
    }
  }
  return out;
}

double TabulatedRms(const DeviationSeries& series, const std::vector<double>& s) {
  double sum = 0.0, time = 0.0;
  for (size_t i = 0; i < series.steps.size() && i < s.size(); ++i) {
    sum += s[i] * s[i] * series.steps[i].dt;
    time += series.steps[i].dt;
  }
  return time > 0.0 ? std::sqrt(sum / time) : 0.0;
}

std::vector<Vector3d> TabulatedMotion_in(const DeviationSeries& series,
                                         const std::vector<double>& s, const Vector3d& a_k) {
  std::vector<Vector3d> out;
  Vector3d sum = Vector3d::Zero();
  for (size_t i = 0; i < series.steps.size() && i < s.size(); ++i) {
    const TrajectoryStep& st = series.steps[i];
    sum += (st.C_in_k * (s[i] * a_k)).cross(st.h_in) * st.dt;
    out.push_back(sum);
  }
  return out;
}

double AverageEvidence(const std::vector<double>& evidence) {
  if (evidence.empty()) return -std::numeric_limits<double>::infinity();
  const double top = *std::max_element(evidence.begin(), evidence.end());
  double sum = 0.0;
  for (double e : evidence) sum += std::exp(0.5 * (e - top));
  return top + 2.0 * std::log(sum / static_cast<double>(evidence.size()));
}

}  // namespace esg::estimator::discovery
