// StarTrackerMountMonitor: tells a star-tracker mount shift (its output rotated by a constant
// rotation in body axes: a misalignment jump after a thermal or mechanical event) from the other
// ways a star tracker goes wrong, so that the filter re-references the star tracker to the gyros
// instead of leaving it out for good or, after hours of autonomy have widened the pairs'
// covariance, adopting the shifted reference (docs/decisions.md D34).
//
// At each measurement step where the gyro pairs voted the star tracker faulty (eq. (12), or the
// three-pair isolation of fault_detection.h), the session adds the rotation from the output
// pair's attitude to the (corrected) star-tracker attitude in body axes,
//   d_b = Log(q_in_b(pair)^-1 (x) q_in_b(star tracker)),
// with its covariance R_b: the star tracker's noise about its body axes plus the pair's attitude
// covariance rotated into body axes. A mount shift m_b makes every d_b = m_b + noise. A frozen
// output, a time-tag error during a slew, outliers or a pair that has drifted do not: their d_b
// turns with the body (the body rotates by degrees in the 10 minutes of a window on every profile
// this filter serves) or lasts a few samples only.
//
// After W consecutive voted steps (no step between them with the star tracker accepted, absent or
// not voted), the weighted mean m = (sum R_i^-1)^-1 sum R_i^-1 d_i and the scatter
//   T = sum (d_i - m)^T R_i^-1 (d_i - m)  ~  chi-square(3 (W - 1))
// decide: T below the 1 - alpha quantile calls the shift constant and returns m with its
// covariance, (sum R_i^-1)^-1 plus the last pair's covariance (the pairs' attitude error does not
// average out over a window; counted in full, which is conservative). Otherwise the oldest step
// leaves the window and the test is repeated at the next voted step.
//
// A time-tag error tau of the star tracker also rotates its output by a constant while the body
// turns at a steady rate w_b: by -w_b tau (a rotation about the rate axis). Where the filter ran
// on such a star tracker before, its misalignment states absorbed part of the rotation of the
// rates it ran at, and a change of rate leaves a rotation of up to |w_b - w_before| tau. The
// decision says a latency explains the shift as well (and the session does not re-reference: the
// latency is a configuration matter, starTracker.latencyS, or a filter state with
// starTracker.latencySigmaS) when the shift lies along the window's mean rate within its
// covariance, or when the rate of the window differs from the rate at one of the last
// kAppliedSteps steps that applied the star tracker (w_before, the one most different) by enough
// for a latency within kMaxLatencyS to make it. A mount shift within an hour of a change of rate
// is therefore not corrected until the star tracker has been applied for an hour at a steady
// rate.
//
// The pair's attitude error enters each R_i as if independent between steps: it is not (it
// changes slowly), which makes the scatter test more permissive by at most that error's share;
// with a calibrated pair a few arcsec against the star tracker's 5 arcsec across the boresight.
#ifndef ESG_ESTIMATOR_STAR_TRACKER_MOUNT_H_
#define ESG_ESTIMATOR_STAR_TRACKER_MOUNT_H_

#include <deque>
#include <optional>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/types/span.h"

namespace esg::estimator {

struct StarTrackerMountOptions {
  int window_steps = 10;  // W [measurement steps]
  double alpha = 1e-3;    // level of the constancy test
};

class StarTrackerMountMonitor {
 public:
  explicit StarTrackerMountMonitor(StarTrackerMountOptions options = {});

  struct Decision {
    Eigen::Vector3d shift_b = Eigen::Vector3d::Zero();       // m [rad], body axes
    Eigen::Matrix3d covariance_b = Eigen::Matrix3d::Zero();  // of m [rad^2]
    double scatter = 0.0;                                    // T
    double threshold = 0.0;                                  // chi2inv(1 - alpha, 3 (W - 1))
    int steps = 0;                                           // W
    // The window's mean body rate w [rad/s], w_before (rule above), and whether a star-tracker
    // time-tag
    // error explains m as well as a mount shift does (rule above): m lies along w (its part
    // perpendicular to w below the 1 - alpha quantile of chi-square(2), perpendicular_chi2)
    // with |m| / |w| within kMaxLatencyS, or |m| <= |w - w_before| kMaxLatencyS. Then
    // tau = -m.u / |u|^2 [s] (u = w or w - w_before; the sample stamped t is the attitude at
    // t - tau) is the alternative.
    Eigen::Vector3d mean_rate_b = Eigen::Vector3d::Zero();
    Eigen::Vector3d rate_before_b = Eigen::Vector3d::Zero();
    bool latency_alternative = false;
    double latency_alternative_s = 0.0;
    double perpendicular_chi2 = 0.0;       // of m's part perpendicular to u
    double perpendicular_threshold = 0.0;  // chi2inv(1 - alpha, 2)
  };
  // The largest time-tag error the configuration admits (spacecraft_config.h,
  // starTracker.latencyS).
  static constexpr double kMaxLatencyS = 10.0;

  // One step where the pairs voted the star tracker faulty: d_b and R_b as above, w_b the body
  // rate of the step [rad/s]. Returns the decision once W such steps in a row pass the constancy
  // test.
  std::optional<Decision> AddVoted(const Eigen::Vector3d& d_b, const Eigen::Matrix3d& R_b,
                                   const Eigen::Vector3d& w_b = Eigen::Vector3d::Zero());
  // A measurement step where the pairs did not vote the star tracker faulty (or it was absent):
  // the window starts again.
  void Clear() { steps_.clear(); }
  // The body rate [rad/s] of a step whose star-tracker measurements the filter applied; the last
  // kAppliedSteps are kept (about the last hour the star tracker was in use).
  void NoteApplied(const Eigen::Vector3d& w_b);
  static constexpr int kAppliedSteps = 60;

  int window_size() const { return static_cast<int>(steps_.size()); }
  const StarTrackerMountOptions& options() const { return options_; }

  // The window, for the session checkpoint: the count of applied rates kept (up to
  // kAppliedSteps), those rates (3 each, oldest first), the step count, then
  // per step d_b (3), R_b (9, row by row) and w_b (3).
  std::vector<double> ExportState() const;
  // DataLoss naming the field if the state does not fit these options (the object is then
  // unchanged).
  absl::Status RestoreState(absl::Span<const double> state);

 private:
  struct Step {
    Eigen::Vector3d d_b;
    Eigen::Matrix3d R_b;
    Eigen::Vector3d w_b;
  };
  StarTrackerMountOptions options_;
  double threshold_ = 0.0;
  double perpendicular_threshold_ = 0.0;
  std::deque<Eigen::Vector3d> applied_rates_b_;
  std::deque<Step> steps_;
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_STAR_TRACKER_MOUNT_H_
