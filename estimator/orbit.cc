#include "estimator/orbit.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/utc_time.h"

namespace esg::estimator {

OrbitState InterpolateHermite(const OrbitState& a, const OrbitState& b, absl::Time t) {
  const double h = absl::ToDoubleSeconds(b.time - a.time);
  const double s = absl::ToDoubleSeconds(t - a.time) / h;
  const double s2 = s * s, s3 = s2 * s;
  const double h00 = 2 * s3 - 3 * s2 + 1, h10 = s3 - 2 * s2 + s;
  const double h01 = -2 * s3 + 3 * s2, h11 = s3 - s2;
  const double d00 = 6 * s2 - 6 * s, d10 = 3 * s2 - 4 * s + 1;
  const double d01 = -6 * s2 + 6 * s, d11 = 3 * s2 - 2 * s;
  OrbitState out;
  out.time = t;
  out.r_in_km = h00 * a.r_in_km + h10 * h * a.v_in_km_s + h01 * b.r_in_km + h11 * h * b.v_in_km_s;
  out.v_in_km_s = (d00 * a.r_in_km + d01 * b.r_in_km) / h + d10 * a.v_in_km_s + d11 * b.v_in_km_s;
  return out;
}

double HermiteErrorBoundKm(const OrbitState& a, const OrbitState& b) {
  const double h = absl::ToDoubleSeconds(b.time - a.time);
  double bound = 0.0;
  for (const OrbitState* s : {&a, &b}) {
    const double r = s->r_in_km.norm();
    const double w = s->v_in_km_s.norm() / r;  // [rad/s]
    bound = std::max(bound, r * std::pow(w * h, 4) / 384.0);
  }
  return bound;
}

OrbitState CircularOrbitState(double inclination_rad, double raan_rad, double period_s,
                              double arg_latitude0_rad, absl::Time epoch, double t_s) {
  const double n = 2.0 * M_PI / period_s;
  const double r_km = std::cbrt(kEarthGmKm3S2 / (n * n));
  const Eigen::Vector3d x_p(std::cos(raan_rad), std::sin(raan_rad), 0.0);
  const Eigen::Vector3d y_p(-std::sin(raan_rad) * std::cos(inclination_rad),
                            std::cos(raan_rad) * std::cos(inclination_rad), std::sin(inclination_rad));
  const double u = arg_latitude0_rad + n * t_s;
  OrbitState s;
  s.time = epoch + absl::Seconds(t_s);
  s.r_in_km = r_km * (std::cos(u) * x_p + std::sin(u) * y_p);
  s.v_in_km_s = r_km * n * (-std::sin(u) * x_p + std::cos(u) * y_p);
  return s;
}

double KeplerPeriodS(const OrbitState& state) {
  const double inverse_a = 2.0 / state.r_in_km.norm() - state.v_in_km_s.squaredNorm() / kEarthGmKm3S2;
  if (!(inverse_a > 0.0)) return std::numeric_limits<double>::infinity();
  const double a_km = 1.0 / inverse_a;
  return 2.0 * M_PI * std::sqrt(a_km * a_km * a_km / kEarthGmKm3S2);
}

absl::StatusOr<Orbit> Orbit::FromArcs(std::vector<OrbitArc> arcs,
                                      const std::vector<std::string>& arc_names) {
  if (arcs.empty()) return absl::InvalidArgumentError("arcs: an orbit needs at least one arc");
  for (size_t i = 0; i < arcs.size(); ++i) {
    const OrbitArc& arc = arcs[i];
    // What an error calls the arc, up to its field: "arcs[1]." or the caller's name.
    const std::string at =
        i < arc_names.size() ? arc_names[i] : absl::StrCat("arcs[", i, "].");
    if (arc.states.size() < 2) {
      return absl::InvalidArgumentError(
          absl::StrCat(at, "states: an arc needs at least 2 states, got ", arc.states.size()));
    }
    for (size_t j = 0; j < arc.states.size(); ++j) {
      const OrbitState& s = arc.states[j];
      const std::string state = absl::StrCat(at, "states[", j, "]");
      if (!s.r_in_km.allFinite()) return absl::InvalidArgumentError(state + ".r_in_km: not finite");
      if (!s.v_in_km_s.allFinite()) {
        return absl::InvalidArgumentError(state + ".v_in_km_s: not finite");
      }
      if (s.r_in_km.norm() < kEarthPolarRadiusKm) {
        return absl::InvalidArgumentError(absl::StrFormat(
            "%s.r_in_km: %.3f km from the Earth's centre, inside the Earth (the polar radius is "
            "%.3f km): not a position from the Earth's centre in km",
            state, s.r_in_km.norm(), kEarthPolarRadiusKm));
      }
      if (j == 0) continue;
      const OrbitState& prev = arc.states[j - 1];
      if (s.time <= prev.time) {
        return absl::InvalidArgumentError(absl::StrCat(state, ".time: ", FormatUtc(s.time),
                                                       " is not after the previous state's ",
                                                       FormatUtc(prev.time)));
      }
      const double error_km = HermiteErrorBoundKm(prev, s);
      if (error_km > kMaxInterpolationErrorKm) {
        return absl::InvalidArgumentError(absl::StrFormat(
            "%s.time: states %.0f s apart (%s to %s): interpolating between them may be off by "
            "up to %.3g km, more than %.3g km; deliver states closer together",
            state, absl::ToDoubleSeconds(s.time - prev.time), FormatUtc(prev.time),
            FormatUtc(s.time), error_km, kMaxInterpolationErrorKm));
      }
    }
    if (!(arc.from <= arc.to) || arc.from < arc.states.front().time ||
        arc.to > arc.states.back().time) {
      return absl::InvalidArgumentError(absl::StrCat(
          at, "from/to: ", FormatUtc(arc.from), " to ", FormatUtc(arc.to),
          " is empty or not inside its states' span ", FormatUtc(arc.states.front().time), " to ",
          FormatUtc(arc.states.back().time)));
    }
  }
  return Orbit(std::move(arcs));
}

absl::StatusOr<OrbitState> Orbit::StateAt(absl::Time t) const {
  for (auto arc = arcs_.rbegin(); arc != arcs_.rend(); ++arc) {
    if (t < arc->from || t > arc->to) continue;
    const auto next = std::upper_bound(arc->states.begin(), arc->states.end(), t,
                                       [](absl::Time x, const OrbitState& s) { return x < s.time; });
    if (next == arc->states.begin()) return arc->states.front();
    if (next == arc->states.end()) return arc->states.back();  // t is the last state's time
    return InterpolateHermite(*(next - 1), *next, t);
  }
  std::string coverage;
  for (const OrbitArc& arc : arcs_) {
    absl::StrAppend(&coverage, coverage.empty() ? "" : ", ", FormatUtc(arc.from), " to ",
                    FormatUtc(arc.to));
  }
  return absl::OutOfRangeError(
      absl::StrCat("orbit: no arc covers ", FormatUtc(t), " (covered: ", coverage, ")"));
}

std::vector<TimeInterval> Orbit::Gaps(absl::Time from, absl::Time to) const {
  std::vector<std::pair<absl::Time, absl::Time>> covered;
  for (const OrbitArc& arc : arcs_) covered.emplace_back(arc.from, arc.to);
  std::sort(covered.begin(), covered.end());
  std::vector<TimeInterval> gaps;
  absl::Time cursor = from;  // everything before it is covered or reported
  for (const auto& [a, b] : covered) {
    if (cursor > to) break;
    if (a > cursor) {
      // The gap ends just before a: [cursor, a) holds the same instants as [cursor, a - 1 ns].
      gaps.push_back(TimeInterval{cursor, std::min(to, a - absl::Nanoseconds(1))});
    }
    if (b >= cursor) cursor = b + absl::Nanoseconds(1);
  }
  if (cursor <= to) gaps.push_back(TimeInterval{cursor, to});
  return gaps;
}

}  // namespace esg::estimator
