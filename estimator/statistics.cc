#include "estimator/statistics.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <tuple>
#include <utility>

namespace esg::estimator {

namespace {

constexpr double kEps = 1e-15;
constexpr double kTiny = 1e-300;

// Series for P(a, x), x < a + 1.
double GammaSeries(double a, double x) {
  double sum = 1.0 / a, term = sum, ap = a;
  for (int n = 0; n < 1000; ++n) {
    ap += 1.0;
    term *= x / ap;
    sum += term;
    if (std::abs(term) < std::abs(sum) * kEps) break;
  }
  return sum * std::exp(-x + a * std::log(x) - std::lgamma(a));
}

// Continued fraction for Q(a, x) = 1 - P(a, x), x >= a + 1 (modified Lentz).
double GammaContinuedFraction(double a, double x) {
  double b = x + 1.0 - a, c = 1.0 / kTiny, d = 1.0 / b, h = d;
  for (int i = 1; i < 1000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double del = d * c;
    h *= del;
    if (std::abs(del - 1.0) < kEps) break;
  }
  return std::exp(-x + a * std::log(x) - std::lgamma(a)) * h;
}

double GammaQ(double a, double x) {
  if (x <= 0.0) return 1.0;
  if (x < a + 1.0) return 1.0 - GammaSeries(a, x);
  return GammaContinuedFraction(a, x);
}

double BetaContinuedFraction(double x, double a, double b) {
  const double qab = a + b, qap = a + 1.0, qam = a - 1.0;
  double c = 1.0, d = 1.0 - qab * x / qap;
  if (std::abs(d) < kTiny) d = kTiny;
  d = 1.0 / d;
  double h = d;
  for (int m = 1; m < 1000; ++m) {
    const int m2 = 2 * m;
    double aa = m * (b - m) * x / ((qam + m2) * (a + m2));
    d = 1.0 + aa * d;
    if (std::abs(d) < kTiny) d = kTiny;
    c = 1.0 + aa / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    h *= d * c;
    aa = -(a + m) * (qab + m) * x / ((a + m2) * (qap + m2));
    d = 1.0 + aa * d;
    if (std::abs(d) < kTiny) d = kTiny;
    c = 1.0 + aa / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double del = d * c;
    h *= del;
    if (std::abs(del - 1.0) < kEps) break;
  }
  return h;
}


}  // namespace

double RegularizedGammaP(double a, double x) {
  if (x <= 0.0) return 0.0;
  if (x < a + 1.0) return GammaSeries(a, x);
  return 1.0 - GammaContinuedFraction(a, x);
}

double ChiSquareCdf(double x, double k) { return RegularizedGammaP(0.5 * k, 0.5 * x); }

double ChiSquareSurvival(double x, double k) { return GammaQ(0.5 * k, 0.5 * x); }

double ChiSquareQuantile(double p, double k) {
  if (!(p > 0.0)) return 0.0;
  if (!(p < 1.0)) return std::numeric_limits<double>::infinity();
  const double q = 1.0 - p;
  double lo = 0.0, hi = std::max(1.0, k);
  while (ChiSquareSurvival(hi, k) > q) hi *= 2.0;
  for (int i = 0; i < 200; ++i) {
    const double mid = 0.5 * (lo + hi);
    if (ChiSquareSurvival(mid, k) > q) {
      lo = mid;
    } else {
      hi = mid;
    }
    if (hi - lo < 1e-10 * std::max(1.0, hi)) break;
  }
  return 0.5 * (lo + hi);
}

double RegularizedBeta(double x, double a, double b) {
  if (x <= 0.0) return 0.0;
  if (x >= 1.0) return 1.0;
  const double front = std::exp(std::lgamma(a + b) - std::lgamma(a) - std::lgamma(b) +
                                a * std::log(x) + b * std::log1p(-x));
  if (x < (a + 1.0) / (a + b + 2.0)) return front * BetaContinuedFraction(x, a, b) / a;
  return 1.0 - front * BetaContinuedFraction(1.0 - x, b, a) / b;
}

double FSurvival(double f, double d1, double d2) {
  if (!(f > 0.0)) return 1.0;
  // P(F > f) = I_{d2 / (d2 + d1 f)}(d2 / 2, d1 / 2).
  return RegularizedBeta(d2 / (d2 + d1 * f), 0.5 * d2, 0.5 * d1);
}

double NormalSurvival(double z) { return 0.5 * std::erfc(z / std::sqrt(2.0)); }


double Lag1Autocorrelation(const std::vector<double>& x) {
  const size_t n = x.size();
  if (n < 3) return 0.0;
  double mean = 0.0;
  for (double v : x) mean += v;
  mean /= static_cast<double>(n);
  double num = 0.0, den = 0.0;
  for (size_t i = 0; i < n; ++i) {
    den += (x[i] - mean) * (x[i] - mean);
    if (i > 0) num += (x[i] - mean) * (x[i - 1] - mean);
  }
  return den > 0.0 ? num / den : 0.0;
}

bool Significant(double p, double alpha, int tests) { return p < alpha / std::max(1, tests); }

double EvidenceThreshold(double alpha, int comparisons) {
  return 2.0 * std::log(std::max(1, comparisons) / alpha);
}

double EvidenceBound(double evidence) { return std::min(1.0, std::exp(-0.5 * evidence)); }

double EvidenceOverPrior(const std::vector<std::pair<double, double>>& weight_and_evidence) {
  double top = -std::numeric_limits<double>::infinity();
  for (const auto& [w, e] : weight_and_evidence) {
    if (w > 0.0) top = std::max(top, 0.5 * e);
  }
  if (!std::isfinite(top)) return -std::numeric_limits<double>::infinity();
  double sum = 0.0;
  for (const auto& [w, e] : weight_and_evidence) {
    if (w > 0.0) sum += w * std::exp(0.5 * e - top);
  }
  return 2.0 * (top + std::log(sum));
}

}  // namespace esg::estimator
