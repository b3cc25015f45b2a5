// Propagation (EstimationSession::Propagate, Predict): the nominal spin axes integrated at the
// integration rate, or in substeps bounded by the motion over the interval (D120), with the
// drift of eq. (1)/(10) (drift_model.h), the configured basis terms beyond them (basis_term.h)
// and the residual drift of eq. (11), dh_in/dt = (C_in_k dw_k) x h_in
// (docs/physics.md, spin_axis.h), and the covariance transition of the spin-axis errors with the
// integrated random walk of eq. (11) as process noise. Prediction across a gap runs the same
// propagation on the readings a planned attitude implies.
#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/attitude_profile.h"
#include "estimator/basis_term.h"
#include "estimator/drift_model.h"
#include "estimator/rotation.h"
#include "estimator/session.h"
#include "estimator/session_internal.h"
#include "estimator/spin_axis.h"
#include "estimator/triad.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"

namespace esg::estimator {

using Eigen::Matrix2d;
using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using Matrix23 = Eigen::Matrix<double, 2, 3>;

using session_internal::kJ;
using session_internal::Seconds;

using DriftColumns = Eigen::Matrix<double, 3, kNumDriftCoefficients>;

namespace {

// The case-frame readings of every running gyro at both ends of the interval (gyros_ order).
struct ReadingEnds {
  std::vector<Vector3d> begin, end;
};

// The body rates the interval's attitude-pair attitudes give: the mean over the interval, the
// extrapolation to its end and their sum, the rate at the end.
struct BodyRates {
  Vector3d mean_b, extrapolation_b, end_b;
};

// The body rate at the end of the interval, for the star-tracker latency correction of the
// measurement update and the mount-shift test's latency alternative (D34). Reads the attitude
// pair's attitudes at both ends, the interval's length `span` > 0 and the previous interval's
// mean rate and length (0: none measured). The mean rate comes from q_end = q_begin (x)
// Exp(w_mean T); taken at the interval's midpoint and extrapolated to its end along the line
// through the previous interval's mean (second order for a smoothly changing rate, such as a
// slew's); no extrapolation without a previous interval.
BodyRates BodyRatesOver(const Quaterniond& q_begin, const Quaterniond& q_end, double span,
                        const Vector3d& previous_mean_rate_b, double previous_interval_s) {
  BodyRates r;
  r.mean_b = LogQuaternion(q_begin.conjugate() * q_end) / span;
  r.extrapolation_b = Vector3d::Zero();
  if (previous_interval_s > 0.0) {
    r.extrapolation_b = (r.mean_b - previous_mean_rate_b) * span / (span + previous_interval_s);
  }
  r.end_b = r.mean_b + r.extrapolation_b;
  return r;
}

// How the substeps of one interval are sized (SessionOptions::Substeps, and Predict's own).
enum class SubstepRule {
  kFixedRate,      // the configured integration rate (the paper's 8 Hz)
  kReadingTurn,    // prediction (D15): one per 0.1 deg of the readings' turn
  kMotionBounded,  // D120: the largest angle that moves over the interval, bounded per substep
};

// The number of substeps over the interval. kFixedRate: span x the configured integration rate.
// kReadingTurn (prediction): sized to the motion of the readings instead, one per 0.1 deg (the
// drift depends on time only through them). kMotionBounded: one per `max_substep_turn_rad` of
// the larger of the readings' turn and `motion_rad` (the body's turn, the spin axes' drift turn,
// the basis terms' phase over the interval; MotionOver), at most kFixedRate's count: the midpoint
// rule's relative error for a drift turning by phi over a substep is phi^2 / 24 (3e-6 at the
// default 0.5 deg, the diagnosis's bound, discovery/deviation.cc), so the integral of C_in_k B dt
// over the interval stays within phi^2 / 24 of its value. Counted in double: the span is the
// caller's (a library user may send a frame years after the previous one, or at
// absl::InfiniteFuture), so the count is checked before it becomes an int; refused (OutOfRange)
// beyond int's range.
absl::StatusOr<int> SubstepCount(const ReadingEnds& ends, double span, SubstepRule rule,
                                 double integration_rate_hz, double motion_rad,
                                 double max_substep_turn_rad, absl::Time frame_time) {
  double max_turn = 0.0;  // largest angle a reading turns over the interval [rad]
  for (size_t i = 0; i < ends.begin.size(); ++i) {
    max_turn =
        std::max(max_turn, std::acos(std::clamp(ends.begin[i].dot(ends.end[i]), -1.0, 1.0)));
  }
  const double fixed_rate_substeps = std::ceil(span * integration_rate_hz - 1e-9);
  double substeps_wanted = fixed_rate_substeps;
  if (rule == SubstepRule::kReadingTurn) {
    substeps_wanted = std::ceil(max_turn / (0.1 * kRadPerDeg));
  } else if (rule == SubstepRule::kMotionBounded) {
    // A motion that is not finite (NaN from a span of absl::InfiniteFuture times a rate of 0)
    // falls back to the fixed rate, which refuses such a span below. std::max would drop a NaN
    // second argument and leave the readings' turn alone.
    const double bounded = std::ceil(std::max(max_turn, motion_rad) / max_substep_turn_rad);
    if (std::isfinite(motion_rad) && bounded < fixed_rate_substeps) substeps_wanted = bounded;
  }
  if (!(substeps_wanted <= static_cast<double>(std::numeric_limits<int>::max()))) {
    return absl::OutOfRangeError(absl::StrFormat(
        "frame time %s: propagating %g s at filter.integrationRateHz %g needs %g steps, more "
        "than %d",
        FormatUtc(frame_time), span, integration_rate_hz, substeps_wanted,
        std::numeric_limits<int>::max()));
  }
  return std::max(1, static_cast<int>(substeps_wanted));
}

// The largest angle [rad] a basis term's regressor turns through over [begin, begin + span] by
// time alone (its other inputs, the readings and the body rate, are bounded by the turns): an
// orbital harmonic's phase 2 pi n span / period, an exponential decay's span / tau. Infinity
// (the fixed rate) when a term switches on inside the interval (a spin-axis harmonic's or a
// decay's epoch: the midpoint rule places a step to within half a substep) or reads a channel
// (held values that expire, lags of their own: channel_signal.h).
double BasisPhaseOver(const std::vector<BasisTerm>& basis, absl::Time begin, double span) {
  const absl::Time end = begin + absl::Seconds(span);
  double phase_rad = 0.0;
  for (const BasisTerm& t : basis) {
    switch (t.kind) {
      case BasisKind::kOrbitalHarmonic:
        phase_rad = std::max(phase_rad, 2.0 * kPi * t.harmonic * span / t.period);
        break;
      case BasisKind::kCyclingHarmonic:
        phase_rad = std::max(phase_rad, 2.0 * kPi * span / t.period);
        break;
      case BasisKind::kExponentialDecay:
        if (t.epoch > begin && t.epoch < end) return std::numeric_limits<double>::infinity();
        if (end > t.epoch) phase_rad = std::max(phase_rad, span / t.time_constant);
        break;
      case BasisKind::kSpinAxisHarmonic:
        if (t.epoch > begin && t.epoch < end) return std::numeric_limits<double>::infinity();
        break;
      case BasisKind::kChannel:
        return std::numeric_limits<double>::infinity();
      case BasisKind::kBodyRate:
      case BasisKind::kBodyRateProduct:
      case BasisKind::kRamp:  // linear in time: the midpoint rule is exact for it alone
      case BasisKind::kRampHarmonic:
      case BasisKind::kSuspensionVoltage:
        break;
    }
  }
  return phase_rad;
}

// Gyro i's rows of the transition over the interval, Phi = I + E (2 x its spin-axis drivers):
// only the spin-axis errors move, d(dh)/dt = T^T [(C_in_k (B dtheta + sum_j s_j e_m(j)
// dvalue_j)) x h] + J dw_int, with the tangent basis T and the axis h_in at the interval's end
// held over it. Reads M (sum of C_in_k B dt over the substeps) and M_basis (the free basis terms'
// columns, likewise). Columns: the spin-axis drivers of state_layout.h, residual drift (when
// `rw`), free coefficients, then free basis terms.
MatrixXd SpinAxisTransitionRows(const Eigen::Matrix<double, 3, 2>& T, const Vector3d& h_in,
                                const StateLayout& layout, int i, bool rw, double span,
                                const DriftColumns& M, const MatrixXd& M_basis) {
  const Matrix23 Tt = T.transpose();
  const Matrix3d minus_hx = -Skew(h_in);  // v x h = -h x v
  MatrixXd E = MatrixXd::Zero(2, layout.SpinAxisDriverCount(i));
  if (rw) E.leftCols<2>() = kJ * span;
  const std::vector<int>& free = layout.FreeCoefficients(i);
  for (int j = 0; j < layout.ThetaCount(i); ++j) {
    E.col(layout.DriftSize() + j) = Tt * minus_hx * M.col(free[j]);
  }
  for (int j = 0; j < layout.BasisCount(i); ++j) {
    E.col(layout.DriftSize() + layout.ThetaCount(i) + j) = Tt * minus_hx * M_basis.col(j);
  }
  return E;
}

// P <- Phi P Phi^T with Phi = I + E, E nonzero only in each gyro's spin-axis rows (E[i], in the
// columns of its own residual drifts and free coefficients, which follow the spin-axis pair
// contiguously): P + E P + P E^T + E P E^T in O(n k) instead of O(n^3). In place: AddFrame and
// Predict work on a copy of the session, so a failure later leaves the caller's session
// untouched. Only the spin-axis rows and columns change; their blocks are symmetrised, the rest
// of P is untouched.
void TransitionCovariance(MatrixXd& P, const StateLayout& layout, const std::vector<MatrixXd>& E) {
  const int n = static_cast<int>(E.size());
  std::vector<MatrixXd> EP(n);
  for (int i = 0; i < n; ++i) {
    EP[i] = E[i] * P.middleRows(layout.SpinAxisDrivers(i), E[i].cols());  // 2 x n, from P before
  }
  std::vector<std::vector<Matrix2d>> EPEt(n, std::vector<Matrix2d>(n));
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j < n; ++j) {
      EPEt[i][j] = EP[i].middleCols(layout.SpinAxisDrivers(j), E[j].cols()) * E[j].transpose();
    }
  }
  for (int i = 0; i < n; ++i) P.middleRows(layout.SpinAxis(i), 2) += EP[i];
  for (int i = 0; i < n; ++i) P.middleCols(layout.SpinAxis(i), 2) += EP[i].transpose();
  for (int i = 0; i < n; ++i) {
    for (int j = 0; j <= i; ++j) {
      const int oi = layout.SpinAxis(i), oj = layout.SpinAxis(j);
      const Matrix2d block = 0.5 * (P.block<2, 2>(oi, oj) + P.block<2, 2>(oj, oi).transpose()) +
                             0.5 * (EPEt[i][j] + EPEt[j][i].transpose());
      P.block<2, 2>(oi, oj) = block;
      P.block<2, 2>(oj, oi) = block.transpose();
    }
  }
}

// The integrated random walk of eq. (11) over the interval, intensity q_rw [rad/s/sqrt(s)], added
// to gyro i's spin-axis and residual-drift blocks of P.
void AddRandomWalkNoise(MatrixXd& P, const StateLayout& layout, int i, double q_rw, double span) {
  const double q2 = q_rw * q_rw;
  const int h = layout.SpinAxis(i), d = layout.Drift(i);
  P.block<2, 2>(d, d) += q2 * span * Matrix2d::Identity();
  P.block<2, 2>(h, d) += q2 * span * span / 2.0 * kJ;
  P.block<2, 2>(d, h) += q2 * span * span / 2.0 * kJ.transpose();
  P.block<2, 2>(h, h) += q2 * span * span * span / 3.0 * Matrix2d::Identity();
}

// The adaptive process noise (noise_widening.h): white noise on every spin-axis angle, q_w
// [rad^2/s], over the interval.
void AddWideningNoise(MatrixXd& P, const StateLayout& layout, int gyro_count, double q_w,
                      double span) {
  for (int i = 0; i < gyro_count; ++i) {
    P.block<2, 2>(layout.SpinAxis(i), layout.SpinAxis(i)) += q_w * span * Matrix2d::Identity();
  }
}

// Gyro i's (its id `id`) rows of P that the propagation changed, spin axis then residual drift
// (contiguous, state_layout.h): refused (Internal) when one is not finite or a variance negative.
absl::Status CheckPropagatedRows(const MatrixXd& P, const StateLayout& layout, int i, int id) {
  const int rows = StateLayout::kSpinAxisSize + layout.DriftSize();
  const int h = layout.SpinAxis(i);
  if (!P.middleRows(h, rows).allFinite()) {
    return absl::InternalError(
        absl::StrFormat("covariance of gyro %d is not finite after propagation", id));
  }
  for (int k = 0; k < rows; ++k) {
    if (P(h + k, h + k) < 0.0) {
      return absl::InternalError(
          absl::StrFormat("covariance of gyro %d has a negative variance", id));
    }
  }
  return absl::OkStatus();
}

}  // namespace

// The steps of Propagate that read or write the running gyros' state.
struct EstimationSession::PropagationSteps {
  // Reads the frame's readings: each gyro's has_reading, and its suspension voltages for the
  // basis terms (the frame's, else the last received, held).
  static void TakeReadings(const TelemetryFrame& frame, std::vector<GyroState>& gyros) {
    for (GyroState& g : gyros) {
      g.has_reading = frame.gyros[g.id - 1].has_value();
      if (g.has_reading && frame.gyros[g.id - 1]->u_k_mv.has_value()) {
        g.u_k_v = *frame.gyros[g.id - 1]->u_k_mv * kVoltsPerMv;
      }
    }
  }

  // The readings at the interval's begin (each gyro's h_k_last) and, for the gyros with a
  // reading in the frame, at its end; the others' ends are left for FillEnds.
  static ReadingEnds ReadingsAtBothEnds(const TelemetryFrame& frame,
                                        const std::vector<GyroState>& gyros) {
    ReadingEnds ends;
    ends.begin.resize(gyros.size());
    ends.end.resize(gyros.size());
    for (size_t i = 0; i < gyros.size(); ++i) {
      ends.begin[i] = gyros[i].h_k_last;
      if (gyros[i].has_reading) ends.end[i] = frame.gyros[gyros[i].id - 1]->h_k.normalized();
    }
    return ends;
  }

  // The end readings of the gyros without one in the frame. A gyro is not held at its last
  // reading (which the spacecraft's motion has made stale): its case-frame axis at the end is
  // the one the attitude pair's attitude at the end, q_end, implies, h_k = C_k_b C_b_in h_in, so
  // that neither its drift nor anything else depends on a reading it did not send. Without q_end
  // (no pair has fresh readings, or it cannot be formed) it holds its last reading (the output is
  // then not valid, OutputAttitude).
  static void FillEnds(const std::vector<GyroState>& gyros,
                       const absl::StatusOr<Quaterniond>* q_end, ReadingEnds& ends) {
    for (size_t i = 0; i < gyros.size(); ++i) {
      if (gyros[i].has_reading) continue;
      ends.end[i] = q_end != nullptr && q_end->ok()
                        ? (gyros[i].C_b_k().transpose() *
                           (*q_end)->toRotationMatrix().transpose() * gyros[i].h_in)
                              .normalized()
                        : ends.begin[i];
    }
  }

  // Integrates every gyro's spin axis h_in over the interval [begin, begin + span] in `substeps`
  // substeps, taken at their midpoints (second order in dt for the slowly varying drift): the
  // readings interpolated between the ends, the attitude pair (ia, ib) carrying case-frame drift
  // to inertial axes, eq. (1)/(10) with theta, the residual drift of eq. (11) when `rw`, and the
  // basis terms at their current values (BasisDrift; a channel term reads `channels`, held since
  // the previous frame). Returns per gyro the sums the transition
  // needs: M[i] = sum of C_in_k B dt and M_basis[i], the free basis terms' columns carried to
  // inertial axes likewise, sum of C_in_k s e_m dt.
  static void IntegrateSpinAxes(std::vector<GyroState>& gyros, const StateLayout& layout,
                                const ReadingEnds& ends, int ia, int ib, absl::Time begin,
                                double span, int substeps, bool rw, const Vector3d& interval_rate_b,
                                const ChannelSignals& channels, std::vector<DriftColumns>& M,
                                std::vector<MatrixXd>& M_basis) {
    const double dt = span / substeps;
    std::vector<Matrix3d> C_b_k(gyros.size());
    M.assign(gyros.size(), DriftColumns::Zero());
    for (size_t i = 0; i < gyros.size(); ++i) C_b_k[i] = gyros[i].C_b_k();
    M_basis.assign(gyros.size(), MatrixXd());
    for (int i = 0; i < static_cast<int>(gyros.size()); ++i) {
      M_basis[i] = MatrixXd::Zero(3, layout.BasisCount(i));
    }
    std::vector<Vector3d> h_k(gyros.size());
    Matrix3d C_in_b = Matrix3d::Identity();
    for (int step = 0; step < substeps; ++step) {
      const double s = (step + 0.5) / substeps;
      const absl::Time substep_time = begin + absl::Seconds(s * span);
      for (size_t i = 0; i < gyros.size(); ++i) h_k[i] = SlerpUnit(ends.begin[i], ends.end[i], s);
      auto q = PairAttitude(gyros[ia].h_in, gyros[ib].h_in, C_b_k[ia] * h_k[ia],
                            C_b_k[ib] * h_k[ib]);
      if (q.ok()) C_in_b = q->toRotationMatrix();
      for (size_t i = 0; i < gyros.size(); ++i) {
        GyroState& g = gyros[i];
        const DriftRegressorMatrix B = DriftRegressor(h_k[i]);
        const Matrix3d C_in_k = C_in_b * C_b_k[i];
        const DriftColumns CB = C_in_k * B;
        // eq. (1)/(10) carried to inertial axes: dh_in/dt = (C_in_k dw_k) x h_in.
        Vector3d dw_in = CB * g.theta;
        if (rw) dw_in += g.T() * g.residual_drift;
        if (!g.basis.empty()) {
          BasisInputs in;
          in.time = substep_time;
          in.h_k = h_k[i];
          in.w_k = C_b_k[i].transpose() * interval_rate_b;
          in.u_k_v = g.u_k_v;
          in.channels = &channels;
          BasisDrift(g.basis, layout, static_cast<int>(i), in, C_in_k, dt, dw_in, M_basis[i]);
        }
        g.h_in = StepSpinAxis(g.h_in, dw_in, dt);
        M[i] += CB * dt;
      }
    }
  }

  // The basis terms beyond eq. (1)/(10), held and free at their current values, for gyro i over
  // one substep: their drift added to dw_in, the free terms' columns times dt to M_basis. Only
  // their part perpendicular to h_k moves the spin axis (basis_term.h); it is taken here, with
  // the projection I - h_k h_k^T that eq. (1)/(10)'s projected-gradient form carries
  // (drift_model.h), so that the integrator (a finite rotation per substep, which the along-h
  // part would tilt at second order in dt) treats a term as the eq. (1)/(10) term it equals:
  // -(I - h h^T) C1 is the C1 term of eq. (10).
  static void BasisDrift(const std::vector<BasisTerm>& basis, const StateLayout& layout, int i,
                         const BasisInputs& in, const Matrix3d& C_in_k, double dt, Vector3d& dw_in,
                         MatrixXd& M_basis) {
    const Matrix3d C_in_k_perp = C_in_k * (Matrix3d::Identity() - in.h_k * in.h_k.transpose());
    dw_in += C_in_k_perp * BasisDriftSum_k(basis, in);
    const std::vector<int>& free_basis = layout.FreeBasisTerms(i);
    for (int j = 0; j < layout.BasisCount(i); ++j) {
      M_basis.col(j) += C_in_k_perp * BasisRegressor_k(basis[free_basis[j]], in) * dt;
    }
  }

  // The largest angle [rad] that moves over the interval [begin, begin + span], besides the
  // readings (SubstepCount): the body's turn `body_turn_rad` (the attitude pair's attitudes at
  // both ends), each spin axis's turn by its drift, |dw_k| span with the drift of eq. (1)/(10),
  // the basis terms and eq. (11)'s residual drift taken at the larger of both ends (an upper
  // bound of its part perpendicular to the axis, which alone moves it), and each basis term's
  // phase by time (BasisPhaseOver).
  static double MotionOver(const std::vector<GyroState>& gyros, const ReadingEnds& ends,
                           double body_turn_rad, absl::Time begin, double span, bool rw,
                           const Vector3d& interval_rate_b, const ChannelSignals& channels) {
    double motion_rad = body_turn_rad;
    for (size_t i = 0; i < gyros.size(); ++i) {
      const GyroState& g = gyros[i];
      double drift_rad_s = 0.0;
      for (const Vector3d* h_k : {&ends.begin[i], &ends.end[i]}) {
        Vector3d dw_k = DriftRegressor(*h_k) * g.theta;  // eq. (1)/(10)
        if (!g.basis.empty()) {
          BasisInputs in;
          in.time = h_k == &ends.begin[i] ? begin : begin + absl::Seconds(span);
          in.h_k = *h_k;
          in.w_k = g.C_b_k().transpose() * interval_rate_b;
          in.u_k_v = g.u_k_v;
          in.channels = &channels;
          dw_k += BasisDriftSum_k(g.basis, in);
        }
        drift_rad_s = std::max(drift_rad_s, dw_k.norm());
      }
      if (rw) drift_rad_s += g.residual_drift.norm();  // eq. (11)
      motion_rad = std::max(motion_rad, drift_rad_s * span);
      motion_rad = std::max(motion_rad, BasisPhaseOver(g.basis, begin, span));
    }
    return motion_rad;
  }

  // After the integration, per gyro: its tangent basis kept perpendicular to the moved axis (a
  // change of order 1e-5 rad), its transition rows E[i] (SpinAxisTransitionRows), the spin axis's
  // motion against its drivers since the last measurement update, inertial, accumulated
  // (motion_in, for the reading-fault tracks, session_reading_faults.cc), and h_k_last set to the
  // interval's end reading.
  static std::vector<MatrixXd> Transition(std::vector<GyroState>& gyros, const StateLayout& layout,
                                          bool rw, double span, const ReadingEnds& ends,
                                          const std::vector<DriftColumns>& M,
                                          const std::vector<MatrixXd>& M_basis) {
    std::vector<MatrixXd> E(gyros.size());
    for (int i = 0; i < static_cast<int>(gyros.size()); ++i) {
      GyroState& g = gyros[i];
      g.t1 = (g.t1 - g.t1.dot(g.h_in) * g.h_in).normalized();
      E[i] = SpinAxisTransitionRows(g.T(), g.h_in, layout, i, rw, span, M[i], M_basis[i]);
      if (g.motion_in.rows() != 3 || g.motion_in.cols() != E[i].cols()) {
        g.motion_in = MatrixXd::Zero(3, E[i].cols());
      }
      g.motion_in += g.T() * E[i];
      g.h_k_last = ends.end[i];
    }
    return E;
  }
};

absl::Status EstimationSession::Propagate(const TelemetryFrame& frame) {
  using Steps = PropagationSteps;
  const double span = Seconds(frame.time - last_time_);
  const bool rw = layout_.has_drift();

  // Readings at both ends. The pair that carries case-frame drift to inertial axes has fresh
  // readings in this frame (AttitudePair); the other gyros' ends follow from its attitude.
  Steps::TakeReadings(frame, gyros_);
  const std::array<int, 2> pair = AttitudePair();
  const int ia = IndexOf(pair[0]), ib = IndexOf(pair[1]);
  ReadingEnds ends = Steps::ReadingsAtBothEnds(frame, gyros_);
  body_rate_b_ = Vector3d::Zero();
  rate_extrapolation_b_ = Vector3d::Zero();
  // The body rate the basis terms see over the whole interval (their w_k = C_k_b w_b): the
  // attitude pair's mean rate over the interval, not the extrapolated end rate body_rate_b_ (the
  // drift is integrated across the interval, and the mean is what its two ends measure); zero
  // when no pair has fresh readings at both ends.
  Vector3d interval_rate_b = Vector3d::Zero();
  double body_turn_rad = 0.0;  // the attitude pair's turn between the interval's ends
  const double previous_interval_s = previous_interval_s_;
  previous_interval_s_ = 0.0;  // set again below when this interval's mean rate is measured
  if (!gyros_[ia].has_reading || !gyros_[ib].has_reading) {
    Steps::FillEnds(gyros_, nullptr, ends);
  } else {
    const auto q_end =
        PairAttitude(gyros_[ia].h_in, gyros_[ib].h_in, gyros_[ia].C_b_k() * ends.end[ia],
                     gyros_[ib].C_b_k() * ends.end[ib]);
    Steps::FillEnds(gyros_, &q_end, ends);
    if (span > 0.0) {
      const auto q_begin =
          PairAttitude(gyros_[ia].h_in, gyros_[ib].h_in, gyros_[ia].C_b_k() * ends.begin[ia],
                       gyros_[ib].C_b_k() * ends.begin[ib]);
      if (q_begin.ok() && q_end.ok()) {
        const BodyRates rates =
            BodyRatesOver(*q_begin, *q_end, span, previous_mean_rate_b_, previous_interval_s);
        interval_rate_b = rates.mean_b;
        body_turn_rad = rates.mean_b.norm() * span;
        rate_extrapolation_b_ = rates.extrapolation_b;
        body_rate_b_ = rates.end_b;
        previous_mean_rate_b_ = rates.mean_b;
        previous_interval_s_ = span;
      }
    }
  }

  // The spin axes integrated over the interval, then the covariance carried by the transition
  // with the process noise of eq. (11) and of the widening.
  SubstepRule rule = SubstepRule::kFixedRate;
  double motion_rad = 0.0;
  if (adaptive_integration_) {
    rule = SubstepRule::kReadingTurn;
  } else if (options_.substeps == SessionOptions::Substeps::kMotionBounded) {
    rule = SubstepRule::kMotionBounded;
    motion_rad = Steps::MotionOver(gyros_, ends, body_turn_rad, last_time_, span, rw,
                                   interval_rate_b, channel_signals_);
  }
  const absl::StatusOr<int> substeps =
      SubstepCount(ends, span, rule, config_.filter.integration_rate_hz, motion_rad,
                   options_.max_substep_turn_deg * kRadPerDeg, frame.time);
  if (!substeps.ok()) return substeps.status();
  last_propagation_substeps_ = *substeps;
  std::vector<DriftColumns> M;
  std::vector<MatrixXd> M_basis;
  Steps::IntegrateSpinAxes(gyros_, layout_, ends, ia, ib, last_time_, span, *substeps, rw,
                           interval_rate_b, channel_signals_, M, M_basis);
  const std::vector<MatrixXd> E = Steps::Transition(gyros_, layout_, rw, span, ends, M, M_basis);
  TransitionCovariance(P_, layout_, E);
  if (rw) {
    for (int i = 0; i < gyro_count(); ++i) {
      AddRandomWalkNoise(P_, layout_, i, RandomWalkOf(gyros_[i].id), span);  // eq. (11)
    }
  }
  if (widening_.widened()) {
    // The widening's variance per measurement step.
    const double q_w = widening_.added_variance() / config_.filter.measurement_step;
    AddWideningNoise(P_, layout_, gyro_count(), q_w, span);
  }
  for (int i = 0; i < gyro_count(); ++i) {
    if (absl::Status st = CheckPropagatedRows(P_, layout_, i, gyros_[i].id); !st.ok()) return st;
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<PredictedSample>> EstimationSession::Predict(
    const std::vector<absl::Time>& times, const AttitudeProfile* planned,
    absl::Time planned_start) const {
  if (!initialized_) {
    return absl::FailedPreconditionError(
        "prediction needs an initialised session (no star-tracker fix yet)");
  }
  EstimationSession s = *this;
  s.use_star_tracker_ = false;
  s.adaptive_integration_ = true;
  const Quaterniond q_hold = CurrentAttitude().q_in_b;
  std::vector<PredictedSample> out;
  out.reserve(times.size());
  for (absl::Time t : times) {
    if (t <= s.last_time_) {
      return absl::OutOfRangeError(absl::StrCat("prediction time ", FormatUtc(t),
                                                " is not after the last frame ",
                                                FormatUtc(s.last_time_)));
    }
    const Quaterniond q_in_b =
        planned != nullptr ? planned->Attitude(Seconds(t - planned_start)) : q_hold;
    const Matrix3d C_b_in = q_in_b.toRotationMatrix().transpose();
    // The readings the plan implies: h_k = C_k_b C_b_in h_in (gyros' current predicted axes).
    TelemetryFrame frame;
    frame.time = t;
    for (const GyroState& g : s.gyros_) {
      GyroReading r;
      r.h_k = (g.C_b_k().transpose() * C_b_in * g.h_in).normalized();
      frame.gyros[g.id - 1] = r;
    }
    // Propagation only (no measurement), then the output is the plan with the envelope of the
    // propagated covariance.
    if (absl::Status st = s.Propagate(frame); !st.ok()) return st;
    s.last_time_ = t;
    s.channel_signals_.Advance(frame);
    for (GyroState& g : s.gyros_) {
      g.h_k_last = (g.C_b_k().transpose() * C_b_in * g.h_in).normalized();
    }
    PredictedSample sample;
    sample.time = t;
    sample.attitude = s.OutputAttitude(t);
    sample.attitude.q_in_b = q_in_b;
    for (const GyroState& g : s.gyros_) sample.h_in.emplace_back(g.id, g.h_in);
    out.push_back(std::move(sample));
  }
  return out;
}

}  // namespace esg::estimator
