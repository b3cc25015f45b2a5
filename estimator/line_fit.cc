#include "estimator/line_fit.h"

#include <algorithm>
#include <cmath>
#include <tuple>
#include <utility>

namespace esg::estimator {

namespace {

// Least squares over the points with use[i] (centred sums).
std::pair<double, double> LineFit(const std::vector<double>& t, const std::vector<double>& y,
                                  const std::vector<bool>& use) {
  double n = 0, st = 0, sy = 0;
  for (size_t i = 0; i < t.size(); ++i) {
    if (!use[i]) continue;
    n += 1;
    st += t[i];
    sy += y[i];
  }
  if (n < 1) return {0.0, 0.0};
  const double tm = st / n, ym = sy / n;
  double stt = 0, sty = 0;
  for (size_t i = 0; i < t.size(); ++i) {
    if (!use[i]) continue;
    stt += (t[i] - tm) * (t[i] - tm);
    sty += (t[i] - tm) * (y[i] - ym);
  }
  const double b = (n >= 2 && stt > 0) ? sty / stt : 0.0;
  return {ym - b * tm, b};
}

}  // namespace

RobustLine FitRobustLine(const std::vector<double>& t, const std::vector<double>& y) {
  RobustLine out;
  const size_t n = std::min(t.size(), y.size());
  if (n == 0) return out;
  std::vector<bool> use(n, true);
  auto [a, b] = LineFit(t, y, use);
  std::vector<double> r(n);
  for (size_t i = 0; i < n; ++i) r[i] = std::abs(y[i] - (a + b * t[i]));
  std::vector<double> sorted = r;
  std::nth_element(sorted.begin(), sorted.begin() + n / 2, sorted.end());
  const double mad = sorted[n / 2];
  if (mad > 0.0) {
    for (size_t i = 0; i < n; ++i) use[i] = r[i] <= 5.0 * 1.4826 * mad;
    std::tie(a, b) = LineFit(t, y, use);
  }
  double ss = 0.0;
  int used = 0;
  for (size_t i = 0; i < n; ++i) {
    if (!use[i]) continue;
    const double e = y[i] - (a + b * t[i]);
    ss += e * e;
    ++used;
  }
  out.intercept = a;
  out.slope = b;
  out.used = used;
  out.residual_sigma = used > 2 ? std::sqrt(ss / (used - 2)) : 0.0;
  return out;
}

}  // namespace esg::estimator
