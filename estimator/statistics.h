// Distribution functions and small robust fits for the significance tests of the filter's
// monitors (consistency, widening, drift change, reading faults, star-tracker mount) and of the
// discovery (docs/discovery.md):
// chi-square tail probabilities and quantiles for likelihood-ratio tests, the F distribution
// for tests with an estimated dispersion, Bonferroni levels, and a robust line fit.
#ifndef ESG_ESTIMATOR_STATISTICS_H_
#define ESG_ESTIMATOR_STATISTICS_H_

#include <utility>
#include <vector>

#include "estimator/line_fit.h"

namespace esg::estimator {

// Regularised lower incomplete gamma P(a, x), a > 0, x >= 0 (series / continued fraction).
double RegularizedGammaP(double a, double x);

// P(X <= x) for X ~ chi-square with k > 0 degrees of freedom.
double ChiSquareCdf(double x, double k);
// P(X > x), accurate in the far tail (computed from Q directly).
double ChiSquareSurvival(double x, double k);
// x with ChiSquareCdf(x, k) = p, 0 < p < 1 (bisection on the survival function in log space).
double ChiSquareQuantile(double p, double k);

// Regularised incomplete beta I_x(a, b) (continued fraction).
double RegularizedBeta(double x, double a, double b);
// P(F > f) for F ~ F(d1, d2).
double FSurvival(double f, double d1, double d2);

// Standard normal upper tail P(Z > z).
double NormalSurvival(double z);

// Bonferroni: p is significant at family-wise level alpha over `tests` tests (at least one).
bool Significant(double p, double alpha, int tests);

// Evidence (docs/discovery.md, "Evidence"): e = 2 ln B, B the Bayes factor of a model with an
// effect against the model without it (B = p(data | with) / p(data | without), each parameter
// integrated over its prior). Under the model without the effect E[B] = 1, so by Markov's
// inequality P(B >= M / alpha) <= alpha / M: the threshold 2 ln(M / alpha) holds the chance of
// any false finding among M comparisons below alpha, with no asymptotics and whatever k.
double EvidenceThreshold(double alpha, int comparisons);
// 1 / B = exp(-e / 2), at most 1: the bound on the false-alarm probability of a finding at e.
double EvidenceBound(double evidence);
// The evidence of a parameter integrated over a discrete prior: 2 ln sum_j w_j exp(e_j / 2),
// from the prior weights w_j (summing to 1) and the evidence e_j of the model at each point
// (computed without overflow); -infinity for an empty prior.
double EvidenceOverPrior(const std::vector<std::pair<double, double>>& weight_and_evidence);

// The robust line fit lives in estimator/line_fit.h (shared with the offline gap runs).
using ::esg::estimator::FitRobustLine;
using ::esg::estimator::RobustLine;

// Lag-1 autocorrelation of a series (mean removed); 0 for fewer than 3 values.
double Lag1Autocorrelation(const std::vector<double>& x);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_STATISTICS_H_
