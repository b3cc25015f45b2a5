#include "estimator/discovery/profile_interval.h"

#include <algorithm>
#include <cmath>
#include <limits>

namespace esg::estimator::discovery {

Parabola ParabolaThrough(double x0, double y0, double x1, double y1, double x2, double y2) {
  Parabola p;
  const double a = ((y2 - y1) / (x2 - x1) - (y1 - y0) / (x1 - x0)) / (x2 - x0);
  if (!(a > 0.0)) return p;
  p.ok = true;
  p.curvature = a;
  // The vertex: where the parabola's slope, (y1 - y0) / (x1 - x0) + a (2 x - x0 - x1), is zero.
  p.vertex = std::clamp(0.5 * (x0 + x1) - (y1 - y0) / (x1 - x0) / (2.0 * a), x0, x2);
  return p;
}

std::vector<double> TrapezoidWeights(const ProfilePoints& profile, double span) {
  std::vector<double> weights;
  for (size_t j = 0; j < profile.size(); ++j) {
    const double left = j > 0 ? profile[j].first - profile[j - 1].first : 0.0;
    const double right = j + 1 < profile.size() ? profile[j + 1].first - profile[j].first : 0.0;
    weights.push_back(0.5 * (left + right) / span);
  }
  return weights;
}

double IntegratedDeviance(const std::vector<std::pair<double, double>>& points) {
  double best = std::numeric_limits<double>::infinity();
  for (const auto& [w, v] : points) best = std::min(best, v);
  double sum = 0.0;
  for (const auto& [w, v] : points) sum += w * std::exp(-0.5 * (v - best));
  return best - 2.0 * std::log(sum);
}

size_t ProfileMinimum(const ProfilePoints& profile) {
  size_t best = 0;
  for (size_t j = 0; j < profile.size(); ++j) {
    if (profile[j].second < profile[best].second) best = j;
  }
  return best;
}

LevelInterval IntervalAtLevel(const ProfilePoints& profile, size_t best, double level) {
  auto crossing = [&](size_t inside, size_t outside) {
    const auto [x0, y0] = profile[inside];
    const auto [x1, y1] = profile[outside];
    return y1 > y0 ? x0 + (x1 - x0) * (level - y0) / (y1 - y0) : x1;
  };
  LevelInterval in;
  in.lower = profile.front().first;
  in.upper = profile.back().first;
  for (size_t j = best; j > 0; --j) {
    if (profile[j - 1].second > level) {
      in.lower = crossing(j, j - 1);
      in.lower_open = false;
      break;
    }
  }
  for (size_t j = best; j + 1 < profile.size(); ++j) {
    if (profile[j + 1].second > level) {
      in.upper = crossing(j, j + 1);
      in.upper_open = false;
      break;
    }
  }
  return in;
}

std::optional<double> WidestEndBracketMiddle(const ProfilePoints& points, double drop,
                                             double resolution) {
  const size_t top = ProfileMinimum(points);
  const double level = points[top].second + drop;
  double widest = 0.0, middle = 0.0;
  size_t j = top;
  while (j > 0 && points[j - 1].second <= level) --j;
  if (j > 0 && points[j].first - points[j - 1].first > widest) {
    widest = points[j].first - points[j - 1].first;
    middle = 0.5 * (points[j].first + points[j - 1].first);
  }
  j = top;
  while (j + 1 < points.size() && points[j + 1].second <= level) ++j;
  if (j + 1 < points.size() && points[j + 1].first - points[j].first > widest) {
    widest = points[j + 1].first - points[j].first;
    middle = 0.5 * (points[j].first + points[j + 1].first);
  }
  if (!(widest > resolution)) return std::nullopt;
  return middle;
}

}  // namespace esg::estimator::discovery
