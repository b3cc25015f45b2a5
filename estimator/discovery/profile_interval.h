// Intervals read off a profile of -2 log L over one parameter (an onset, ln tau): the points
// evaluated, in increasing order of the parameter, each (parameter, -2 log L). Pure functions,
// shared by the time behaviours (time_behaviour.h) and the channel candidate
// (channel_candidate.h).
#ifndef ESG_ESTIMATOR_DISCOVERY_PROFILE_INTERVAL_H_
#define ESG_ESTIMATOR_DISCOVERY_PROFILE_INTERVAL_H_

#include <cstddef>
#include <optional>
#include <utility>
#include <vector>

namespace esg::estimator::discovery {

using ProfilePoints = std::vector<std::pair<double, double>>;

// The drop of -2 log L that bounds a 95% interval of one parameter: chi2inv(0.95, 1).
inline constexpr double kProfileIntervalDrop = 3.841458820694124;

// The parabola y = a (x - vertex)^2 + c through three points x0 < x1 < x2 (a profile's best point
// and its neighbours): `ok` when it has a minimum (a > 0), its vertex clamped to [x0, x2], a its
// curvature.
struct Parabola {
  bool ok = false;
  double vertex = 0.0, curvature = 0.0;
};
Parabola ParabolaThrough(double x0, double y0, double x1, double y1, double x2, double y2);

// The weights of the trapezoid rule on the points of `profile` (increasing in the parameter) for
// a prior uniform across `span`: 0.5 (left gap + right gap) / span each.
std::vector<double> TrapezoidWeights(const ProfilePoints& profile, double span);
// -2 ln of the prior-weighted likelihood over points (weight, -2 log L): the parameter
// integrated over its prior.
double IntegratedDeviance(const std::vector<std::pair<double, double>>& points);

// The first point of the smallest -2 log L.
size_t ProfileMinimum(const ProfilePoints& profile);

struct LevelInterval {
  double lower = 0.0;
  double upper = 0.0;
  // An end the profile never rises above the level beyond: the profile's first (last) point.
  bool lower_open = true;
  bool upper_open = true;
};

// Where the profile stays at or below `level` on either side of its point `best`: each end linear
// between the last point inside and the first beyond (the point beyond itself where the profile
// does not rise between them).
LevelInterval IntervalAtLevel(const ProfilePoints& profile, size_t best, double level);

// The interval's ends resolved by bisection: the middle of the wider of its two end brackets (the
// last point within `drop` of the minimum and the first beyond it) when that bracket is wider than
// `resolution`; nullopt when both ends are resolved.
std::optional<double> WidestEndBracketMiddle(const ProfilePoints& points, double drop,
                                             double resolution);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_PROFILE_INTERVAL_H_
