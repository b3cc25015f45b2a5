// One run of a (candidate) model over a recording, and what the discovery measures on it
// (docs/discovery.md): the filter (session.h) with a given configuration and model, the
// star-tracker quaternions optionally corrected for a latency and a misalignment, the star tracker
// optionally withheld over some spans (held-out prediction). Records per measurement step the
// innovation log-likelihood terms (StepReport::star_tracker_nis, star_tracker_log_det_s) and the
// per-gyro star-tracker innovations, and in withheld spans the attitude and spin-axis prediction
// errors against the withheld (corrected) star tracker. Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_MODEL_RUN_H_
#define ESG_ESTIMATOR_DISCOVERY_MODEL_RUN_H_

#include <array>
#include <memory>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/discovery/regimes.h"
#include "estimator/session.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"

namespace esg::estimator::discovery {

// Star-tracker model of a candidate: the recorded quaternion stamped t is
// q_st(t) = q_in_b(t - latency) (x) Exp(misalignment_b); its correction is
// q_in_b(t) = q_st(t) (x) Exp(-misalignment_b) (x) Exp(w_b_in_b(t) latency), to first order in
// the latency (the rate w_b_in_b measured from the gyros, regimes.h).
//
// A drift the model holds at fitted values outside the filter's drift model (a drift that
// follows the sun, sun_terms.h) corrects one gyro's readings instead: the spin-axis motion it
// caused, dh_k in case axes at every frame, is taken off the reading, h_k <- normalise(h_k -
// dh_k), as if the rotor had not drifted (held at its value, like a readout distortion).
struct ReadingShift {
  int gyro = 0;
  std::shared_ptr<const std::vector<Eigen::Vector3d>> dh_k;  // per frame, case axes [1]
};
struct StarTrackerCorrection {
  double latency = 0.0;                                      // [s], positive: stamped late
  Eigen::Vector3d misalignment_b = Eigen::Vector3d::Zero();  // [rad]
  std::vector<ReadingShift> reading_shifts;
  // The star tracker's mount turning with the orbit (star_tracker_cycle.h): a further
  // misalignment cycle_cos_b cos(phi) + cycle_sin_b sin(phi), phi = 2 pi (t - cycle_epoch) /
  // cycle_period_s, body axes [rad]; none while cycle_period_s is 0.
  double cycle_period_s = 0.0;
  absl::Time cycle_epoch = absl::UnixEpoch();
  Eigen::Vector3d cycle_cos_b = Eigen::Vector3d::Zero();
  Eigen::Vector3d cycle_sin_b = Eigen::Vector3d::Zero();
  // The star tracker's misalignment at `time` [rad, body axes]: misalignment_b and the cycle.
  Eigen::Vector3d MisalignmentAt(absl::Time time) const;
  bool IsZero() const {
    return latency == 0.0 && misalignment_b.isZero(0.0) && reading_shifts.empty() &&
           cycle_period_s == 0.0;
  }
};

// A copy of the frames with every star-tracker quaternion corrected (and the gyro readings of
// `reading_shifts`).
std::vector<TelemetryFrame> CorrectStarTracker(const std::vector<TelemetryFrame>& frames,
                                               const BodyRates& rates,
                                               const StarTrackerCorrection& correction);

struct GyroInnovation {
  int id = 0;
  Eigen::Vector2d z = Eigen::Vector2d::Zero();      // star-tracker difference [rad]
  Eigen::Vector2d sigma = Eigen::Vector2d::Zero();  // sqrt(diag S) [rad]
};

struct StepRecord {
  int frame = 0;
  bool star_tracker_present = false;  // a valid star-tracker sample in the (corrected) data
  bool withheld = false;              // star tracker withheld at this step (held-out span)
  bool nis_formed = false;            // star-tracker differences formed (not eq. (12)-rejected)
  bool accepted = false;              // applied (passed eq. (14))
  int m = 0;                          // number of star-tracker differences
  double nis = 0.0;                   // z^T S^-1 z
  double log_det_s = 0.0;             // log det S, S in rad^2
  std::vector<GyroInnovation> innovations;
};

struct HeldOutGyroError {
  int id = 0;
  // Predicted spin axis against the one rebuilt from the withheld star tracker,
  // h_et_in - h_in, inertial axes (perpendicular to h_in to first order) [rad].
  Eigen::Vector3d error_in = Eigen::Vector3d::Zero();
  double sigma = 0.0;  // filter's 1-sigma of the spin-axis error (rms of its two axes) [rad]
};

struct HeldOutSample {
  int frame = 0;
  int span = 0;          // index into ModelRunOptions::withheld
  double seconds = 0.0;  // since the span's first frame
  // Attitude error in inertial axes, q_st = Exp(error_in) (x) q_est (conventions.h) [rad].
  Eigen::Vector3d error_in = Eigen::Vector3d::Zero();
  Eigen::Vector3d sigma_b = Eigen::Vector3d::Zero();  // filter's attitude 1-sigma [rad]
  std::vector<HeldOutGyroError> gyros;
};

struct ModelRunOptions {
  // Frame ranges [first, last] (inclusive) over which the star tracker is withheld.
  std::vector<std::pair<int, int>> withheld;
  // Continue from `start` (a checkpoint of the same configuration and layout taken before frame
  // `start_frame`) instead of from the first frame: the run's steps then begin at start_frame.
  // The session continues bit for bit (session.h ExportCheckpoint), so the steps before
  // start_frame of the run that took the checkpoint complete it.
  const SessionCheckpoint* start = nullptr;
  int start_frame = 0;
  // Checkpoints taken before each of these frames (ascending) into ModelRun::checkpoints.
  std::vector<int> checkpoint_frames;
  // Last frame to process (-1: to the end).
  int stop_frame = -1;
};

struct ModelRun {
  std::vector<StepRecord> steps;  // one per measurement step
  std::vector<HeldOutSample> held_out;
  std::vector<GyroEstimate> gyros;  // final estimates
  // Final covariance of each gyro's drift coefficients, same order as `gyros`
  // (EstimationSession::CoefficientCovariance).
  std::vector<Eigen::MatrixXd> coefficient_covariance;
  int resets = 0;                   // FILTER_RESET events
  int rejections = 0;               // star-tracker rejections (eq. (12), (14))
  // Before each frame of ModelRunOptions::checkpoint_frames that was reached, in that order.
  std::vector<SessionCheckpoint> checkpoints;
};

// Runs the session over `frames` (already corrected). Errors: those of
// EstimationSession::Create / AddFrame.
absl::StatusOr<ModelRun> RunModel(const SpacecraftConfig& config, const SessionOptions& options,
                                  const std::vector<TelemetryFrame>& frames,
                                  const ModelRunOptions& run_options = {});

// Innovation deviance, -2 log L up to a constant, of the star-tracker differences over the
// in-sample steps (not withheld) of a run: sum of min(nis, cap(m)) + log det S, where cap(m) is
// the chi-square(m) quantile at 1 - outlier_p: a step beyond it is an outlier whatever the model,
// and counts the same for every model (a contaminated-normal likelihood). Steps with a star
// tracker present but no differences formed (eq. (12) named the star tracker) count cap(m) plus
// the run's previous log det S, so every model is scored on the same steps.
struct Deviance {
  double value = 0.0;    // sum of the per-step terms
  double nis_sum = 0.0;  // sum of min(nis, cap) over the steps
  int components = 0;    // sum of m
  int steps = 0;
  int capped = 0;  // steps at the cap
};
inline constexpr double kOutlierP = 1e-4;
Deviance ComputeDeviance(const ModelRun& run, double outlier_p = kOutlierP);

// Per-step deviance terms in the same convention (0 where the step is not scored), by step index.
std::vector<double> StepDeviance(const ModelRun& run, double outlier_p = kOutlierP);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_MODEL_RUN_H_
