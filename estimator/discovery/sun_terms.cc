#include "estimator/discovery/sun_terms.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/rotation.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Matrix3d;
using Eigen::Vector3d;

namespace {

// chi-square(1) 95% quantile: the lag's likelihood-ratio interval, as the drift step's onset's.
constexpr double kInterval95 = 3.84;

// The crossing of `level` between grid points a (above it) and b (below), linear in log(lag).
double Crossing(double lag_a, double e_a, double lag_b, double e_b, double level) {
  const double f = (e_a - level) / (e_a - e_b);
  return std::exp(std::log(lag_a) + f * (std::log(lag_b) - std::log(lag_a)));
}

bool IsOrbital(const std::string& label) { return absl::StartsWith(label, "orbit "); }
bool IsConstant(const std::string& label) { return label == "1"; }

}  // namespace

std::vector<SunRegressors> SunRegressorsOf(const std::vector<DeviationSeries>& series,
                                           const SpacecraftConfig& config,
                                           const std::vector<GyroEstimate>& estimates,
                                           std::string* note, const Orbit* orbit) {
  std::vector<SunRegressors> out;
  for (const DeviationSeries& s : series) {
    auto r = ComputeSunRegressors(s, ModelMounting_b_k(config, estimates, s.gyro), orbit);
    if (!r.ok()) {
      if (note != nullptr) {
        *note = absl::StrCat("no sun regressors: ", r.status().message());
      }
      return {};
    }
    out.push_back(std::move(*r));
  }
  return out;
}

Matrix3d ModelMounting_b_k(const SpacecraftConfig& config,
                           const std::vector<GyroEstimate>& estimates, int gyro) {
  const GyroConfig* gc = config.FindGyro(gyro);
  if (gc == nullptr) return Matrix3d::Identity();
  for (const GyroEstimate& e : estimates) {
    if (e.id == gyro) return ExpMatrix(e.misalignment_b) * gc->C_b_k;  // session.h
  }
  return gc->C_b_k;
}

LagInterval SunLagInterval(const SelectedGroup& group) {
  LagInterval out;
  const std::vector<double>& lag = group.lag_hours;
  const std::vector<double>& e = group.lag_evidence;
  if (lag.empty() || lag.size() != e.size()) return out;
  const int n = static_cast<int>(lag.size());
  const int top = static_cast<int>(std::max_element(e.begin(), e.end()) - e.begin());
  const double level = e[top] - kInterval95;
  out.best = out.lower = out.upper = lag[top];
  int i = top;
  while (i > 0 && e[i - 1] >= level) --i;
  out.lower = i == 0 ? lag.front() : Crossing(lag[i], e[i], lag[i - 1], e[i - 1], level);
  i = top;
  while (i < n - 1 && e[i + 1] >= level) ++i;
  out.upper = i == n - 1 ? lag.back() : Crossing(lag[i], e[i], lag[i + 1], e[i + 1], level);
  return out;
}

Vector3d SunAmplitude_k(const SelectedGroup& group) {
  if (!group.lag_averaged_k.isZero(0.0)) return group.lag_averaged_k;
  return SunAmplitudeAtBestLag_k(group);
}

Vector3d SunAmplitudeAtBestLag_k(const SelectedGroup& group) {
  Vector3d a = Vector3d::Zero();
  for (const FittedColumn& c : group.columns) a(c.column.term.axis - 1) += c.value;
  return a;
}

Matrix3d SunAmplitudeCovariance_k(const SelectedGroup& group) {
  if (!group.lag_averaged_covariance_k.isZero(0.0)) return group.lag_averaged_covariance_k;
  Matrix3d P = Matrix3d::Zero();
  const int n = static_cast<int>(group.columns.size());
  if (group.covariance.rows() != n) return P;
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      P(group.columns[i].column.term.axis - 1, group.columns[j].column.term.axis - 1) +=
          group.covariance(i, j);
    }
  }
  return P;
}

std::string DescribeSunGroup(const SelectedGroup& group, bool shadowed) {
  const double deg_h = RadPerSecToDegPerHour(1.0);
  const Vector3d a = SunAmplitude_k(group);
  const Matrix3d P = SunAmplitudeCovariance_k(group);
  const Vector3d u = a.normalized();
  const double size_sigma = std::sqrt(std::max(0.0, u.dot(P * u)));
  const LagInterval lag = SunLagInterval(group);
  std::string text =
      group.sun_face == kSunlitFamily
          ? absl::StrFormat(
                "drift along (%.2f, %.2f, %.2f) (case axes) follows the eclipses of the orbit "
                "with a %.2g h lag (95%% interval %.2g-%.2g h), %.4f +- %.4f deg/h in sunlight "
                "against the Earth's shadow: the fraction of the sun's disc seen from the orbit "
                "(1 in sunlight, 0 in the umbra), whatever the attitude, through a first-order "
                "thermal lag (heaters or the whole spacecraft cooling in the shadow, not one "
                "face's illumination)",
                u.x(), u.y(), u.z(), lag.best, lag.lower, lag.upper, a.norm() * deg_h,
                size_sigma * deg_h)
          : absl::StrFormat(
                "drift along (%.2f, %.2f, %.2f) (case axes) follows the sun on body face %s with "
                "a %.2g h lag (95%% interval %.2g-%.2g h), %.4f +- %.4f deg/h at full "
                "illumination: the face's illumination max(0, n . s_b)%s, s_b the sun's "
                "direction in body axes, through a first-order thermal lag",
                u.x(), u.y(), u.z(), SunFaceName(group.sun_face), lag.best, lag.lower, lag.upper,
                a.norm() * deg_h, size_sigma * deg_h,
                shadowed ? " times the fraction of the sun's disc seen from the orbit (0 in the "
                           "Earth's shadow)"
                         : "");
  std::vector<std::string> cannot;
  for (const auto& [label, against] : group.alternatives) {
    if (IsOrbital(label) && cannot.size() < 2 &&
        std::none_of(cannot.begin(), cannot.end(), [](const std::string& c) {
          return absl::StrContains(c, "orbit");
        })) {
      cannot.push_back(absl::StrFormat(
          "a drift cycling with the orbit (\"%s\", 2 ln B %.1f: in a steady orbital orientation "
          "the sun turns about the body once an orbit)",
          label, against));
    }
    if (IsConstant(label)) {
      cannot.push_back(absl::StrFormat(
          "a constant case-fixed drift (\"1\", 2 ln B %.1f: the sun fixed in body axes, as in an "
          "inertial hold)",
          against));
    }
  }
  if (!cannot.empty()) {
    absl::StrAppend(&text, "; the recording cannot tell it from ", absl::StrJoin(cannot, ", nor "));
  }
  return text;
}

std::vector<Parameter> SunParameters(const SelectedGroup& group) {
  const double deg_h = RadPerSecToDegPerHour(1.0);
  const Vector3d a = SunAmplitude_k(group);
  const Matrix3d P = SunAmplitudeCovariance_k(group);
  std::vector<Parameter> out;
  for (int i = 0; i < 3; ++i) {
    out.push_back(Parameter{absl::StrCat("sunDriftDegH[", i, "]"), a(i) * deg_h,
                            std::sqrt(std::max(0.0, P(i, i))) * deg_h, "deg/h"});
  }
  const Vector3d u = a.normalized();
  out.push_back(Parameter{"sunDriftSizeDegH", a.norm() * deg_h,
                          std::sqrt(std::max(0.0, u.dot(P * u))) * deg_h, "deg/h"});
  const LagInterval lag = SunLagInterval(group);
  out.push_back(Parameter{"sunLagHours", lag.best, 0.5 * (lag.upper - lag.lower), "h"});
  out.push_back(Parameter{"sunLagLowerHours", lag.lower, 0.0, "h"});
  out.push_back(Parameter{"sunLagUpperHours", lag.upper, 0.0, "h"});
  const Vector3d n_b = SunFaceNormal_b(group.sun_face);
  for (int i = 0; i < 3; ++i) {
    out.push_back(Parameter{absl::StrCat("sunFaceNormalB[", i, "]"), n_b(i), 0.0, "1"});
  }
  return out;
}

ReadingShift SunReadingShift(const SelectedGroup& group, const DeviationSeries& series,
                             const SunRegressors& sun, const std::vector<TelemetryFrame>& frames,
                             const CarriedAttitude& attitude, const Matrix3d& C_b_k) {
  ReadingShift out;
  out.gyro = group.gyro;
  auto dh_k = std::make_shared<std::vector<Vector3d>>(frames.size(), Vector3d::Zero());
  out.dh_k = dh_k;
  if (group.columns.empty() || group.sun_face < 0) return out;
  const int lag = group.columns.front().column.sun_lag;
  if (group.sun_face >= static_cast<int>(sun.values.size()) ||
      lag >= static_cast<int>(sun.values[group.sun_face].size())) {
    return out;
  }
  const std::vector<Vector3d> motion_in =
      TabulatedMotion_in(series, sun.values[group.sun_face][lag], SunAmplitudeAtBestLag_k(group));
  // Each frame takes the motion of the substeps before it (their midpoints precede it).
  size_t step = 0;
  Vector3d dh_in = Vector3d::Zero();
  for (size_t j = 0; j < frames.size(); ++j) {
    while (step < motion_in.size() && series.steps[step].inputs.time < frames[j].time) {
      dh_in = motion_in[step];
      ++step;
    }
    if (j >= attitude.known.size() || !attitude.known[j]) continue;
    const Matrix3d C_in_k = attitude.q_in_b[j].toRotationMatrix() * C_b_k;
    (*dh_k)[j] = C_in_k.transpose() * dh_in;
  }
  return out;
}

std::string HeldSunGroupName(int gyro, const std::string& label) {
  return absl::StrCat(kEffectBasisTerm, "[", gyro, "] ", label);
}

std::vector<int> HeldSunFaces(const ModelState& model, int gyro) {
  std::vector<int> out;
  for (int face = 0; face <= kSunlitFamily; ++face) {
    const std::string prefix = HeldSunGroupName(gyro, absl::StrCat("sun ", SunFaceName(face), " "));
    for (const std::string& added : model.added) {
      if (absl::StartsWith(added, prefix)) {
        out.push_back(face);
        break;
      }
    }
  }
  return out;
}

}  // namespace esg::estimator::discovery
