// The measurement update (EstimationSession::MeasurementUpdate, ApplyCorrection): the eq. (12)
// mismatch test between the working pair, the reserve pair and the star tracker; the
// measurements of eq. (13) (star-tracker differences z2..z5 per healthy gyro, z_avt per healthy
// pair) with one noise map for R; the innovation test of eq. (14); the filter reset after
// kResetAfterRejections rejected steps; the Joseph update (ekf.h) and the feedback of the error
// estimate into the nominal state.
#include "estimator/session.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/ekf.h"
#include "estimator/fault_detection.h"
#include "estimator/measurements.h"
#include "estimator/reading_fault_monitor.h"
#include "estimator/rotation.h"
#include "estimator/session_internal.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"

namespace esg::estimator {

using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using Eigen::VectorXd;

using session_internal::kDriftChangeDecisionSteps;
using session_internal::kImmediateIsolationStrength;
using session_internal::kNoiseFloor;
using session_internal::Count;

namespace {

// Whether every healthy pair the eq. (12) test formed agrees with the star tracker within its
// allowed angle (the working pair always, the reserve pair when formed): the condition for a
// filter reset to re-anchor to the star tracker (D19).
bool StarTrackerAgreesWithPairs(const MismatchTest& mt) {
  return mt.available[kMismatch13] && mt.angle[kMismatch13] < mt.allowed[kMismatch13] &&
         (!mt.available[kMismatch23] || mt.angle[kMismatch23] < mt.allowed[kMismatch23]);
}

// The measurements of one update (eq. (13)): z_st (2 per healthy gyro, the first n_st rows) then
// z_avt (one per healthy pair, the last n_avt rows, avt_pairs naming the pair's gyro ids), their
// rows of H over the whole state, the noise covariance R = G diag(noise) G^T and the innovation
// covariance S = H P H^T + R.
struct Measurements {
  int n_st = 0;
  int n_avt = 0;
  MatrixXd H;
  VectorXd z;
  MatrixXd R;
  MatrixXd S;
  std::vector<std::pair<int, int>> avt_pairs;
};

// eq. (14) on each z_avt row: a row within k_d sigma is kept (appended to `keep`) when
// `apply_avt`, one beyond it is reported (GYRO_DATA_REJECTED) and never kept. Reads the rows and
// S; writes `keep` and the report's events.
void TestAutonomousRows(const TelemetryFrame& frame, const Measurements& mz, double kd,
                        bool apply_avt, StepReport& report, std::vector<int>& keep) {
  for (int k = 0; k < mz.n_avt; ++k) {
    const int i = mz.n_st + k;
    const double sigma = std::sqrt(mz.S(i, i));
    // eq. (14) on z_avt.
    if (std::abs(mz.z(i)) <= kd * sigma) {
      if (apply_avt) keep.push_back(i);
    } else {
      report.events.push_back(Event{
          Event::Kind::kGyroDataRejected, frame.time,
          absl::StrFormat("gyros %d,%d", mz.avt_pairs[k].first, mz.avt_pairs[k].second),
          std::abs(mz.z(i)), kd * sigma, "1",
          absl::StrFormat("eq. (14): autonomous measurement z_avt = %.3g exceeds k_d sigma_z = %.3g",
                          mz.z(i), kd * sigma)});
    }
  }
}

// The rows `keep` of the measurement (H, z) and of its noise covariance R, in that order: what
// the Joseph update applies.
struct KeptRows {
  MatrixXd H;
  VectorXd z;
  MatrixXd R;
};

KeptRows SelectRows(const Measurements& mz, const std::vector<int>& keep, int n) {
  const int mk = static_cast<int>(keep.size());
  KeptRows k;
  k.H.resize(mk, n);
  k.R.resize(mk, mk);
  k.z.resize(mk);
  for (int i = 0; i < mk; ++i) {
    k.H.row(i) = mz.H.row(keep[i]);
    k.z(i) = mz.z(keep[i]);
    for (int j = 0; j < mk; ++j) k.R(i, j) = mz.R(keep[i], keep[j]);
  }
  return k;
}

// The attitude error a star-tracker update estimated (StepReport::attitude_error_b_arcsec) and its
// 1-sigma, about the body axes [arcsec]. Reads the output pair's attitude before and after the
// update, the Jacobian J of the attitude before it (dtheta_in against the state errors, the error
// convention of conventions.h) and P before and after.
struct AttitudeError {
  Vector3d error_b_arcsec;
  Vector3d sigma_b_arcsec;
};

AttitudeError AttitudeErrorOfUpdate(const Quaterniond& q_in_b_before,
                                    const Quaterniond& q_in_b_after, const MatrixXd& J_before,
                                    const MatrixXd& P_before, const MatrixXd& P_after) {
  // q_in_b(after) = q_in_b(before) (x) Exp(dtheta_b): the correction about the body axes, which
  // is also C_b_in Log(q_in_b(after) (x) q_in_b(before)^-1) (a rotation leaves its own axis
  // fixed, so C_b_in before or after the update gives the same vector).
  const Vector3d dtheta_b = LogQuaternion(q_in_b_before.conjugate() * q_in_b_after);
  // Its covariance: J (P_before - P_after) J^T, the attitude covariance the update removed
  // (sigma_before^2 - sigma_after^2 per axis, with J held at the prior state so that the readout
  // noise term of the two attitude covariances cancels exactly), rotated to the body axes.
  const Matrix3d C_b_in = q_in_b_before.toRotationMatrix().transpose();
  const Matrix3d removed_b =
      C_b_in * (J_before * (P_before - P_after) * J_before.transpose()) * C_b_in.transpose();
  AttitudeError e;
  for (int k = 0; k < 3; ++k) {
    e.error_b_arcsec(k) = RadToArcsec(dtheta_b(k));
    e.sigma_b_arcsec(k) = RadToArcsec(std::sqrt(std::max(removed_b(k, k), 0.0)));
  }
  return e;
}

// The attitudes of the three pairs of the three-pair isolation (pair k is the pair without gyro
// ids[k], fault_detection.h), each with its covariance S in inertial axes and the linearisation of
// its error against the state (J) and the readout noise (G).
struct ThreePairs {
  std::array<Quaterniond, 3> q;
  std::array<Matrix3d, 3> S;
  std::array<MatrixXd, 3> J, G;
};

// The pair mismatches of eq. (12) in the isolation test: each pair against the star tracker
// (q_st, covariance S_st, when `st_present`) and each two pairs against each other, with their
// allowed angles (k_d times the mismatch's sigma along its direction, or the configured
// threshold). Reads the pairs, P and the readout noise sigma_r; writes the test's pair_star_* and
// pair_pair_* fields.
void PairMismatches(const ThreePairs& pairs, bool st_present, const Quaterniond& q_st,
                    const Matrix3d& S_st, const MatrixXd& P, double sigma_r, double kd,
                    double configured, IsolationTest& test) {
  const auto& q = pairs.q;
  for (int k = 0; k < 3 && st_present; ++k) {
    // A pair and the star tracker are independent: S_k + S_st.
    test.pair_star_angle[k] = RotationAngle(q[k], q_st);
    test.pair_star_allowed[k] = AllowedMismatchAngle(q[k], q_st, pairs.S[k] + S_st, kd, configured);
  }
  for (int m = 0; m < 3; ++m) {
    // The two pairs that share gyro ids[m]: their errors share that gyro's state and reading, so
    // the mismatch covariance is that of the difference of their linearised errors
    // (MismatchCovariance), not S_k + S_l.
    const int k = (m + 1) % 3, l = (m + 2) % 3;
    const Matrix3d Sigma =
        MismatchCovariance(pairs.J[k], pairs.G[k], pairs.J[l], pairs.G[l], P, sigma_r * sigma_r);
    test.pair_pair_angle[m] = RotationAngle(q[k], q[l]);
    test.pair_pair_allowed[m] = AllowedMismatchAngle(q[k], q[l], Sigma, kd, configured);
  }
}

// What every decision of one three-pair isolation reads: the frame, the three gyros, whether the
// star tracker is present, the test and its decision; and the report the decisions write their
// events to.
struct IsolationContext {
  const TelemetryFrame& frame;
  const std::array<int, 3>& ids;
  bool st_present;
  const IsolationTest& test;
  const IsolationDecision& d;
  StepReport& report;
  // The evidence text of an event (fault_detection.h IsolationEvidence), formed when an event is
  // written: most steps write none, and forming it at every step cost 4% of a diagnosis.
  std::string Evidence() const { return IsolationEvidence(test, d); }
};

// The exceeded mismatch with the largest angle-to-allowed ratio (best, -1 when none): the
// event's value/threshold.
struct StrongestMismatch {
  double value = 0.0;
  double threshold = 0.0;
  double best = -1.0;
};

StrongestMismatch StrongestExceeded(const IsolationTest& test, const IsolationDecision& d) {
  StrongestMismatch s;
  auto consider = [&](double angle, double allowed, bool exceeded) {
    if (exceeded && allowed > 0.0 && angle / allowed > s.best) {
      s.best = angle / allowed;
      s.value = angle;
      s.threshold = allowed;
    }
  };
  for (int k = 0; k < 3; ++k) {
    consider(test.pair_star_angle[k], test.pair_star_allowed[k], d.pair_star_exceeded[k]);
    consider(test.pair_pair_angle[k], test.pair_pair_allowed[k], d.pair_pair_exceeded[k]);
  }
  return s;
}

// Isolation::kAmbiguous: nothing is excluded; a gyro whose own star-tracker difference fails,
// when it is the only one, is withheld (writes withheld_gyro: that gyro, else 0); a
// FAULT_AMBIGUOUS event names the candidates.
void OnAmbiguous(const IsolationContext& c, const StrongestMismatch& sm, int& withheld_gyro) {
  // A gyro whose own star-tracker difference fails is kept out of this step's update, so
  // that a fault not yet isolated is not absorbed into the spin axes.
  int failed = 0;
  for (int k = 0; k < 3; ++k) {
    if (c.d.gyro_star_failed[k]) {
      ++failed;
      withheld_gyro = c.ids[k];
    }
  }
  if (failed != 1) withheld_gyro = 0;
  std::string candidates;
  for (int cand : c.d.candidates) {
    if (!candidates.empty()) candidates += ", ";
    candidates += cand == 0 ? std::string("star tracker") : absl::StrFormat("gyro %d", cand);
  }
  c.report.events.push_back(Event{
      Event::Kind::kFaultAmbiguous, c.frame.time, "gyros and star tracker",
      RadToArcsec(sm.value), RadToArcsec(sm.threshold), "arcsec",
      absl::StrCat("fault isolation with three pairs (eq. (12)): mismatches exceeded but the "
                   "fault is ambiguous (",
                   candidates.empty() ? std::string("no single subsystem explains them")
                                      : absl::StrCat("candidates: ", candidates),
                   "); nothing excluded. Evidence: ", c.Evidence())});
}

// Healthy pairs after the isolation's decision: the pair without the excluded gyro, or all
// three; true when the star tracker is present, not named, and agrees with each of them.
bool StarTrackerAgreesAfterIsolation(bool st_present, const IsolationDecision& d) {
  bool agrees = st_present && d.result != Isolation::kStarTracker;
  for (int k = 0; k < 3 && agrees; ++k) {
    if (d.result == Isolation::kGyro && k != d.faulty_index) continue;
    agrees = !d.pair_star_exceeded[k];
  }
  return agrees;
}

// The note a DRIFT_CHANGED alert ends with when the change's onset is at a change of the gyro's
// turn rate: a reading error that changes as the reading turns (an unconfigured case
// misalignment, a readout scale error) changes the rate too, and the alert says so when the
// change is no larger than such an error gives; a change of the turn's axis is named from 1 degree
// on. Empty otherwise.
std::string TurnRateNote(const std::optional<ReadingFaultMonitor::DriftChange>& dc) {
  if (!dc.has_value() || !dc->may_be_slow_reading_error) return std::string();
  const double axis_deg = RadToDeg(dc->turn_axis_change);
  return absl::StrFormat(
      "; its onset is at a change of the gyro's turn rate (%.3g to %.3g deg/s%s), "
      "where a reading error that changes as the reading turns (an unconfigured "
      "case misalignment or a readout scale error of up to %.0f arcsec) changes "
      "the rate by up to %.3f deg/h: this may be such an error rather than a "
      "drift change (configure gyros[].misalignmentSigmaArcsec, or run esg "
      "diagnose over the span)",
      RadToDeg(dc->turn_rate_before), RadToDeg(dc->turn_rate_after),
      axis_deg >= 1.0 ? absl::StrFormat(", its axis turned by %.0f deg", axis_deg) : "",
      RadToArcsec(kSlowReadingErrorRad), RadPerSecToDegPerHour(dc->slow_reading_change));
}

}  // namespace

// The steps of MeasurementUpdate, in its order; each says what it reads and what it writes.
struct EstimationSession::UpdateSteps {
  // Whether gyro g's measurements enter this step: running, not excluded, not the withheld gyro,
  // with a reading in the frame.
  static bool HasReading(const TelemetryFrame& frame, int withheld_gyro, const GyroState& g) {
    return !g.faulty && g.id != withheld_gyro && frame.gyros[g.id - 1].has_value();
  }

  // The ids of the running, not excluded gyros with a reading (gyros_ order).
  static std::vector<int> FreshIds(const EstimationSession& s, const TelemetryFrame& frame,
                                   int withheld_gyro) {
    std::vector<int> fresh;
    for (const GyroState& g : s.gyros_) {
      if (HasReading(frame, withheld_gyro, g)) fresh.push_back(g.id);
    }
    return fresh;
  }

  // The indices into gyros_ of the gyros whose measurements enter the update (HasReading).
  static std::vector<int> HealthyIndices(const EstimationSession& s, const TelemetryFrame& frame,
                                         int withheld_gyro) {
    std::vector<int> healthy;  // gyro indices
    for (int i = 0; i < s.gyro_count(); ++i) {
      if (HasReading(frame, withheld_gyro, s.gyros_[i])) healthy.push_back(i);
    }
    return healthy;
  }

  // eq. (12) with what is available: the working pair and the reserve pair (when formed, their
  // gyros having a reading) and the star tracker q_st (when `st_available`, covariance S_st).
  // Reads the pairs, the gyros' readings and P (through PairQuaternion); writes nothing.
  static MismatchTest MismatchOfPairs(const EstimationSession& s, const TelemetryFrame& frame,
                                      int withheld_gyro, bool st_available,
                                      const Quaterniond& q_st, const Matrix3d& S_st) {
    const double kd = s.config_.filter.innovation_kd;
    Matrix3d S1, S2;
    std::optional<Quaterniond> q1, q2;
    const GyroState* a1 = s.Find(s.working_pair_[0]);
    const GyroState* b1 = s.Find(s.working_pair_[1]);
    const GyroState* a2 = s.Find(s.reserve_pair_[0]);
    const GyroState* b2 = s.Find(s.reserve_pair_[1]);
    auto has_reading = [&](const GyroState& g) { return HasReading(frame, withheld_gyro, g); };
    const bool reserve_usable = s.reserve_pair_ != s.working_pair_ && a2 && b2 &&
                                has_reading(*a2) && has_reading(*b2);
    if (a1 && b1 && has_reading(*a1) && has_reading(*b1)) {
      q1 = s.PairQuaternion(a1->id, b1->id, a1->h_k_last, b1->h_k_last, &S1);
    }
    if (reserve_usable) q2 = s.PairQuaternion(a2->id, b2->id, a2->h_k_last, b2->h_k_last, &S2);
    // Allowed angle of each mismatch (eq. (12)): the configured one, or k_d times the mismatch's
    // sigma along its direction. The two pairs share the reference gyro; the sum of their
    // covariances bounds that of their mismatch.
    auto allowed = [&](const std::optional<Quaterniond>& a, const Quaterniond* b, const Matrix3d& S) {
      if (!a.has_value() || b == nullptr) return 0.0;
      return AllowedMismatchAngle(*a, *b, S, kd, s.config_.filter.fault_threshold);
    };
    const std::array<double, 3> allowed_angles = {
        allowed(q1, q2 ? &*q2 : nullptr, S1 + S2), allowed(q1, st_available ? &q_st : nullptr, S1 + S_st),
        allowed(q2, st_available ? &q_st : nullptr, S2 + S_st)};
    return TestMismatch(q1 ? &*q1 : nullptr, q2 ? &*q2 : nullptr, st_available ? &q_st : nullptr,
                        allowed_angles);
  }

  // D94: a pair eq. (12) names faulty whose gyro shows no abrupt change of its readings (no
  // recent verdict in `abrupt`) disagrees by a drift the model lacks: nothing is excluded, a
  // FAULT_AMBIGUOUS event is raised and the gyro is withheld at this step when WithholdUnverified
  // says so (writes withheld_gyro); the decision becomes "no fault, output unchanged".
  static void DowngradeWithoutAbruptChange(EstimationSession& s, const TelemetryFrame& frame,
                                           const MismatchTest& mt, FaultDecision& decision,
                                           StepReport& report, int& withheld_gyro) {
    const int m = decision.evidence;
    report.events.push_back(Event{
        Event::Kind::kFaultAmbiguous, frame.time,
        absl::StrFormat("gyro %d", decision.excluded_gyro), RadToArcsec(mt.angle[m]),
        RadToArcsec(mt.allowed[m]), "arcsec",
        absl::StrFormat("eq. (12) names the %s pair, but the readings of gyro %d show no "
                        "abrupt change (a jump, frozen or erratic readings, a drift change "
                        "beyond %.3g deg/h): a drift the model lacks, not a fault; gyro %d is "
                        "not excluded (its measurements are withheld at the first step it is "
                        "named, applied from the second)",
                        decision.faulty == Subsystem::kWorkingPair ? "working" : "reserve",
                        decision.excluded_gyro,
                        RadPerSecToDegPerHour(s.config_.filter.drift_change_limit),
                        decision.excluded_gyro)});
    if (s.WithholdUnverified(decision.excluded_gyro, frame.time)) {
      withheld_gyro = decision.excluded_gyro;
    }
    decision.faulty = Subsystem::kNone;
    decision.excluded_gyro = 0;
    decision.output_pair = s.working_pair_;
    decision.output_switched = false;
  }

  // The decision of eq. (12) (DecideFault of fault_detection.h) applied and reported: a gyro with
  // a recent abrupt verdict is excluded with it (or, without one, downgraded as above); the
  // working pair's, reserve pair's or star tracker's fault event; the output moves to the
  // decision's pair; a star tracker named faulty is rejected at this step (clears st_available)
  // and counted voted faulty in the streak.
  static void ApplyFaultDecision(EstimationSession& s, const TelemetryFrame& frame,
                                 const MismatchTest& mt, StepReport& report, bool& st_available,
                                 int& withheld_gyro) {
    // The decision is fault_detection's (DecideFault); here it is applied and reported.
    FaultDecision decision = DecideFault(mt, s.working_pair_, s.reserve_pair_);
    // D94: a pair named faulty whose gyro shows no abrupt change of its readings disagrees by a
    // drift the model lacks: nothing is excluded, the gyro is withheld at this step.
    std::optional<AbruptRecord> abrupt;
    if (decision.excluded_gyro != 0) abrupt = s.RecentAbrupt(decision.excluded_gyro, frame.time);
    if (decision.excluded_gyro != 0 && !abrupt.has_value()) {
      DowngradeWithoutAbruptChange(s, frame, mt, decision, report, withheld_gyro);
    }
    auto event = [&](Event::Kind kind, std::string subsystem, std::string message) {
      const int m = decision.evidence;
      Event ev{kind, frame.time, std::move(subsystem), RadToArcsec(mt.angle[m]),
               RadToArcsec(mt.allowed[m]), "arcsec", std::move(message)};
      report.events.push_back(std::move(ev));
    };
    if (decision.excluded_gyro != 0) s.MarkExcluded(decision.excluded_gyro, ExclusionFrom(*abrupt));
    switch (decision.faulty) {
      case Subsystem::kNone:
        break;
      case Subsystem::kWorkingPair:
        event(Event::Kind::kWorkingPairFault,
              absl::StrFormat("working_pair[%d,%d]", s.working_pair_[0], s.working_pair_[1]),
              absl::StrFormat("eq. (12): working pair disagrees with reserve pair and star tracker; "
                              "output switched to reserve pair [%d,%d], gyro %d excluded: %s",
                              decision.output_pair[0], decision.output_pair[1],
                              decision.excluded_gyro,
                              ExclusionFrom(*abrupt).Describe()));
        break;
      case Subsystem::kReservePair:
        event(Event::Kind::kReservePairFault,
              absl::StrFormat("reserve_pair[%d,%d]", s.reserve_pair_[0], s.reserve_pair_[1]),
              absl::StrFormat("eq. (12): reserve pair disagrees with working pair and star tracker; "
                              "gyro %d excluded: %s",
                              decision.excluded_gyro, ExclusionFrom(*abrupt).Describe()));
        break;
      case Subsystem::kStarTracker:
        event(Event::Kind::kStarTrackerFault, "star_tracker",
              "eq. (12): star tracker disagrees with both gyro pairs; its measurements are rejected");
        break;
    }
    s.working_pair_ = decision.output_pair;
    if (decision.reject_star_tracker) {
      st_available = false;
      s.star_tracker_voted_faulty_ = true;
    }
  }

  // The measurements of eq. (13) for the gyros `healthy` (indices): z_st, the star tracker's
  // differences against each (when n_st > 0, with the star tracker's own attitude C_in_b_st as
  // the body attitude of the rebuild), then z_avt, one per healthy pair (n_avt); noise sources
  // the star-tracker rotation (3, body axes) and the readout (2 per gyro, case tangent plane).
  // Reads the gyros, the layout and P; writes nothing.
  static Measurements BuildMeasurements(const EstimationSession& s, const std::vector<int>& healthy,
                                        int n_st, int n_avt, const Matrix3d& C_in_b_st, int n) {
    const double sigma_r = std::max(s.config_.readout_noise, kNoiseFloor);
    const int m = n_st + n_avt;
    const int n_noise = 3 + 2 * static_cast<int>(s.gyros_.size());
    Measurements mz;
    mz.n_st = n_st;
    mz.n_avt = n_avt;
    mz.H = MatrixXd::Zero(m, n);
    mz.z = VectorXd::Zero(m);
    MatrixXd G = MatrixXd::Zero(m, n_noise);
    VectorXd noise_var(n_noise);
    noise_var.head<3>() = s.StarTrackerVarianceB();
    noise_var.tail(n_noise - 3).setConstant(sigma_r * sigma_r);
    auto noise_col = [](int gyro_index) { return 3 + 2 * gyro_index; };

    int row = 0;
    for (int i : healthy) {
      if (n_st == 0) break;
      const StarTrackerRows rows = s.GyroStarTrackerRows(i, C_in_b_st);
      const StarTrackerDifference& d = rows.d;
      mz.z.segment<2>(row) = d.z;
      mz.H.middleRows<2>(row) = rows.H;
      G.block<2, 3>(row, 0) = d.G_st;
      G.block<2, 2>(row, noise_col(i)) = d.G_readout;
      row += 2;
    }
    for (size_t ka = 0; ka < healthy.size() && n_avt > 0; ++ka) {
      for (size_t kb = ka + 1; kb < healthy.size(); ++kb) {
        const int ia = healthy[ka], ib = healthy[kb];
        const GyroState& a = s.gyros_[ia];
        const GyroState& b = s.gyros_[ib];
        const AutonomousDifference d = MakeAutonomousDifference(
            a.h_in, a.T(), a.C_b_k(), a.h_k_last, b.h_in, b.T(), b.C_b_k(), b.h_k_last);
        mz.z(row) = d.z;
        mz.H.block<1, 2>(row, s.layout_.SpinAxis(ia)) = d.H_h_a;
        mz.H.block<1, 2>(row, s.layout_.SpinAxis(ib)) = d.H_h_b;
        if (s.layout_.HasPhi(ia)) mz.H.block<1, 3>(row, s.layout_.Phi(ia)) = d.H_phi_a;
        if (s.layout_.HasPhi(ib)) mz.H.block<1, 3>(row, s.layout_.Phi(ib)) = d.H_phi_b;
        G.block<1, 2>(row, noise_col(ia)) = d.G_readout_a;
        G.block<1, 2>(row, noise_col(ib)) = d.G_readout_b;
        mz.avt_pairs.emplace_back(a.id, b.id);
        ++row;
      }
    }
    mz.R = G * noise_var.asDiagonal() * G.transpose();
    mz.S = mz.H * s.P_ * mz.H.transpose() + mz.R;
    return mz;
  }

  // eq. (14) on z2..z5 (the star-tracker rows, when there are any) and on each z_avt. Writes the
  // report's innovations and their sigmas, the star-tracker test's ratio, NIS and log det S,
  // star_tracker_used (all rows pass), and the rejection events; returns the rows the update
  // applies: the star-tracker rows when they pass, else the passing z_avt rows.
  static std::vector<int> TestInnovations(const EstimationSession& s, const TelemetryFrame& frame,
                                          const Measurements& mz, const std::vector<int>& healthy,
                                          StepReport& report) {
    const double kd = s.config_.filter.innovation_kd;
    const int n_st = mz.n_st, n_avt = mz.n_avt;
    std::vector<int> keep;
    report.autonomous_innovation = mz.z.tail(n_avt);
    report.autonomous_innovation_sigma = mz.S.diagonal().tail(n_avt).cwiseSqrt();
    if (n_st > 0) {
      report.star_tracker_innovation = mz.z.head(n_st);
      report.star_tracker_innovation_sigma = mz.S.diagonal().head(n_st).cwiseSqrt();
      // eq. (14) on z2..z5.
      const InnovationTest t = TestInnovation(mz.z.head(n_st), mz.S.topLeftCorner(n_st, n_st), kd);
      report.star_tracker_test_ratio = t.worst_ratio;
      report.star_tracker_nis = t.nis;
      report.star_tracker_log_det_s = t.log_det_s;
      if (t.passed) {
        for (int i = 0; i < n_st; ++i) keep.push_back(i);
        report.star_tracker_used = true;
      } else {
        const GyroState* g = &s.gyros_[healthy[t.worst_index / 2]];
        report.events.push_back(Event{
            Event::Kind::kStarTrackerInnovation, frame.time, "star_tracker",
            RadToArcsec(t.worst_value), RadToArcsec(t.worst_threshold), "arcsec",
            absl::StrFormat("eq. (14): star-tracker difference for gyro %d exceeds k_d sigma_z "
                            "(|z| = %.1f arcsec > %.1f); star-tracker data rejected, output autonomous",
                            g->id, RadToArcsec(t.worst_value), RadToArcsec(t.worst_threshold))});
      }
    }
    // With the star-tracker differences applied, z_avt adds nothing: the angle between the rebuilt
    // axes h_et equals the measured theta_S, so z_avt = -(h_et_a - h_a).h_b - h_a.(h_et_b - h_b) to
    // first order, a linear function of z_st with the same noise, and the joint S would be singular.
    // It is tested by eq. (14) every step and applied only when the output runs autonomous.
    TestAutonomousRows(frame, mz, kd, !report.star_tracker_used, report, keep);
    return keep;
  }

  // The star tracker's step counters after the innovation test: a used star tracker clears the
  // streaks of steps without it and of rejections and its voted-faulty flag, counts accepted
  // steps (kResetAfterRejections in a row: accepted since the filter started) and notes the
  // mount monitor's applied step; otherwise counts the steps without it and, when it was
  // present (`st_present`), the rejections.
  static void CountStarTrackerStep(EstimationSession& s, bool used, bool st_present) {
    if (used) {
      s.mount_monitor_.NoteApplied(s.body_rate_b_);
      s.steps_without_star_tracker_ = 0;
      s.consecutive_rejections_ = 0;
      s.star_tracker_voted_faulty_ = false;
      Count(s.consecutive_accepted_);
      if (s.consecutive_accepted_ >= kResetAfterRejections) s.star_tracker_accepted_ = true;
    } else {
      s.consecutive_accepted_ = 0;
      Count(s.steps_without_star_tracker_);
      if (st_present) Count(s.consecutive_rejections_);
    }
  }

  // Whether a filter reset may re-anchor to the star tracker. Until the star tracker has been
  // accepted for kResetAfterRejections steps in a row since the filter started, the pairs'
  // inertial axes rest on the star-tracker sample of initialisation: their disagreement with the
  // star tracker may be that sample's fault (an outlier), and the guard does not apply (D19).
  // The filter is widened before it is reset (noise_widening.h, D20): while the widening can
  // still grow, the rejections are left to it. Reads the flags and the widening.
  static bool ResetAllowed(const EstimationSession& s, bool st_agrees_with_pairs) {
    const bool widening_exhausted =
        !s.options_.adaptive_noise || s.widening_.at_max();
    return !s.star_tracker_accepted_ ||
           (widening_exhausted && !s.star_tracker_voted_faulty_ && st_agrees_with_pairs);
  }

  // docs/decisions.md D19: never re-anchor to a star tracker that eq. (12) voted faulty in this
  // streak, nor to one the healthy pairs disagree with; the filter keeps running on the gyros.
  // Writes the STAR_TRACKER_FAULT event saying why the reset is withheld.
  static void ReportResetWithheld(const EstimationSession& s, const TelemetryFrame& frame,
                                  bool st_agrees_with_pairs, StepReport& report) {
    report.events.push_back(Event{
        Event::Kind::kStarTrackerFault, frame.time, "star_tracker",
        static_cast<double>(s.consecutive_rejections_), static_cast<double>(kResetAfterRejections),
        "steps",
        absl::StrFormat("star-tracker data rejected for %d steps in a row; filter reset withheld: %s",
                        s.consecutive_rejections_,
                        s.star_tracker_voted_faulty_
                            ? "eq. (12) voted the star tracker faulty in this streak"
                        : !st_agrees_with_pairs
                            ? "the healthy gyro pairs disagree with the star tracker (eq. (12))"
                            : "the process noise is widened first (FILTER_WIDENED)")});
  }

  // The star tracker has been present and rejected for kResetAfterRejections steps: a star
  // tracker that is wrong that long flags itself invalid, a filter whose model misses part of
  // the drift does not, so the filter is taken to be wrong (docs/decisions.md); the star
  // tracker is adopted only when eq. (12) did not vote it faulty in this streak and the healthy
  // pairs agree with it at this step (D19). Writes the spin axes and their covariance
  // (SpinAxesFromStarTracker), clears the change detector and the reading-fault monitor, raises
  // FILTER_RESET and clears the streaks.
  static void ResetToStarTracker(EstimationSession& s, const TelemetryFrame& frame,
                                 const Matrix3d& C_in_b_st, StepReport& report) {
    s.SpinAxesFromStarTracker(C_in_b_st);
    s.change_detector_.Clear();
    s.reading_monitor_.Clear();
    report.events.push_back(Event{
        Event::Kind::kFilterReset, frame.time, "filter",
        static_cast<double>(s.consecutive_rejections_), static_cast<double>(kResetAfterRejections),
        "steps",
        absl::StrFormat("star-tracker data rejected for %d steps in a row: spin axes "
                        "re-initialised from the star tracker (is the drift model missing a term?)",
                        s.consecutive_rejections_)});
    s.consecutive_rejections_ = 0;
    s.steps_without_star_tracker_ = 0;
  }

  // The Joseph update (ekf.h) with the rows `keep`, the feedback of its estimate into the nominal
  // state (ApplyCorrection), and, for a star-tracker update with the output pair formed before
  // and after it, the attitude error it estimated (report.attitude_error_b_arcsec and its
  // sigma). Writes P and the nominal state.
  static absl::Status Update(EstimationSession& s, const Measurements& mz,
                             const std::vector<int>& keep, int n, StepReport& report) {
    const KeptRows k = SelectRows(mz, keep, n);
    // The output attitude before the update, for the attitude error estimate of a star-tracker
    // update (StepReport::attitude_error_b_arcsec): its Jacobian J (dtheta_in against the state
    // errors, with the error convention of conventions.h) and P before the update.
    const std::array<int, 2> output_pair = s.AttitudePair();
    const GyroState* out_a = s.Find(output_pair[0]);
    const GyroState* out_b = s.Find(output_pair[1]);
    std::optional<Quaterniond> q_in_b_before;
    MatrixXd J_before, P_before;
    if (report.star_tracker_used && out_a != nullptr && out_b != nullptr && out_a->has_reading &&
        out_b->has_reading) {
      Matrix3d S_in_before;
      q_in_b_before = s.PairQuaternion(out_a->id, out_b->id, out_a->h_k_last, out_b->h_k_last,
                                       &S_in_before, &J_before);
      P_before = s.P_;
    }
    VectorXd dx;
    if (absl::Status st = JosephUpdate(k.H, k.z, k.R, s.P_, dx); !st.ok()) return st;
    s.ApplyCorrection(dx);
    if (!q_in_b_before.has_value()) return absl::OkStatus();
    const std::optional<Quaterniond> q_in_b_after =
        s.PairQuaternion(out_a->id, out_b->id, out_a->h_k_last, out_b->h_k_last, nullptr);
    if (!q_in_b_after.has_value()) return absl::OkStatus();
    const AttitudeError e =
        AttitudeErrorOfUpdate(*q_in_b_before, *q_in_b_after, J_before, P_before, s.P_);
    report.attitude_error_b_arcsec = e.error_b_arcsec;
    report.attitude_error_sigma_b_arcsec = e.sigma_b_arcsec;
    return absl::OkStatus();
  }
};

absl::Status EstimationSession::MeasurementUpdate(const TelemetryFrame& frame, StepReport& report) {
  using Steps = UpdateSteps;
  report.measurement_step = true;
  const int n = state_size();

  const auto& st = frame.star_tracker;
  const bool st_present = use_star_tracker_ && st.has_value() && st->valid;
  bool st_available = st_present;
  // The mount shift (D34) and the time-tag error corrected, the latter with the body rate of the
  // last interval.
  const Quaterniond q_st =
      st_available ? StarTrackerCorrected(st->q_in_b) : Quaterniond::Identity();

  // A gyro the three-pair isolation suspects while the model is known inconsistent is not
  // excluded but its measurements are withheld at this step (D21).
  int withheld_gyro = 0;

  // The corrected star-tracker attitude and its covariance in inertial axes (eq. (12) and the
  // star-tracker rebuild of eq. (13)).
  const Matrix3d C_in_b_st = q_st.toRotationMatrix();
  const Matrix3d S_st = StarTrackerCovarianceIn(C_in_b_st);
  // Whether every healthy pair formed at this step agrees with the star tracker within its
  // eq. (12) allowed angle: the condition for a filter reset to re-anchor to it.
  bool st_agrees_with_pairs = false;
  const std::vector<int> fresh = Steps::FreshIds(*this, frame, withheld_gyro);
  // The tracks of every gyro's readings (D94): the only evidence that lets a gyro be excluded.
  // Not in diagnosis runs (detect_drift_change off), which exclude nothing.
  if (options_.detect_drift_change) TrackReadings(frame, st_available, q_st, fresh);
  // The fault test: with three gyros reading, the three-pair isolation; otherwise (or when a
  // pair cannot be formed) eq. (12) with the working pair, the reserve pair and the star tracker.
  bool isolated = false;
  if (fresh.size() == 3) {
    isolated = IsolateWithThreePairs(frame, {fresh[0], fresh[1], fresh[2]}, st_available, q_st,
                                     S_st, report, st_available, st_agrees_with_pairs,
                                     withheld_gyro);
  }
  if (!isolated) {
    const MismatchTest mt =
        Steps::MismatchOfPairs(*this, frame, withheld_gyro, st_available, q_st, S_st);
    st_agrees_with_pairs = StarTrackerAgreesWithPairs(mt);
    Steps::ApplyFaultDecision(*this, frame, mt, report, st_available, withheld_gyro);
  }

  // A star tracker the pairs voted faulty with a constant rotation against them is re-referenced
  // to the gyros and used again from the next step (D34).
  if (CheckStarTrackerMount(frame, st_present && !st_available, q_st, report)) {
    reading_monitor_.Clear();  // the rebuilds' star tracker changed
  }

  // Measurements (eq. (13)): z_st (2 per healthy gyro) then z_avt (per healthy pair).
  const std::vector<int> healthy = Steps::HealthyIndices(*this, frame, withheld_gyro);
  const int n_st = st_available ? 2 * static_cast<int>(healthy.size()) : 0;
  const int n_avt = options_.use_autonomous_measurements
                        ? static_cast<int>(healthy.size() * (healthy.size() - 1) / 2)
                        : 0;
  if (n_st + n_avt == 0) return absl::OkStatus();
  const Measurements mz = Steps::BuildMeasurements(*this, healthy, n_st, n_avt, C_in_b_st, n);
  const std::vector<int> keep = Steps::TestInnovations(*this, frame, mz, healthy, report);
  Steps::CountStarTrackerStep(*this, report.star_tracker_used, st_present);

  // The filter reset after kResetAfterRejections rejected steps, or why it is withheld (D19, D20).
  const bool reset_allowed = Steps::ResetAllowed(*this, st_agrees_with_pairs);
  if (consecutive_rejections_ == kResetAfterRejections && !reset_allowed) {
    Steps::ReportResetWithheld(*this, frame, st_agrees_with_pairs, report);
  }
  if (consecutive_rejections_ >= kResetAfterRejections && reset_allowed) {
    Steps::ResetToStarTracker(*this, frame, C_in_b_st, report);
    return CheckCovariance(P_);
  }
  if (keep.empty()) return absl::OkStatus();
  return Steps::Update(*this, mz, keep, n, report);
}

bool EstimationSession::ModelKnownNotToFit() const {
  return consistency_.inconsistent() || widening_.widened();
}

const char* EstimationSession::ModelMisfitEvidence() const {
  return widening_.widened() ? "the filter runs widened, FILTER_WIDENED" : "MODEL_INCONSISTENT";
}

// The decisions of IsolateWithThreePairs, in its order; each says what it reads and what it
// writes.
struct EstimationSession::IsolationSteps {
  // The three pairs' attitudes (pair k without gyro ids[k]) from the gyros' last readings, with
  // their covariances and linearisations; nullopt when one cannot be formed. Reads the gyros and P.
  static std::optional<ThreePairs> PairAttitudes(const EstimationSession& s,
                                                 const std::array<int, 3>& ids) {
    ThreePairs pairs;
    for (int k = 0; k < 3; ++k) {
      const std::array<int, 2> p = PairWithout(ids, k);
      const GyroState* a = s.Find(p[0]);
      const GyroState* b = s.Find(p[1]);
      const auto qk = s.PairQuaternion(p[0], p[1], a->h_k_last, b->h_k_last, &pairs.S[k],
                                       &pairs.J[k], &pairs.G[k]);
      if (!qk.has_value()) return std::nullopt;
      pairs.q[k] = *qk;
    }
    return pairs;
  }

  // Each gyro's own star-tracker difference (eq. (13)) against the corrected star tracker q_st,
  // with its exact covariance (D22): writes the test's gyro_star_* fields (NIS, fail level k_d^2).
  // Reads the gyros, P and the star tracker's noise.
  static void GyroStarTests(const EstimationSession& s, const std::array<int, 3>& ids,
                            const Quaterniond& q_st, double kd, double sigma_r,
                            IsolationTest& test) {
    test.gyro_star_available = true;
    test.gyro_star_fail = kd * kd;
    const Matrix3d C_in_b_st = q_st.toRotationMatrix();
    const Vector3d st_var = s.StarTrackerVarianceB();
    for (int k = 0; k < 3; ++k) {
      const StarTrackerRows rows = s.GyroStarTrackerRows(s.IndexOf(ids[k]), C_in_b_st);
      const StarTrackerDifference& sd = rows.d;
      const MatrixXd& H = rows.H;
      const Eigen::Matrix2d S_g = H * s.P_ * H.transpose() +
                                  sd.G_st * st_var.asDiagonal() * sd.G_st.transpose() +
                                  sigma_r * sigma_r * sd.G_readout * sd.G_readout.transpose();
      test.gyro_star_nis[k] = sd.z.dot(S_g.ldlt().solve(sd.z));
    }
  }

  // Excludes gyro ids[k]: the output moves to a pair without it (the working pair when it does not
  // hold it), the cold spare is recommended; `named_by` says what named it, `value`/`threshold`
  // in `unit` are the event's evidence. Writes the gyro's exclusion (MarkExcluded), the working
  // and reserve pairs, and the WORKING_PAIR_FAULT or RESERVE_PAIR_FAULT event.
  static void Exclude(EstimationSession& s, const IsolationContext& c, int k, double value,
                      double threshold, const char* unit, const std::string& named_by,
                      const std::string& details, const Exclusion& why) {
    const int gyro = c.ids[k];
    s.MarkExcluded(gyro, why);
    // A configured gyro that is not running is a cold spare.
    std::string spare;
    for (const GyroConfig& gc : s.config_.gyros) {
      if (s.Find(gc.id) == nullptr) {
        spare += absl::StrFormat("%s%d", spare.empty() ? "" : ", ", gc.id);
      }
    }
    const bool in_working = s.working_pair_[0] == gyro || s.working_pair_[1] == gyro;
    const std::array<int, 2> output = in_working ? PairWithout(c.ids, k) : s.working_pair_;
    c.report.events.push_back(Event{
        in_working ? Event::Kind::kWorkingPairFault : Event::Kind::kReservePairFault, c.frame.time,
        absl::StrFormat("gyro %d", gyro), value, threshold, unit,
        absl::StrFormat("%s: gyro %d faulty: %s; %s; gyro %d excluded, output on pair [%d,%d] "
                        "(valid, degraded); only two gyros remain, switch on the cold spare%s to "
                        "restore isolation. Evidence: %s",
                        named_by, gyro, details, why.Describe(), gyro, output[0], output[1],
                        spare.empty() ? "" : absl::StrCat(" (gyro ", spare, ")"), c.Evidence())});
    s.working_pair_ = output;
    s.reserve_pair_ = output;  // no second pair is left
  }

  // Feeds the per-gyro accumulated test (D33) with this step's star-tracker NIS of each gyro;
  // when it names a gyro, only once the consistency monitor has tested the model and while
  // nothing says it does not fit (D21), and no drift change is being measured already, the gyro's
  // drift is taken to have changed (D94): writes drift_change_gyro_ and drift_change_named_.
  static void NameDriftChange(EstimationSession& s, const IsolationContext& c) {
    const bool star_tracker_suspected =
        s.star_tracker_voted_faulty_ || c.d.result == Isolation::kStarTracker ||
        std::find(c.d.candidates.begin(), c.d.candidates.end(), 0) != c.d.candidates.end();
    const auto change = s.change_detector_.Add(c.ids, c.test.gyro_star_nis, star_tracker_suspected);
    if (change.has_value() && s.consistency_.tests() > 0 && !s.ModelKnownNotToFit() &&
        s.drift_change_gyro_ == 0) {
      // D94: the gyro's drift changed; by how much is measured on its track from now on, until
      // the change is clearly beyond the limit (excluded) or below it (DRIFT_CHANGED).
      s.drift_change_gyro_ = change->gyro_id;
      s.drift_change_named_ = c.frame.time;
    }
  }

  // A drift change below the limit, or not shown beyond it after kDriftChangeDecisionSteps
  // (`dc` the track's estimate, nullopt when it has none): the gyro's drift coefficients are
  // re-opened (ReopenDrift), its spin-axis covariance grown by the displacement the old drift
  // made since the onset, the change detector cleared, drift_change_gyro_ cleared, and a
  // DRIFT_CHANGED event raised; nothing is excluded.
  static void AcceptDriftChange(EstimationSession& s, const IsolationContext& c, int k,
                                const std::optional<ReadingFaultMonitor::DriftChange>& dc,
                                const std::string& named) {
    const std::array<int, 3>& ids = c.ids;
    const double change_rad_s = dc.has_value() ? dc->magnitude : 0.0;
    const double sigma_rad_s = dc.has_value() ? std::sqrt(std::max(dc->cov.trace(), 0.0)) : 0.0;
    s.ReopenDrift(ids[k], change_rad_s);
    if (dc.has_value() && c.frame.time > dc->onset) {
      // Between the onset and now the filter carried the old drift: the gyro's spin axis
      // moved against the model by the change integrated over that time, which its
      // measurements pulled into the spin axis and the other states only in part. Its
      // spin-axis covariance grows by that displacement's second moment, (|c|^2 + tr cov_c)
      // dt^2 per tangent axis, so the re-opened coefficients are not fitted against a spin
      // axis the filter wrongly holds as known.
      const double dt_s = absl::ToDoubleSeconds(c.frame.time - dc->onset);
      const double var_rad2 =
          (change_rad_s * change_rad_s + std::max(dc->cov.trace(), 0.0)) * dt_s * dt_s;
      const int sa = s.layout_.SpinAxis(s.IndexOf(ids[k]));
      for (int a = 0; a < StateLayout::kSpinAxisSize; ++a) s.P_(sa + a, sa + a) += var_rad2;
    }
    s.change_detector_.Clear();
    s.drift_change_gyro_ = 0;
    // Where the reading's turn rate changes at the onset, a reading error that changes as
    // the reading turns (an unconfigured case misalignment, a readout scale error) changes
    // the rate too: the alert says so when the change is no larger than such an error gives.
    const std::string turn_note = TurnRateNote(dc);
    c.report.events.push_back(Event{
        Event::Kind::kDriftChanged, c.frame.time, absl::StrFormat("gyro %d", ids[k]),
        RadPerSecToDegPerHour(change_rad_s),
        RadPerSecToDegPerHour(s.config_.filter.drift_change_limit), "deg/h",
        absl::StrFormat(
            "drift of gyro %d changed by %.3f +- %.3f deg/h at %s (%s the limit %.3g deg/h "
            "with the model's uncertainty: not a fault): %s; its drift coefficients are "
            "re-opened and recalibrated, nothing excluded%s",
            ids[k], RadPerSecToDegPerHour(change_rad_s), RadPerSecToDegPerHour(sigma_rad_s),
            FormatUtc(dc.has_value() ? dc->onset : c.frame.time),
            dc.has_value() && dc->below ? "below" : "not shown beyond",
            RadPerSecToDegPerHour(dc.has_value() ? dc->bound
                                                 : s.config_.filter.drift_change_limit),
            named, turn_note)});
  }

  // The per-gyro accumulated test (D33): a gyro whose own star-tracker differences fail over the
  // window while the other two pass is excluded, whatever the single step's mismatches say;
  // only once the consistency monitor has tested the model and while nothing says it does not
  // fit (D21): a drift term the model lacks can be larger in one gyro and fail its differences
  // alone, and is announced by the monitor's and the widening's own alerts.
  // The gyro named (NameDriftChange) has its drift change measured on its track
  // (EstimateDriftChange): beyond the limit it is excluded (true returned, st_agrees_with_pairs
  // set for the pair left); below it, or not shown beyond it once kDriftChangeDecisionSteps
  // have passed, AcceptDriftChange; otherwise the measuring goes on. False: nothing excluded.
  static bool AccumulatedTest(EstimationSession& s, const IsolationContext& c,
                              bool& st_agrees_with_pairs) {
    NameDriftChange(s, c);
    const std::array<int, 3>& ids = c.ids;
    const int k = static_cast<int>(std::find(ids.begin(), ids.end(), s.drift_change_gyro_) -
                                   ids.begin());
    if (s.drift_change_gyro_ == 0 || k >= 3) return false;
    const auto dc =
        s.reading_monitor_.EstimateDriftChange(ids[k], ReadingFaultMonitor::Source::kStarTracker);
    const bool waited =
        c.frame.time - s.drift_change_named_ >=
        absl::Seconds(kDriftChangeDecisionSteps * s.config_.filter.measurement_step);
    const std::string named = absl::StrFormat(
        "named at %s by its own star-tracker differences summed over %d steps (the other gyros' "
        "passing), its track measured over the last %d steps",
        FormatUtc(s.drift_change_named_),
        s.change_detector_.options().window_steps, s.reading_monitor_.options().window_steps);
    if (dc.has_value() && dc->beyond) {
      Exclusion why;
      why.reason = ExclusionReason::kDriftBeyondLimit;
      why.time = dc->onset;
      why.value = RadPerSecToDegPerHour(dc->magnitude);
      why.threshold = RadPerSecToDegPerHour(dc->bound);
      s.drift_change_gyro_ = 0;
      Exclude(s, c, k, why.value, why.threshold, "deg/h",
              "accumulated star-tracker test (eq. (13) differences of each gyro, D33) and the "
              "gyro's track (D94)",
              named, why);
      st_agrees_with_pairs = c.st_present && !c.d.pair_star_exceeded[k];
      return true;
    }
    if (!dc.has_value() || dc->below || waited) AcceptDriftChange(s, c, k, dc, named);
    return false;
  }

  // Isolation::kGyro: the pairs name gyro d.excluded_gyro. D94: only an abrupt change of the
  // gyro's readings (a jump, frozen or erratic readings, a drift change beyond the limit)
  // excludes it; without one the gyro is withheld (WithholdUnverified) and named suspect, a
  // FAULT_AMBIGUOUS event raised. With one, D24: evidence below kImmediateIsolationStrength
  // excludes only when the previous measurement step named the same gyro (else withheld and
  // named suspect); otherwise Exclude. Writes withheld_gyro, suspect_gyro_ and suspect_time_.
  static void OnGyroNamed(EstimationSession& s, const IsolationContext& c,
                          const StrongestMismatch& sm, int& withheld_gyro) {
    const IsolationDecision& d = c.d;
    const IsolationTest& test = c.test;
    // D94: only an abrupt change of the gyro's readings (a jump, frozen or erratic readings, a
    // drift change beyond the limit) excludes it; mismatches that grow with a drift the model
    // lacks, however it behaves in time, withhold the gyro at this step and no more. With
    // such a verdict the exclusion stands even while the model is known not to fit (D21
    // guarded against the drift; the verdict tells the two apart).
    const std::optional<AbruptRecord> abrupt = s.RecentAbrupt(d.excluded_gyro, c.frame.time);
    if (!abrupt.has_value()) {
      if (s.WithholdUnverified(d.excluded_gyro, c.frame.time)) withheld_gyro = d.excluded_gyro;
      // The pairs named it at this step all the same: D24's confirmation counts it (a jump's
      // verdict may come at the step after, when the pairs name the gyro again).
      s.suspect_gyro_ = d.excluded_gyro;
      s.suspect_time_ = c.frame.time;
      c.report.events.push_back(Event{
          Event::Kind::kFaultAmbiguous, c.frame.time, absl::StrFormat("gyro %d", d.excluded_gyro),
          RadToArcsec(sm.value), RadToArcsec(sm.threshold), "arcsec",
          absl::StrFormat("fault isolation with three pairs (eq. (12)) points at gyro %d, but "
                          "its readings show no abrupt change (a jump, frozen or erratic "
                          "readings, a drift change beyond %.3g deg/h): a drift the model "
                          "lacks%s, not a fault; gyro %d is not excluded (its measurements are "
                          "withheld at the first step it is named, applied from the second). "
                          "Evidence: %s",
                          d.excluded_gyro,
                          RadPerSecToDegPerHour(s.config_.filter.drift_change_limit),
                          s.ModelKnownNotToFit()
                              ? absl::StrCat(" (", s.ModelMisfitEvidence(), ")")
                              : std::string(),
                          d.excluded_gyro, c.Evidence())});
      return;
    }
    // D24: evidence below twice the allowed angles (or a gyro's own star-tracker chi-square
    // below 4 k_d^2) excludes only when the previous measurement step named the same gyro;
    // until then the gyro is withheld. A readout jump of arcminutes exceeds at once.
    const double strength =
        d.decided_by_gyro_star
            ? std::sqrt(test.gyro_star_nis[d.faulty_index] / test.gyro_star_fail)
            : sm.best;
    const bool confirmed =
        s.suspect_gyro_ == d.excluded_gyro && s.suspect_time_ == s.last_update_time_;
    if (strength < kImmediateIsolationStrength && !confirmed) {
      s.suspect_gyro_ = d.excluded_gyro;
      s.suspect_time_ = c.frame.time;
      withheld_gyro = d.excluded_gyro;
      c.report.events.push_back(Event{
          Event::Kind::kFaultAmbiguous, c.frame.time, absl::StrFormat("gyro %d", d.excluded_gyro),
          RadToArcsec(sm.value), RadToArcsec(sm.threshold), "arcsec",
          absl::StrFormat("fault isolation with three pairs (eq. (12)) points at gyro %d with "
                          "evidence %.2f times its threshold (below %.1f): gyro %d is withheld at "
                          "this step and excluded if the next measurement step names it again. "
                          "Evidence: %s",
                          d.excluded_gyro, strength, kImmediateIsolationStrength,
                          d.excluded_gyro, c.Evidence())});
      return;
    }
    const std::array<int, 2> kept = PairWithout(c.ids, d.faulty_index);
    Exclude(s, c, d.faulty_index, RadToArcsec(sm.value), RadToArcsec(sm.threshold), "arcsec",
            "fault isolation with three pairs (eq. (12))",
            d.decided_by_gyro_star
                ? absl::StrFormat("its own star-tracker difference fails while those of gyros "
                                  "%d and %d pass",
                                  kept[0], kept[1])
                : absl::StrFormat("the pairs holding it disagree with pair [%d,%d]%s", kept[0],
                                  kept[1],
                                  c.st_present ? " and the star tracker, which agree with each other"
                                               : ""),
            ExclusionFrom(*abrupt));
  }

  // Isolation::kStarTracker: the three pairs agree with each other and not with the star
  // tracker. D21: while the model is known not to fit they may share the model's error (a drift
  // the model lacks in every gyro): FAULT_AMBIGUOUS, the star tracker stays subject to eq. (14)
  // only. Otherwise STAR_TRACKER_FAULT: its measurements are rejected at this step (clears
  // st_available) and it is counted voted faulty in the streak.
  static void OnStarTrackerNamed(EstimationSession& s, const IsolationContext& c,
                                 const StrongestMismatch& sm, bool& st_available) {
    if (s.ModelKnownNotToFit()) {
      // D21: while the model is known not to fit, three pairs that agree with each other and
      // not with the star tracker may share the model's error (a drift the model lacks in
      // every gyro); the star tracker stays subject to eq. (14) only.
      c.report.events.push_back(Event{
          Event::Kind::kFaultAmbiguous, c.frame.time, "star_tracker", RadToArcsec(sm.value),
          RadToArcsec(sm.threshold), "arcsec",
          absl::StrFormat("fault isolation with three pairs (eq. (12)) points at the star "
                          "tracker, but the configured model does not explain the data (%s): "
                          "its measurements are kept, subject to eq. (14). Evidence: %s",
                          s.ModelMisfitEvidence(),
                          c.Evidence())});
      return;
    }
    c.report.events.push_back(Event{
        Event::Kind::kStarTrackerFault, c.frame.time, "star_tracker", RadToArcsec(sm.value),
        RadToArcsec(sm.threshold), "arcsec",
        absl::StrCat("fault isolation with three pairs (eq. (12)): the star tracker disagrees "
                     "with all three gyro pairs, which agree with each other; its measurements "
                     "are rejected. Evidence: ",
                     c.Evidence())});
    st_available = false;
    s.star_tracker_voted_faulty_ = true;
  }
};

bool EstimationSession::IsolateWithThreePairs(const TelemetryFrame& frame, const std::array<int, 3>& ids,
                                              bool st_present, const Quaterniond& q_st,
                                              const Matrix3d& S_st, StepReport& report,
                                              bool& st_available, bool& st_agrees_with_pairs,
                                              int& withheld_gyro) {
  using Steps = IsolationSteps;
  const double kd = config_.filter.innovation_kd;
  const double sigma_r = std::max(config_.readout_noise, kNoiseFloor);
  // The test: the pairs' mismatches with each other and the star tracker, each gyro's own
  // star-tracker difference; then fault_detection's decision and its evidence text.
  const std::optional<ThreePairs> pairs = Steps::PairAttitudes(*this, ids);
  if (!pairs.has_value()) return false;
  IsolationTest test;
  test.gyro_ids = ids;
  test.star_available = st_present;
  PairMismatches(*pairs, st_present, q_st, S_st, P_, sigma_r, kd, config_.filter.fault_threshold,
                 test);
  if (st_present) Steps::GyroStarTests(*this, ids, q_st, kd, sigma_r, test);
  const IsolationDecision d = DecideIsolation(test, working_pair_);
  const IsolationContext c{frame, ids, st_present, test, d, report};

  // The accumulated test and the drift change it names: an exclusion there ends the step.
  if (st_present && options_.detect_drift_change &&
      Steps::AccumulatedTest(*this, c, st_agrees_with_pairs)) {
    return true;
  }
  // The single step's decision.
  const StrongestMismatch sm = StrongestExceeded(test, d);
  switch (d.result) {
    case Isolation::kNone:
      break;
    case Isolation::kGyro:
      Steps::OnGyroNamed(*this, c, sm, withheld_gyro);
      break;
    case Isolation::kStarTracker:
      Steps::OnStarTrackerNamed(*this, c, sm, st_available);
      break;
    case Isolation::kAmbiguous:
      OnAmbiguous(c, sm, withheld_gyro);
      break;
  }
  st_agrees_with_pairs = StarTrackerAgreesAfterIsolation(st_present, d);
  return true;
}

void EstimationSession::ApplyCorrection(const VectorXd& dx) {
  // Feedback of the error estimate into the nominal state, then the error state is zero.
  for (int i = 0; i < gyro_count(); ++i) {
    GyroState& g = gyros_[i];
    g.h_in = (g.h_in + g.T() * dx.segment<2>(layout_.SpinAxis(i))).normalized();
    g.t1 = (g.t1 - g.t1.dot(g.h_in) * g.h_in).normalized();
    if (layout_.has_drift()) g.residual_drift += dx.segment<2>(layout_.Drift(i));
    const std::vector<int>& free = layout_.FreeCoefficients(i);
    for (int j = 0; j < layout_.ThetaCount(i); ++j) g.theta(free[j]) += dx(layout_.Theta(i) + j);
    const std::vector<int>& free_basis = layout_.FreeBasisTerms(i);
    for (int j = 0; j < layout_.BasisCount(i); ++j) {
      g.basis[free_basis[j]].value += dx(layout_.Basis(i) + j);
    }
    if (layout_.HasPhi(i)) {
      // C_b_k(true) = Exp(dphi) Exp(phi) C_b_k(config): compose the rotations.
      const Eigen::Vector3d dphi_b = dx.segment<3>(layout_.Phi(i));
      g.phi_b = LogQuaternion(ExpQuaternion(dphi_b) * ExpQuaternion(g.phi_b));
    }
  }
  if (layout_.has_latency()) latency_s_ += dx(layout_.Latency());
}

}  // namespace esg::estimator
