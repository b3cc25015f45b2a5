#include "estimator/discovery/profile_interval.h"

namespace esg::estimator::discovery {

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
