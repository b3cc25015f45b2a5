// The star tracker in the filter: its sample corrected for a mount shift (D34) and for its
// latency, its noise and covariance, each gyro's star-tracker difference (eq. (13)) with its rows
// of H, and the mount-shift test that re-references the star tracker to the gyros
// (star_tracker_mount.h).
#include <array>
#include <cmath>
#include <optional>
#include <string>

#include "absl/strings/str_format.h"
#include "estimator/measurements.h"
#include "estimator/rotation.h"
#include "estimator/session.h"
#include "estimator/session_internal.h"
#include "estimator/units.h"

namespace esg::estimator {

using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Quaterniond;
using Eigen::Vector3d;

using session_internal::kNoiseFloor;
using session_internal::Count;

EstimationSession::StarTrackerRows EstimationSession::GyroStarTrackerRows(
    int i, const Matrix3d& C_in_b_st) const {
  const GyroState& g = gyros_[i];
  StarTrackerRows r;
  r.d = MakeStarTrackerDifference(g.h_in, g.T(), C_in_b_st, g.C_b_k(), g.h_k_last);
  r.H = MatrixXd::Zero(2, state_size());
  r.H.block<2, 2>(0, layout_.SpinAxis(i)) = r.d.H_h;
  if (layout_.HasPhi(i)) r.H.block<2, 3>(0, layout_.Phi(i)) = r.d.H_phi;
  // The corrected star tracker errs by the body rotation -w_b dtau (session.h).
  if (layout_.has_latency()) r.H.block<2, 1>(0, layout_.Latency()) = -r.d.G_st * body_rate_b_;
  return r;
}

Quaterniond EstimationSession::StarTrackerCorrected(const Quaterniond& q_st) const {
  // A mount shift m: the sample is q_in_b (x) Exp(m) (star_tracker_mount.h).
  Quaterniond q = q_st.normalized();
  if (st_realignments_ > 0) q = q * ExpQuaternion(-st_mount_b_);
  // A positive latency: the sample stamped t is the attitude at t - latency, and
  // q(t) = q(t - latency) (x) Exp(w_b latency) for a body rate w_b steady over it.
  if (latency_s_ == 0.0) return q.normalized();
  return (q * ExpQuaternion(body_rate_b_ * latency_s_)).normalized();
}

Vector3d EstimationSession::StarTrackerVarianceB() const {
  // A mount correction (D34) errs by the pairs' attitude error when it was found: counted as
  // noise of every later sample.
  Vector3d var =
      config_.star_tracker.noise.cwiseMax(kNoiseFloor).cwiseAbs2() + st_mount_noise_var_b_;
  if (latency_s_ != 0.0 || layout_.has_latency()) {
    const double tau_bound =
        std::abs(latency_s_) +
        (layout_.has_latency() ? std::sqrt(P_(layout_.Latency(), layout_.Latency())) : 0.0);
    const double sigma = rate_extrapolation_b_.norm() * tau_bound;
    var.array() += sigma * sigma;
  }
  return var;
}

Matrix3d EstimationSession::StarTrackerCovarianceIn(const Matrix3d& C_in_b_st) const {
  Matrix3d S = C_in_b_st * Matrix3d(StarTrackerVarianceB().asDiagonal()) * C_in_b_st.transpose();
  if (layout_.has_latency()) {
    const Vector3d w_in = C_in_b_st * body_rate_b_;
    S += P_(layout_.Latency(), layout_.Latency()) * w_in * w_in.transpose();
  }
  return S;
}

bool EstimationSession::CheckStarTrackerMount(const TelemetryFrame& frame, bool voted,
                                              const Quaterniond& q_st, StepReport& report) {
  if (!options_.realign_star_tracker) return false;
  // D21: while the model is known not to fit, the pairs may share its error; their vote is not
  // evidence of a mount shift.
  if (!voted || ModelKnownNotToFit()) {
    mount_monitor_.Clear();
    return false;
  }
  // The output pair, from fresh readings of gyros not excluded.
  const std::array<int, 2> p = AttitudePair();
  const GyroState* a = Find(p[0]);
  const GyroState* b = Find(p[1]);
  if (a == nullptr || b == nullptr || a->faulty || b->faulty || !frame.gyros[a->id - 1] ||
      !frame.gyros[b->id - 1]) {
    mount_monitor_.Clear();
    return false;
  }
  Matrix3d S_pair_in;
  const std::optional<Quaterniond> q_pair =
      PairQuaternion(a->id, b->id, a->h_k_last, b->h_k_last, &S_pair_in);
  if (!q_pair.has_value()) {
    mount_monitor_.Clear();
    return false;
  }
  // d_b = Log(q_pair^-1 (x) q_st): the rotation from the pair's body frame to the star tracker's,
  // in body axes; its covariance the star tracker's noise and the pair's attitude covariance.
  const Matrix3d C_b_in = q_pair->toRotationMatrix().transpose();
  const Vector3d d_b = LogQuaternion(q_pair->conjugate() * q_st);
  const Matrix3d R_b =
      C_b_in * S_pair_in * C_b_in.transpose() + Matrix3d(StarTrackerVarianceB().asDiagonal());
  const auto decision = mount_monitor_.AddVoted(d_b, 0.5 * (R_b + R_b.transpose()), body_rate_b_);
  if (!decision.has_value()) return false;
  const Vector3d m_arcsec = RadToArcsec(1.0) * decision->shift_b;
  const Vector3d sigma_arcsec =
      RadToArcsec(1.0) * decision->covariance_b.diagonal().cwiseMax(0.0).cwiseSqrt();
  const std::string rotation = absl::StrFormat(
      "a constant rotation about body x, y, z of (%.1f, %.1f, %.1f) arcsec (%.1f arcsec; 1-sigma "
      "%.1f, %.1f, %.1f) over %d measurement steps in a row (scatter chi-square %.1f < %.1f, %d "
      "dof)",
      m_arcsec.x(), m_arcsec.y(), m_arcsec.z(), m_arcsec.norm(), sigma_arcsec.x(), sigma_arcsec.y(),
      sigma_arcsec.z(), decision->steps, decision->scatter, decision->threshold,
      3 * (decision->steps - 1));
  // The body rates the latency test compared [deg/min].
  const double to_deg_min = RadToDeg(1.0) * 60.0;
  const std::string rates = absl::StrFormat(
      "body rate over the window %.2f deg/min, at a step of the last hour that applied the star "
      "tracker %.2f deg/min, change %.2f deg/min",
      to_deg_min * decision->mean_rate_b.norm(), to_deg_min * decision->rate_before_b.norm(),
      to_deg_min * (decision->mean_rate_b - decision->rate_before_b).norm());
  if (decision->latency_alternative) {
    // A rotation along a steady body rate is what a time-tag error makes: the mount is not
    // corrected for what may be a latency.
    report.events.push_back(Event{
        Event::Kind::kFaultAmbiguous, frame.time, "star_tracker", decision->perpendicular_chi2,
        decision->perpendicular_threshold, "chi-square",
        absl::StrFormat(
            "the gyro pairs voted the star tracker faulty; its output differs from pair [%d,%d] by "
            "%s, along the body rate or within what a change of the rate since the star tracker "
            "was "
            "last applied makes (the "
            "part across it chi-square %.1f < %.1f, 2 dof; %s): a mount shift or a star-tracker "
            "time-tag error of %.3f s explain it alike, so the star "
            "tracker is not re-referenced and stays rejected while the pairs disagree with it. "
            "If the star tracker's time tag is late, configure starTracker.latencyS (or "
            "latencySigmaS to estimate it); `esg diagnose` names either",
            p[0], p[1], rotation, decision->perpendicular_chi2, decision->perpendicular_threshold,
            rates, decision->latency_alternative_s)});
    return false;
  }
  // The samples from now on are corrected by the shift on top of any earlier correction:
  // Exp(-new) = Exp(-old) Exp(-m).
  st_mount_b_ = LogQuaternion(ExpQuaternion(decision->shift_b) * ExpQuaternion(st_mount_b_));
  // The shift's error e (the pairs' attitude error when it was found) rotates the new reference
  // against the old one: every gyro's misalignment against it becomes phi_g + e, a common part
  // added to their covariance (e ~ N(0, covariance_b)) when every running gyro's misalignment is
  // a state; otherwise e is counted as star-tracker noise.
  bool every_misalignment_estimated = true;
  for (int i = 0; i < gyro_count(); ++i) every_misalignment_estimated &= layout_.HasPhi(i);
  if (every_misalignment_estimated) {
    for (int i = 0; i < gyro_count(); ++i) {
      for (int j = 0; j < gyro_count(); ++j) {
        P_.block<3, 3>(layout_.Phi(i), layout_.Phi(j)) += decision->covariance_b;
      }
    }
  } else {
    st_mount_noise_var_b_ += decision->covariance_b.diagonal();
  }
  st_mount_var_b_ += decision->covariance_b.diagonal();
  Count(st_realignments_);
  // The rejections of the streak are explained: the reset guard (D19) starts afresh.
  star_tracker_voted_faulty_ = false;
  consecutive_rejections_ = 0;
  report.events.push_back(Event{
      Event::Kind::kStarTrackerRealigned, frame.time, "star_tracker", decision->scatter,
      decision->threshold, "chi-square",
      absl::StrFormat(
          "the gyro pairs voted the star tracker faulty; its output differs from pair [%d,%d] by "
          "%s (%s): a mount shift of the star tracker. Its samples are corrected by this rotation "
          "and "
          "used again from the next step (correction number %d; the gyros, not the star "
          "tracker's old mounting, are now the reference%s). Check the star tracker's mounting "
          "and thermal state",
          p[0], p[1], rotation, rates, st_realignments_,
          every_misalignment_estimated ? ", and the gyro misalignments are re-estimated against it"
                                       : "")});
  return true;
}

}  // namespace esg::estimator
