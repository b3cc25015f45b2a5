// The reduced filter of one gyro's deviation series (deviation.h) and the Bayesian regression on
// it (docs/discovery.md, "The open-ended stage"). The series is modelled, in the projection
// basis (u1, u2), as
//
//     y_k = p(t_k) + sum_j beta_j x_j(t_k) + n_k,   dp/dt = w,   dw/dt = white noise (eq. (11)),
//
// p(0) with a wide prior (it absorbs the first sample's noise), w(0) with the session's prior of
// the residual drift, n_k ~ N(0, phi R_k), x_j a regressor's signature and beta_j ~ N(0, s_j^2)
// its coefficient. This is the configured model's residual random walk of eq. (11) and nothing
// else, so a regressor that explains the deviation is a drift the model lacks.
//
// The filter's gains do not depend on the data, so its innovations are a fixed linear map of the
// series (Whiten): the data and every signature are whitened once, and the model with any set
// of regressors is then an ordinary Gaussian linear model whose marginal likelihood has a closed
// form (the augmented-state filter's likelihood, without re-running it per set). The dispersion
// phi is profiled out (as the library's candidates profile their common noise scale).
#ifndef ESG_ESTIMATOR_DISCOVERY_DEVIATION_FILTER_H_
#define ESG_ESTIMATOR_DISCOVERY_DEVIATION_FILTER_H_

#include <vector>

#include "Eigen/Core"
#include "estimator/discovery/deviation.h"

namespace esg::estimator::discovery {

// A drift that returns to its mean (first-order Gauss-Markov, Ornstein-Uhlenbeck): stationary
// 1-sigma per axis [rad/s] and correlation time [s]. With it the drift state w obeys
// dw/dt = -w / tau + white noise (a random telegraph signal switching with rate 1 / T has the
// same autocorrelation, exp(-2 |s| / T)); the random walk's noise is added to the same state, so
// the walk too returns to its mean over tau (negligible for the configured intensities against
// the stationary sigmas this models).
struct StationaryDrift {
  double sigma = 0.0;
  double correlation_s = 0.0;
};

class DeviationFilter {
 public:
  // `random_walk`: the intensity of eq. (11) [rad/s/sqrt(s)]; `w0_sigma`: the prior 1-sigma of
  // the residual drift at the start [rad/s] (the session's: 0.01 deg/h on top of a calibrated
  // model with eq. (11), none without it); `p0_sigma` [rad]; `stationary`: a Gauss-Markov drift
  // on top (none when its sigma is 0).
  DeviationFilter(const DeviationSeries& series, double random_walk, double w0_sigma,
                  double p0_sigma = 1e-2, StationaryDrift stationary = {});

  // Innovations of the filter on the series z, each normalised by the Cholesky factor of its
  // covariance: 2 per sample, independent N(0, phi) when z follows the model.
  Eigen::VectorXd Whiten(const std::vector<Eigen::Vector2d>& z) const;
  // Sum over the samples of ln det of the innovation covariance (the same for every regression).
  double log_det() const { return log_det_; }

  // Fixed-interval (Rauch-Tung-Striebel) smoothed w(t_k) of the series z [rad/s, (u1, u2)], and
  // its 1-sigma, at each sample.
  void SmoothDrift(const std::vector<Eigen::Vector2d>& z, std::vector<Eigen::Vector2d>& w,
                   std::vector<Eigen::Vector2d>& w_sigma) const;

 private:
  using Matrix4d = Eigen::Matrix4d;
  using Vector4d = Eigen::Vector4d;
  Matrix4d Transition(double dt) const;
  double correlation_s_ = 0.0;               // StationaryDrift::correlation_s; 0: none
  std::vector<double> dt_;                   // from the previous sample [s]
  std::vector<Eigen::Matrix<double, 4, 2>> K_;  // gains
  std::vector<Eigen::Matrix2d> L_inv_;       // inverse Cholesky factor of the innovation cov
  std::vector<Matrix4d> P_pred_, P_post_;    // for the smoother
  double log_det_ = 0.0;
};

// The Gaussian linear model y ~ N(X beta, phi I), beta ~ N(0, diag(prior_sigma^2)), phi profiled.
struct RegressionFit {
  double deviance = 0.0;    // -2 ln of the marginal likelihood at the best phi (+ constant)
  double dispersion = 1.0;  // phi
  Eigen::VectorXd mean;     // posterior mean of beta (at phi)
  Eigen::VectorXd sigma;    // posterior 1-sigma
  Eigen::MatrixXd covariance;  // posterior covariance (at phi)
};
// X: one whitened signature per column (y.size() rows each); may be empty.
RegressionFit FitRegression(const Eigen::VectorXd& y, const std::vector<const Eigen::VectorXd*>& X,
                            const Eigen::VectorXd& prior_sigma);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_DEVIATION_FILTER_H_
