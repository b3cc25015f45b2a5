#include "estimator/discovery/deviation_filter.h"

#include <cmath>

#include "Eigen/Cholesky"
#include "Eigen/Eigenvalues"
#include "Eigen/LU"
#include "Eigen/QR"

namespace esg::estimator::discovery {

using Eigen::Matrix2d;
using Eigen::Matrix4d;
using Eigen::MatrixXd;
using Eigen::Vector2d;
using Eigen::Vector4d;
using Eigen::VectorXd;

namespace {


// Integrated random walk over dt (eq. (11)): w gains variance q^2 dt, p its integral.
Matrix4d ProcessNoise(double q, double dt) {
  const double q2 = q * q;
  Matrix4d Q = Matrix4d::Zero();
  Q.topLeftCorner<2, 2>() = q2 * dt * dt * dt / 3.0 * Matrix2d::Identity();
  Q.topRightCorner<2, 2>() = q2 * dt * dt / 2.0 * Matrix2d::Identity();
  Q.bottomLeftCorner<2, 2>() = q2 * dt * dt / 2.0 * Matrix2d::Identity();
  Q.bottomRightCorner<2, 2>() = q2 * dt * Matrix2d::Identity();
  return Q;
}

// A Gauss-Markov drift over dt (DeviationFilter's StationaryDrift): w(t) = a w(0) + noise,
// a = exp(-dt / tau), driving white noise of intensity c^2 = 2 sigma^2 / tau; p gains its integral.
Matrix4d StationaryNoise(const StationaryDrift& g, double dt) {
  if (!(g.sigma > 0.0) || !(g.correlation_s > 0.0)) return Matrix4d::Zero();
  const double tau = g.correlation_s;
  const double a = std::exp(-dt / tau);
  const double c2 = 2.0 * g.sigma * g.sigma / tau;
  const double qww = g.sigma * g.sigma * (1.0 - a * a);
  const double qpw = 0.5 * c2 * tau * tau * (1.0 - a) * (1.0 - a);
  const double qpp = c2 * tau * tau * (dt - 2.0 * tau * (1.0 - a) + 0.5 * tau * (1.0 - a * a));
  Matrix4d Q = Matrix4d::Zero();
  Q.topLeftCorner<2, 2>() = qpp * Matrix2d::Identity();
  Q.topRightCorner<2, 2>() = qpw * Matrix2d::Identity();
  Q.bottomLeftCorner<2, 2>() = qpw * Matrix2d::Identity();
  Q.bottomRightCorner<2, 2>() = qww * Matrix2d::Identity();
  return Q;
}

}  // namespace

Matrix4d DeviationFilter::Transition(double dt) const {
  Matrix4d F = Matrix4d::Identity();
  if (correlation_s_ > 0.0) {  // w decays; p gains tau (1 - a) w
    const double a = std::exp(-dt / correlation_s_);
    F.topRightCorner<2, 2>() = correlation_s_ * (1.0 - a) * Matrix2d::Identity();
    F.bottomRightCorner<2, 2>() = a * Matrix2d::Identity();
  } else {
    F.topRightCorner<2, 2>() = dt * Matrix2d::Identity();
  }
  return F;
}

DeviationFilter::DeviationFilter(const DeviationSeries& series, double random_walk,
                                 double w0_sigma, double p0_sigma, StationaryDrift stationary) {
  if (stationary.sigma > 0.0 && stationary.correlation_s > 0.0) {
    correlation_s_ = stationary.correlation_s;
    w0_sigma = std::sqrt(w0_sigma * w0_sigma + stationary.sigma * stationary.sigma);
  }
  const size_t n = series.y.size();
  dt_.resize(n);
  K_.resize(n);
  L_inv_.resize(n);
  P_pred_.resize(n);
  P_post_.resize(n);
  Matrix4d P = Vector4d(p0_sigma * p0_sigma, p0_sigma * p0_sigma, w0_sigma * w0_sigma,
                        w0_sigma * w0_sigma)
                   .asDiagonal();
  Eigen::Matrix<double, 2, 4> H = Eigen::Matrix<double, 2, 4>::Zero();
  H.leftCols<2>().setIdentity();
  for (size_t k = 0; k < n; ++k) {
    dt_[k] = k == 0 ? 0.0 : 3600.0 * (series.hours[k] - series.hours[k - 1]);
    if (k > 0) {
      const Matrix4d F = Transition(dt_[k]);
      P = F * P * F.transpose() + ProcessNoise(random_walk, dt_[k]) +
          StationaryNoise(stationary, dt_[k]);
    }
    P_pred_[k] = P;
    const Matrix2d S = P.topLeftCorner<2, 2>() + series.R[k];
    const Eigen::LLT<Matrix2d> llt(S);
    const Matrix2d L = llt.matrixL();
    L_inv_[k] = L.inverse();
    log_det_ += 2.0 * std::log(L(0, 0) * L(1, 1));
    K_[k] = P * H.transpose() * S.inverse();
    const Matrix4d IKH = Matrix4d::Identity() - K_[k] * H;
    P = IKH * P * IKH.transpose() + K_[k] * series.R[k] * K_[k].transpose();  // Joseph form
    P = 0.5 * (P + P.transpose());
    P_post_[k] = P;
  }
}

VectorXd DeviationFilter::Whiten(const std::vector<Vector2d>& z) const {
  VectorXd out(2 * z.size());
  Vector4d x = Vector4d::Zero();
  for (size_t k = 0; k < z.size(); ++k) {
    if (k > 0) x = Transition(dt_[k]) * x;
    const Vector2d nu = z[k] - x.head<2>();
    out.segment<2>(2 * k) = L_inv_[k] * nu;
    x += K_[k] * nu;
  }
  return out;
}

void DeviationFilter::SmoothDrift(const std::vector<Vector2d>& z, std::vector<Vector2d>& w,
                                  std::vector<Vector2d>& w_sigma) const {
  const size_t n = z.size();
  std::vector<Vector4d> x_pred(n), x_post(n);
  Vector4d x = Vector4d::Zero();
  for (size_t k = 0; k < n; ++k) {
    if (k > 0) x = Transition(dt_[k]) * x;
    x_pred[k] = x;
    x += K_[k] * (z[k] - x.head<2>());
    x_post[k] = x;
  }
  w.assign(n, Vector2d::Zero());
  w_sigma.assign(n, Vector2d::Zero());
  if (n == 0) return;
  Vector4d xs = x_post[n - 1];
  Matrix4d Ps = P_post_[n - 1];
  w[n - 1] = xs.tail<2>();
  w_sigma[n - 1] = Ps.diagonal().tail<2>().cwiseMax(0.0).cwiseSqrt();
  for (size_t k = n - 1; k-- > 0;) {
    // Rauch-Tung-Striebel: A = P_post(k) F^T P_pred(k+1)^-1 (a pseudo-inverse: without a random
    // walk the drift states carry no variance).
    const Matrix4d F = Transition(dt_[k + 1]);
    const Matrix4d A = P_post_[k] * F.transpose() *
                       P_pred_[k + 1].completeOrthogonalDecomposition().pseudoInverse();
    xs = x_post[k] + A * (xs - x_pred[k + 1]);
    Ps = P_post_[k] + A * (Ps - P_pred_[k + 1]) * A.transpose();
    w[k] = xs.tail<2>();
    w_sigma[k] = Ps.diagonal().tail<2>().cwiseMax(0.0).cwiseSqrt();
  }
}

RegressionFit FitRegression(const VectorXd& y, const std::vector<const VectorXd*>& X,
                            const VectorXd& prior_sigma) {
  const int m = static_cast<int>(y.size());
  const int k = static_cast<int>(X.size());
  const double yy = y.squaredNorm();
  RegressionFit fit;
  if (k == 0) {
    fit.dispersion = yy / m;
    fit.deviance = m * std::log(fit.dispersion) + m;
    return fit;
  }
  // With D = diag(prior_sigma), B = D X^T X D = V diag(lambda) V^T and c = D X^T y:
  // -2 ln L(phi) = m ln phi + sum ln(1 + lambda_i / phi) + (y^T y - sum c~_i^2 / (phi + lambda_i))
  // / phi, c~ = V^T c (cov(y) = phi I + X D^2 X^T).
  MatrixXd G(k, k);
  VectorXd b(k);
  for (int i = 0; i < k; ++i) {
    b(i) = X[i]->dot(y);
    for (int j = 0; j <= i; ++j) G(i, j) = G(j, i) = X[i]->dot(*X[j]);
  }
  const MatrixXd B = prior_sigma.asDiagonal() * G * prior_sigma.asDiagonal();
  const VectorXd c = prior_sigma.cwiseProduct(b);
  const Eigen::SelfAdjointEigenSolver<MatrixXd> eig(B);
  const VectorXd lambda = eig.eigenvalues().cwiseMax(0.0);
  const VectorXd ct = eig.eigenvectors().transpose() * c;
  auto deviance = [&](double log_phi) {
    const double phi = std::exp(log_phi);
    double d = m * log_phi;
    double quad = 0.0;
    for (int i = 0; i < k; ++i) {
      d += std::log1p(lambda(i) / phi);
      quad += ct(i) * ct(i) / (phi + lambda(i));
    }
    return d + std::max(yy - quad, 0.0) / phi;
  };
  // Golden-section search on ln phi below the no-regressor estimate y^T y / m.
  double lo = std::log(yy / m) - 25.0, hi = std::log(yy / m) + 1.0;
  const double g = 0.5 * (std::sqrt(5.0) - 1.0);
  double a = hi - g * (hi - lo), bb = lo + g * (hi - lo);
  double fa = deviance(a), fb = deviance(bb);
  for (int it = 0; it < 120 && hi - lo > 1e-10; ++it) {
    if (fa < fb) {
      hi = bb;
      bb = a;
      fb = fa;
      a = hi - g * (hi - lo);
      fa = deviance(a);
    } else {
      lo = a;
      a = bb;
      fa = fb;
      bb = lo + g * (hi - lo);
      fb = deviance(bb);
    }
  }
  const double log_phi = 0.5 * (lo + hi);
  fit.dispersion = std::exp(log_phi);
  fit.deviance = deviance(log_phi);
  // Posterior: mean D (B + phi I)^-1 D b, covariance phi D (B + phi I)^-1 D.
  const MatrixXd inner = (B + fit.dispersion * MatrixXd::Identity(k, k)).inverse();
  fit.mean = prior_sigma.asDiagonal() * inner * c;
  fit.covariance =
      fit.dispersion * prior_sigma.asDiagonal() * inner * prior_sigma.asDiagonal();
  fit.sigma = fit.covariance.diagonal().cwiseMax(0.0).cwiseSqrt();
  return fit;
}

}  // namespace esg::estimator::discovery
