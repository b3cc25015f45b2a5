// Offline runs of the estimator over a whole recording: calibration (the filter over every
// frame) and the long-gap experiment of the paper's Fig. 7/8 (calibrate up to a time, then run
// without the star tracker and compare the attitude with the withheld star-tracker data).
// Pure computation; the CLI (client/commands/) does the files and the printing.
#ifndef ESG_ESTIMATOR_OFFLINE_H_
#define ESG_ESTIMATOR_OFFLINE_H_

#include <functional>
#include <map>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/session.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"

namespace esg::estimator {

using ProgressFn = std::function<void(double fraction)>;

struct CalibrationResult {
  std::vector<GyroEstimate> gyros;  // final estimates
  // sqrt(P/P0) per gyro id, per free coefficient index (drift_model.h theta).
  std::map<int, std::vector<std::pair<int, double>>> relative_sigma;
  std::vector<Event> events;
  std::map<Event::Kind, int> event_counts;
  int frames = 0;
  int measurement_steps = 0;
  int star_tracker_steps_used = 0;
  SessionState final_state = SessionState::kNoData;
  AttitudeEstimate final_attitude;
  // Star-tracker differences after the update of each step would need the truth; instead the
  // RMS of the accepted star-tracker innovations [rad] (z2..z5 of eq. (13)) is reported.
  double innovation_rms = 0.0;
  // The process-noise widening at the end as an unmodelled drift [deg/h] (noise_widening.h);
  // 0 when the filter ends as configured.
  double widened_drift_deg_h = 0.0;
  // The star-tracker latency at the end: configured, or estimated (latencySigmaS > 0).
  LatencyEstimate star_tracker_latency;
};

// Runs a session over every frame. The session after the last frame is returned through
// `session_out` when not null. Errors: those of EstimationSession::Create and AddFrame
// (a frame out of order names its index).
absl::StatusOr<CalibrationResult> RunCalibration(const SpacecraftConfig& config,
                                                 const SessionOptions& options,
                                                 const std::vector<TelemetryFrame>& frames,
                                                 const ProgressFn& progress = {},
                                                 EstimationSession* session_out = nullptr);

struct GapSample {
  absl::Time time;
  double hours_since_gap = 0.0;
  // Attitude error in inertial axes, q_st = Exp(error_in) (x) q_est [rad], and its angle.
  Eigen::Vector3d error_in = Eigen::Vector3d::Zero();
  double angle = 0.0;
  Eigen::Vector3d sigma_b = Eigen::Vector3d::Zero();  // filter's 1-sigma about body axes [rad]
  bool outlier = false;  // excluded from the fit (robust rejection)
};

struct GapResult {
  CalibrationResult calibration;  // state at the gap start
  std::vector<GapSample> samples;
  // Slope of each inertial error component against time (line_fit.h FitRobustLine: robust
  // to star-tracker outliers),
  // [rad/s]; its norm is the drift-caused error rate of the paper's Fig. 7/8.
  Eigen::Vector3d slope_in = Eigen::Vector3d::Zero();
  double drift_rate = 0.0;  // |slope_in| [rad/s]
  double final_error = 0.0;  // angle at the last sample [rad]
  double gap_hours = 0.0;
};

// Calibrates with every frame up to (and including) gap_start, then withholds the star tracker
// and runs on the gyro readings to the end. InvalidArgument if gap_start leaves no frame on
// either side or fewer than 3 star-tracker samples in the gap.
absl::StatusOr<GapResult> RunGap(const SpacecraftConfig& config, const SessionOptions& options,
                                 const std::vector<TelemetryFrame>& frames, absl::Time gap_start,
                                 const ProgressFn& progress = {});


}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_OFFLINE_H_
