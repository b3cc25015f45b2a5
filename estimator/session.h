// EstimationSession: the per-spacecraft estimation pipeline of the paper's section 2
// (docs/physics.md): an error-state extended Kalman filter over the running gyros,
// quasi-continuous correction by the star tracker, calibration of the drift model (models 1, 10,
// 11), fault detection by eq. (12) and (14), and long-gap prediction. Pure computation: frames
// in, reports out. Where each part lives: session.cc's file comment.
//
// FILTER STATE (error form, conventions.h: error = true - estimate): one block per running gyro,
// in the order of the gyros (working pair first, reference gyro first), indexed only through
// StateLayout (state_layout.h): spin-axis error dh_g (2), residual random-walk drift dw_int_g of
// eq. (11) (2, with model 11), errors of the free drift coefficients dtheta_g (0-13), of the free
// basis terms (basis_term.h, 0-16) and the misalignment dphi_g (3, when misalignmentSigma > 0).
// About 14 states per gyro, 42 for three running gyros with model 10+11. Before the gyro blocks, when the configuration gives the star
// tracker's latency a prior (latencySigmaS > 0), its error dtau [s]: the corrected star-tracker
// attitude q_st (x) Exp(w_b tau_est) then errs by the body rotation -w_b dtau.
//   dh_g and dw_int_g live in the gyro's tangent basis (t1_g, t2_g): t1 = e1 of the `int` frame
//   (conventions.h) projected perpendicular to h_in_g, t2 = h_in_g x t1; for the reference gyro
//   (t1, t2) = (e1, -e3), i.e. the paper's dh_int1_1 and -dh_int3_1 [rad]. The component of
//   dw_int along the spin axis moves nothing and is not a state [rad/s].
//   dphi_g: C_b_k(true) = Exp(phi_g) C_b_k(config) [rad].
//
// MEASUREMENTS every measurement step (60 s default), gyro readings interpolated (slerp) to the
// integration rate (8 Hz default) between telemetry frames:
//   z_avt  (per pair of healthy gyros) cos(theta_R) - cos(theta_S): predicted angle between the
//          inertial spin axes against the measured angle between the body-frame axes (eq. (13));
//   z_st   (2 per healthy gyro) T_g^T (h_et_in - h_in_g), h_et_in = C_in_b(star tracker) C_b_k
//          h_k(measured): the star-tracker differences z2..z5 of eq. (13), in the gyro's basis.
// The measurement noise covariance comes from one noise map (star-tracker noise about body axes,
// readout noise of every gyro), so its correlations across components are exact.
//
// SESSION STATES (progress of the filter; sensor health is its own dimension, below)
//   NO_DATA      no frame with a valid star-tracker quaternion and a readable pair yet.
//                -> CALIBRATING by AddFrame when such a frame initialises the filter.
//   CALIBRATING  filter running; free coefficients still converging.
//                -> CONVERGED when every free coefficient's sigma fell by less than 5% over the
//                last hour (and 2 h have passed).
//   CONVERGED    as CALIBRATING, coefficients settled.
//   AUTONOMOUS   star-tracker data absent or rejected for the last 3 steps (or withheld by
//                SetStarTrackerUse(false)): output from the gyros alone.
//   FAULTED      no usable pair remains: fewer than two running gyros are not excluded. No
//                attitude output.
// SENSOR HEALTH: degraded() when a running gyro is excluded (GyroEstimate::exclusion says why
// and when); the output then comes from a pair without it, valid, in whichever progress state
// the filter is. A gyro is excluded only for an abrupt fault of its readings or a drift change
// beyond filter.driftChangeLimitDegH (reading_fault_monitor.h, docs/decisions.md D94), never for
// a drift the model lacks.
// Invariants: (1) P is symmetric with a non-negative diagonal after every step; (2) every
// h_in_g is a unit vector; (3) a rejected measurement never changes the state; (4) frames are
// applied in strictly increasing time.
#ifndef ESG_ESTIMATOR_SESSION_H_
#define ESG_ESTIMATOR_SESSION_H_

#include <array>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/basis_term.h"
#include "estimator/calibration_model.h"
#include "estimator/channel_signal.h"
#include "estimator/consistency_monitor.h"
#include "estimator/mismatch_location.h"
#include "estimator/drift_model.h"
#include "estimator/gyro_change_detector.h"
#include "estimator/measurements.h"
#include "estimator/noise_widening.h"
#include "estimator/reading_fault_monitor.h"
#include "estimator/spacecraft_config.h"
#include "estimator/star_tracker_mount.h"
#include "estimator/state_layout.h"
#include "estimator/telemetry.h"

namespace esg::estimator {

class AttitudeProfile;

enum class SessionState { kNoData, kCalibrating, kConverged, kAutonomous, kFaulted };
const char* SessionStateName(SessionState s);

// An event: a rejection or a switch, with the numbers that decided it.
struct Event {
  enum class Kind {
    kStarTrackerInnovation,  // eq. (14) rejected the star-tracker measurements
    kStarTrackerFault,       // eq. (12) named the star tracker (also: a filter reset withheld
                             // because of it, docs/decisions.md D19)
    kWorkingPairFault,       // eq. (12) named the working pair, or isolated a gyro of it with
                             // three pairs (subsystem "gyro N"): output moved to a pair without it
    kReservePairFault,       // eq. (12) named the reserve pair, or isolated a gyro outside the
                             // working pair with three pairs (subsystem "gyro N")
    kGyroDataRejected,       // eq. (14) rejected an autonomous measurement z_avt
    kStarTrackerInvalid,     // the star tracker flagged its own sample invalid (not raised per
                             // sample; reserved for the service's outage alerts)
    kFilterReset,            // star-tracker data rejected for kResetAfterRejections steps in a
                             // row: the filter, not the star tracker, is taken to be wrong and the
                             // spin axes are re-initialised from the star tracker
    kModelInconsistent,      // the running chi-square test of the innovations failed: the
                             // configured model does not explain the data (consistency_monitor.h)
    kFaultAmbiguous,         // fault isolation with three pairs (fault_detection.h): mismatches
                             // exceeded but no single subsystem explains them; nothing excluded
    kFilterWidened,          // the process noise of the spin axes is widened (or narrowed, or
                             // still widened) by noise_widening.h: the star-tracker
                             // innovations stay larger than the configured model allows
    kGyroReadingMissing,     // a running gyro has no reading in this frame: no measurement of it,
                             // its drift mapped with a pair without it, output moved or not valid
    kGyroStarted,            // a configured gyro that was not running reports (the cold spare
                             // switched on) and joined the filter
    kDriftChanged,           // the accumulated star-tracker test (D33) named a gyro whose
                             // drift changed by less than filter.driftChangeLimitDegH: its
                             // coefficients are re-opened (D94); nothing excluded
    kStarTrackerRealigned,   // the pairs voted the star tracker faulty for a window of steps
                             // with a constant rotation between them (a mount shift,
                             // star_tracker_mount.h, D34): the star tracker is corrected by it
                             // and used again
  };
  Kind kind;
  absl::Time time;         // measurement epoch
  std::string subsystem;   // "star_tracker", "working_pair[1,2]", "gyro 2", ...
  double value = 0.0;      // the tested quantity
  double threshold = 0.0;  // its allowed value
  std::string unit;        // of value and threshold ("arcsec", "1")
  std::string message;
};
const char* EventKindName(Event::Kind kind);

// Consecutive measurement steps with star-tracker data present but rejected (eq. (12) or (14))
// after which the filter re-initialises its spin axes from the star tracker (docs/decisions.md).
inline constexpr int kResetAfterRejections = 10;

struct AttitudeEstimate {
  absl::Time time;
  Eigen::Quaterniond q_in_b = Eigen::Quaterniond::Identity();
  Eigen::Vector3d sigma_b = Eigen::Vector3d::Zero();  // 1-sigma about body x, y, z [rad]
  std::array<int, 2> pair = {0, 0};                   // gyro ids it was computed from
  bool valid = false;
  std::string invalid_reason;  // why not valid (empty when valid)
};

// Why a gyro was excluded (D94): an abrupt fault of its readings, or a drift change beyond the
// configured limit. kEarlier: excluded by a session restored from a checkpoint before version 7,
// which kept no reason.
enum class ExclusionReason { kNone, kReadingJump, kBeyondAnyDrift, kErratic, kDriftBeyondLimit, kEarlier };
const char* ExclusionReasonName(ExclusionReason r);

struct Exclusion {
  ExclusionReason reason = ExclusionReason::kNone;
  absl::Time time = absl::InfinitePast();  // measurement epoch of the exclusion
  // The evidence: kReadingJump the jump [arcsec] and its likelihood ratio over a drift change;
  // kBeyondAnyDrift and kDriftBeyondLimit the rate [deg/h] and the bound [deg/h]; kErratic the
  // window's chi-square and its threshold.
  double value = 0.0;
  double threshold = 0.0;
  // Which track showed it (reading_fault_monitor.h): 0 the star-tracker rebuild, 1 the rebuild
  // from the pair of the two other gyros, -1 none (kDriftBeyondLimit, kEarlier).
  int source = -1;
  std::string Describe() const;  // one sentence for operators
};

struct GyroEstimate {
  int id = 0;
  DriftCoefficients coefficients;        // full current model values [rad/s]
  DriftCoefficients sigma;               // 1-sigma, 0 where held [rad/s]
  // The configured basis terms (GyroConfig::basis_terms, same order) with their current values
  // [rad/s per unit of s], and each one's 1-sigma (0 where held), same unit.
  std::vector<BasisTerm> basis_terms;
  std::vector<double> basis_sigma;
  Eigen::Vector3d misalignment_b = Eigen::Vector3d::Zero();        // [rad]
  Eigen::Vector3d misalignment_sigma_b = Eigen::Vector3d::Zero();  // [rad]
  Eigen::Vector2d residual_drift = Eigen::Vector2d::Zero();        // dw_int [rad/s]
  Eigen::Vector2d residual_drift_sigma = Eigen::Vector2d::Zero();  // [rad/s]
  Eigen::Vector3d h_in = Eigen::Vector3d::UnitZ();                 // predicted spin axis
  Eigen::Vector2d spin_axis_sigma = Eigen::Vector2d::Zero();       // [rad]
  bool faulty = false;  // excluded
  Exclusion exclusion;  // why, when faulty
};

struct StepReport {
  absl::Time time;
  bool measurement_step = false;      // a measurement update was attempted at this frame
  bool star_tracker_used = false;     // star-tracker measurements were applied
  AttitudeEstimate attitude;          // output of the working (or reserve) pair
  std::vector<Event> events;
  // Star-tracker innovations of this step in the gyros' bases [rad] (empty if none formed).
  Eigen::VectorXd star_tracker_innovation;
  Eigen::VectorXd star_tracker_innovation_sigma;
  // Largest normalised (sequentially conditioned) star-tracker innovation of eq. (14) [1].
  double star_tracker_test_ratio = 0.0;
  // z^T S^-1 z and log det S of the star-tracker differences (before the eq. (14) decision), for
  // likelihood-based model comparison; 0 when none were formed.
  double star_tracker_nis = 0.0;
  double star_tracker_log_det_s = 0.0;
  // Autonomous innovations z_avt of this step [1] and their sigma.
  Eigen::VectorXd autonomous_innovation;
  Eigen::VectorXd autonomous_innovation_sigma;
  // The attitude error the propagation had accumulated, as this step's star-tracker update
  // estimates it: the rotation the update applied to the output attitude, a small-angle vector
  // about the body axes, q_in_b(after) = q_in_b(before) (x) Exp(attitude_error_b) [arcsec]
  // (conventions.h: error = true - estimate, so it is the estimate of the error of q_in_b(before)).
  // Its 1-sigma per body axis is sqrt(sigma_before^2 - sigma_after^2): under the filter's model the
  // correction has exactly the covariance the update removed, P_before - P_after (Joseph form with
  // the optimal gain: K S K^T), mapped to the attitude [arcsec]. Set only at a step whose
  // star-tracker measurements were applied to the pair that gives the output; absent otherwise
  // (no star tracker, rejected, a filter reset, an output that is not valid).
  std::optional<Eigen::Vector3d> attitude_error_b_arcsec;
  std::optional<Eigen::Vector3d> attitude_error_sigma_b_arcsec;
  SessionState state = SessionState::kNoData;
};

struct SessionOptions {
  ModelSpec model;
  // Initial 1-sigma of the residual drift dw_int [rad/s]; < 0 = derived (0.1 deg/h with model 11
  // alone, 0.01 deg/h on top of a calibrated model).
  double residual_drift_sigma = -1.0;
  // Process the autonomous measurements z_avt (eq. (13)); off only for experiments.
  bool use_autonomous_measurements = true;
  // The model-consistency monitor (consistency_monitor.h); its per-test level is derived in
  // Create from the measurement step for at most 0.1 expected false alarms per 30 days.
  int consistency_window_steps = 60;
  int consistency_test_every_steps = 15;
  // Widen the spin axes' process noise when the star-tracker innovations stay inconsistent
  // (noise_widening.h). Off in diagnosis runs, whose likelihoods must be those of the configured
  // model.
  bool adaptive_noise = true;
  NoiseWideningOptions widening;
  // Name a gyro whose own star-tracker differences fail over a window while the other two pass
  // (gyro_change_detector.h, D33), and judge every gyro's readings for abrupt faults
  // (reading_fault_monitor.h, D94): the judgement that excludes a gyro. Off in diagnosis runs,
  // which look for such changes as physics and exclude nothing.
  bool detect_drift_change = true;
  GyroChangeDetectorOptions drift_change;
  // Re-reference the star tracker to the gyros when the pairs vote it faulty with a constant
  // rotation between them (star_tracker_mount.h, D34). Off in diagnosis runs, which name a
  // star-tracker misalignment as physics.
  bool realign_star_tracker = true;
  StarTrackerMountOptions star_tracker_mount;
  // Diagnosis only (docs/discovery.md, "Time behaviour"); empty for calibration and the service.
  // Per-gyro residual random-walk intensities of eq. (11) [rad/s/sqrt(s)], replacing
  // config.random_walk for the listed gyro ids (gyro id, intensity).
  std::vector<std::pair<int, double>> random_walk_by_gyro;
  // Steps of free drift coefficients at a time: at the first frame at or after `time`, before
  // propagating to it, the variance sigma^2 is added to each free coefficient state of gyro
  // `gyro_id` with a drift_model.h theta index in [first, first + count): from then on the
  // coefficient is C(before) + Delta, Delta ~ N(0, sigma^2) independent of the past. A
  // coefficient held at its configured value (not free) is not affected. With `misalignment`
  // set, the variance sigma^2 [rad^2] is added instead to the gyro's three misalignment states
  // (first and count ignored; none when the gyro's misalignment is not estimated): its readings
  // jump by an unknown constant rotation of its case at `time` (a readout jump, a fault;
  // docs/discovery.md, "Time behaviour", D43).
  struct CoefficientRelease {
    int gyro_id = 0;
    int first = 0;
    int count = 0;
    absl::Time time = absl::InfiniteFuture();
    double sigma = 0.0;  // [rad/s]; [rad] with misalignment
    bool misalignment = false;
  };
  std::vector<CoefficientRelease> coefficient_releases;
  // How Propagate sizes the integration substeps between two frames (docs/physics.md,
  // "Propagation"; docs/decisions.md D120, D125). kMotionBounded (the default, D125): the fewest
  // substeps that keep, over each, within max_substep_turn_deg: the body's turn between the
  // frames (the attitude pair's attitudes), each reading's turn, each spin axis's turn by its
  // drift, and the phase of a basis term that varies with time; never more than kFixedRate
  // takes, and kFixedRate's count over an interval that holds a basis term's switch-on or for a
  // gyro with a channel term. kFixedRate: filter.integrationRateHz (the paper's 8 Hz), the
  // reference the motion-bounded substeps are measured against.
  enum class Substeps { kFixedRate, kMotionBounded };
  Substeps substeps = Substeps::kMotionBounded;
  double max_substep_turn_deg = 0.5;  // kMotionBounded: (0, 10] deg
};

// The residual random-walk intensity of eq. (11) a session with `options` gives gyro `gyro_id`
// [rad/s/sqrt(s)]: SessionOptions::random_walk_by_gyro where listed, else config.random_walk.
double ResidualRandomWalk(const SpacecraftConfig& config, const SessionOptions& options,
                          int gyro_id);

// A reading h_meas of gyro `gc` corrected for its readout distortion D (GyroConfig::
// readout_distortion; h_meas = normalise((I + D) h_k)): normalise((I + D)^-1 h_meas).
Eigen::Vector3d CorrectReadout(const GyroConfig& gc, const Eigen::Vector3d& h_meas);

// The initial 1-sigma of each gyro's residual drift dw_int a session with `options` sets [rad/s]:
// SessionOptions::residual_drift_sigma, or derived from the model.
double InitialResidualDriftSigma(const SessionOptions& options);

// Everything needed to resume exactly (bit for bit) where a session stopped. ExportCheckpoint
// writes version 8; FromCheckpoint reads versions 1 to 8.
struct SessionCheckpoint {
  int version = 1;
  std::vector<double> values;  // opaque, versioned layout written by ExportCheckpoint
};

// The star tracker's latency the filter corrects each sample with (spacecraft_config.h
// StarTrackerConfig::latency): the configured value, or the filter's estimate when the
// configuration gives it a prior (latency_sigma > 0).
struct LatencyEstimate {
  double latency_s = 0.0;  // [s]
  double sigma_s = 0.0;    // 1-sigma [s]; 0 when held at the configured value
  bool estimated = false;
};

// The rotation the star tracker's output is corrected by after a mount shift (D34): its sample
// q_st is used as q_st (x) Exp(-shift_b). Zero until the filter re-referenced the star tracker.
struct StarTrackerMount {
  Eigen::Vector3d shift_b = Eigen::Vector3d::Zero();  // [rad], body axes
  Eigen::Vector3d sigma_b = Eigen::Vector3d::Zero();  // its 1-sigma about body x, y, z [rad]
  int realignments = 0;
};

struct PredictedSample {
  absl::Time time;
  AttitudeEstimate attitude;
  std::vector<std::pair<int, Eigen::Vector3d>> h_in;  // gyro id, predicted inertial spin axis
};

class EstimationSession {
 public:
  // InvalidArgument if the configuration is invalid or the model frees nothing it can estimate.
  static absl::StatusOr<EstimationSession> Create(const SpacecraftConfig& config,
                                                  const SessionOptions& options);

  // Applies one frame (strictly after the previous one: OutOfRange otherwise), its readings
  // first corrected for the configured readout distortions (CorrectedForReadout). Propagates from
  // the previous frame at the integration rate and, at a measurement step, runs eq. (12), the
  // innovation test eq. (14) and the Joseph update. Rejections are events in the report, not
  // errors. Internal if the numerics fail (the session is then unchanged).
  absl::StatusOr<StepReport> AddFrame(const TelemetryFrame& frame);

  // Withholds (false) or restores star-tracker measurements, as for a long-gap experiment.
  void SetStarTrackerUse(bool use) { use_star_tracker_ = use; }

  // Readmits gyro `gyro_id`, excluded by the filter, on an operator's word (docs/service.md
  // "Readmitting a gyro"): its block leaves the state now, and it rejoins at the next measurement
  // step where it reports, as a cold spare switched on does (its spin axis rebuilt, its drift
  // model from the configured prior; a GYRO_STARTED event). NotFound "gyro_id: ..." for a gyro
  // not configured; FailedPrecondition "gyro_id: ..." for one not excluded (running, or not
  // running), or one of the output pair (no clean pair would carry the output meanwhile).
  absl::Status ReadmitGyro(int gyro_id);

  SessionState state() const { return state_; }
  // A running gyro is excluded: the output runs on a pair without it (SESSION STATES above).
  bool degraded() const;
  bool initialized() const { return initialized_; }
  absl::Time last_frame_time() const { return last_time_; }
  std::array<int, 2> working_pair() const { return working_pair_; }
  const SpacecraftConfig& config() const { return config_; }
  const SessionOptions& options() const { return options_; }
  // The integration substeps the last propagation took (SessionOptions::substeps); 0 before any.
  int last_propagation_substeps() const { return last_propagation_substeps_; }
  // The model-consistency monitor. In the checkpoint from version 2 (a session restored from
  // version 1 starts it with empty windows).
  const ConsistencyMonitor& consistency_monitor() const { return consistency_; }
  // The process-noise widening (noise_widening.h); scale() is 1 when the filter runs as
  // configured.
  const NoiseWidening& noise_widening() const { return widening_; }

  AttitudeEstimate CurrentAttitude() const;
  std::vector<GyroEstimate> Gyros() const;
  LatencyEstimate StarTrackerLatency() const;
  StarTrackerMount StarTrackerMountShift() const;
  // Covariance of gyro `id`'s drift coefficients in DriftVector order [rad^2/s^2] (drift_model.h),
  // 0 in the rows and columns of coefficients held; 0 x 0 when the gyro is not running.
  Eigen::MatrixXd CoefficientCovariance(int id) const;
  // sqrt(P/P0) of each free coefficient of gyro `id` (index into theta -> ratio).
  std::vector<std::pair<int, double>> RelativeSigma(int id) const;

  // Predicts from the current state without star tracker: at each time (after the last frame),
  // the gyro readings are those the planned profile implies (q_in_b from `planned`, or an inertial
  // hold of the current attitude when null); returns the attitude with its 1-sigma envelope and
  // the predicted inertial spin axes. The session itself is not changed.
  absl::StatusOr<std::vector<PredictedSample>> Predict(const std::vector<absl::Time>& times,
                                                       const AttitudeProfile* planned,
                                                       absl::Time planned_start) const;

  // Version 8: everything a session restored from it needs to continue bit for bit as this one
  // would (same reports, state and covariance), at any point, including before initialisation.
  // The values and their order (stored by the server) are listed in session_checkpoint.cc.
  SessionCheckpoint ExportCheckpoint() const;
  // Reads versions 1 to 8 (each lacks what the next added: version 1 lacks the consistency
  // monitor and the star-tracker anchoring flags, version 2 the process-noise widening, version 3
  // the estimated latency, version 4 the star-tracker mount, version 5 the basis terms' values
  // and the suspension voltages, version 6 the exclusion reasons and the reading-fault monitor,
  // version 7 the count of fixed drift coefficients before each gyro's theta:
  // session_checkpoint.cc; a session from versions 1-6 that was FAULTED with a usable pair left
  // resumes in its progress state, degraded). DataLoss, with a message starting "checkpoint", if
  // the version is unknown, the values are truncated or oversized, a field holds a value it
  // cannot (an integer or flag field that is not one, a non-finite real, an unknown state, a
  // pair naming gyros the session lacks, an invalid covariance), or the checkpoint does not fit
  // this configuration and model.
  static absl::StatusOr<EstimationSession> FromCheckpoint(const SpacecraftConfig& config,
                                                          const SessionOptions& options,
                                                          const SessionCheckpoint& checkpoint);

  // Filter internals, exposed read-only for tests and diagnostics.
  const Eigen::MatrixXd& covariance() const { return P_; }
  int state_size() const { return static_cast<int>(P_.rows()); }

 private:
  struct GyroState {
    int id = 0;
    Eigen::Matrix3d C_b_k_config;
    Eigen::Vector3d h_in = Eigen::Vector3d::UnitZ();
    Eigen::Vector3d t1 = Eigen::Vector3d::UnitX();  // tangent basis, t2 = h_in x t1
    Eigen::Vector2d residual_drift = Eigen::Vector2d::Zero();
    DriftVector theta = DriftVector::Zero();
    Eigen::Vector3d phi_b = Eigen::Vector3d::Zero();
    bool faulty = false;
    Exclusion exclusion;  // why faulty (D94); in the checkpoint from version 7
    // d(spin-axis motion)/d(drivers) since the last measurement update, inertial (3 x the
    // gyro's spin-axis drivers, state_layout.h): the propagation's E carried to inertial axes
    // and summed over the frames. In the checkpoint from version 7.
    Eigen::MatrixXd motion_in;
    // Whether the latest frame carried this gyro's reading; h_k_last is that reading, or when it
    // did not, the case-frame axis the attitude of a pair with fresh readings implies
    // (session_propagation.cc). For interpolation to the integration rate.
    bool has_reading = false;
    Eigen::Vector3d h_k_last = Eigen::Vector3d::UnitZ();
    // The gyro's basis terms (GyroConfig::basis_terms) at their current values: the configured
    // ones, the free ones fed back by ApplyCorrection. In the checkpoint from version 6.
    std::vector<BasisTerm> basis;
    // The latest suspension offset voltages the frames carried [V] (u_k_mv in mV), held while
    // frames lack them; none received yet: empty (a voltage term then gives 0). In the
    // checkpoint from version 6.
    std::optional<Eigen::Vector3d> u_k_v;

    Eigen::Vector3d t2() const { return h_in.cross(t1); }
    Eigen::Matrix<double, 3, 2> T() const;
    Eigen::Matrix3d C_b_k() const;
  };

  EstimationSession() = default;

  // session_initialization.cc
  absl::Status Initialize(const TelemetryFrame& frame);
  // Sets every running gyro's h_in from the star tracker (h_in = C_in_b C_b_k h_k) and the
  // spin-axis blocks of P to the matching prior (misalignment, shared star-tracker noise, readout);
  // the other blocks of P are kept, cross terms with the spin axes are cleared.
  void SpinAxesFromStarTracker(const Eigen::Matrix3d& C_in_b);
  // A configured gyro that was not running and reports in this frame (a cold spare the
  // spacecraft switched on) joins the filter at a measurement step: its spin axis rebuilt from
  // the star tracker (when this step accepted it) or the output pair, its block appended to the
  // state with the configured prior; a GYRO_STARTED event.
  void StartSwitchedOnGyros(const TelemetryFrame& frame, StepReport& report);
  // The prior of gyros_[i]'s residual drift (eq. (11)), free coefficients and misalignment,
  // written into the diagonal blocks of P (layout_ indices).
  void SetDriftAndMisalignmentPrior(int i, Eigen::MatrixXd& P) const;

  // session_propagation.cc
  absl::Status Propagate(const TelemetryFrame& frame);
  // The steps of Propagate and of FromCheckpoint, each a function stating what it reads and what
  // it writes or refuses (defined in session_propagation.cc and session_checkpoint.cc; nested in
  // the session so that they reach its state without declaring each step here).
  struct PropagationSteps;
  struct CheckpointRestore;

  // session_update.cc
  absl::Status MeasurementUpdate(const TelemetryFrame& frame, StepReport& report);
  // The steps of MeasurementUpdate and the decisions of IsolateWithThreePairs, each a function
  // stating what it reads and writes (defined in session_update.cc, nested like the two above).
  struct UpdateSteps;
  struct IsolationSteps;
  // Fault isolation with the three pairs of the running gyros `ids` (all with a reading) and the
  // star tracker when `st_present` (q_st, covariance S_st in inertial axes): DecideIsolation of
  // fault_detection.h, applied (exclusion, output pair, events). Clears st_available when the star
  // tracker is named; sets st_agrees_with_pairs when every healthy pair agrees with the star
  // tracker. False (nothing done) when a pair attitude cannot be formed.
  bool IsolateWithThreePairs(const TelemetryFrame& frame, const std::array<int, 3>& ids,
                             bool st_present, const Eigen::Quaterniond& q_st,
                             const Eigen::Matrix3d& S_st, StepReport& report, bool& st_available,
                             bool& st_agrees_with_pairs, int& withheld_gyro);
  void ApplyCorrection(const Eigen::VectorXd& dx);
  // Gyro gyros_[i]'s star-tracker difference (eq. (13)) against the corrected star tracker
  // C_in_b_st, and its two rows of H over the whole state (spin axis, misalignment, latency):
  // the one place both the update and the three-pair isolation (D22) form it.
  struct StarTrackerRows {
    StarTrackerDifference d;
    Eigen::MatrixXd H;  // 2 x state_size()
  };
  StarTrackerRows GyroStarTrackerRows(int i, const Eigen::Matrix3d& C_in_b_st) const;
  // The star tracker's sample q_st corrected for a mount shift (D34) and for the latency
  // latency_s_ with the body rate of the current interval:
  // q_in_b(t) = q_st(t) (x) Exp(-shift_b) (x) Exp(w_b latency).
  Eigen::Quaterniond StarTrackerCorrected(const Eigen::Quaterniond& q_st) const;
  // A step where the pairs voted the star tracker faulty (`voted`) or not: feeds the mount-shift
  // test (star_tracker_mount.h) with the rotation from the output pair to the corrected star
  // tracker q_st; when it calls the shift constant, corrects the star tracker by it and reports
  // STAR_TRACKER_REALIGNED. True when the star tracker was re-referenced at this step.
  bool CheckStarTrackerMount(const TelemetryFrame& frame, bool voted, const Eigen::Quaterniond& q_st,
                             StepReport& report);

  // session_reading_faults.cc (D94)
  // Feeds the reading-fault monitor with this step's tracks (the star-tracker rebuild of every
  // gyro with a reading when q_st is present, the rebuild from the pair of the two others when
  // three gyros read) and records each verdict in abrupt_.
  void TrackReadings(const TelemetryFrame& frame, bool st_present, const Eigen::Quaterniond& q_st,
                     const std::vector<int>& fresh);
  // The current values of gyro gyros_[i]'s spin-axis drivers (residual drift, free
  // coefficients, free basis terms: the order of state_layout.h).
  Eigen::VectorXd DriverValues(int i) const;
  // After the step's update: the tracks' posterior residuals.
  void TrackPosteriors(const TelemetryFrame& frame, bool st_present);
  // The verdict that lets gyro `id` be excluded: one within the last kAbruptMemorySteps
  // measurement steps, or nullopt (then whatever names the gyro is a drift the model lacks).
  struct AbruptRecord {
    absl::Time time = absl::InfinitePast();
    ReadingVerdict verdict = ReadingVerdict::kNone;
    ReadingFaultMonitor::Source source = ReadingFaultMonitor::Source::kStarTracker;
    double value = 0.0;
    double threshold = 0.0;
    double statistic = 0.0;
  };
  std::optional<AbruptRecord> RecentAbrupt(int id, absl::Time now) const;
  // A gyro named faulty without a verdict of its readings: withheld at the first step it is
  // named (its readings' verdict may need one more step), applied from the second step in a row
  // on (a drift the model lacks is for the filter to absorb). True: withhold it now.
  bool WithholdUnverified(int id, absl::Time now);
  // The exclusion record a recent abrupt verdict gives.
  static Exclusion ExclusionFrom(const AbruptRecord& a);
  // The bound on gyro gyros_[i]'s drift change over one interval [rad/s]: the configured limit
  // plus three times the model's own rate uncertainty (free coefficients, basis terms, residual
  // drift, from P at the current reading) plus the widening's equivalent drift.
  double DriftBound(int i) const;
  // The model's own uncertainty of gyro gyros_[i]'s spin-axis rate, in its tangent basis T()
  // [(rad/s)^2]: the covariance of its drivers (residual drift, free coefficients, free basis
  // terms) in P carried to the rate; zero when it has none.
  Eigen::Matrix2d ModelRateCovariance(int i) const;
  // Where a failing consistency test's mismatch sits, from the reading-fault monitor's tracks
  // (mismatch_location.h).
  MismatchLocation LocateModelMismatch() const;
  // Re-opens gyro `id`'s free coefficients and basis terms (their initial variance added) and
  // its residual drift (the change's square added) after a drift change below the limit.
  void ReopenDrift(int id, double change_rad_s);
  // Excludes gyro `id` with `why` (no event: the caller reports it).
  void MarkExcluded(int id, const Exclusion& why);
  // Covariance in inertial axes of the corrected star-tracker attitude (C_in_b_st its rotation
  // matrix): the configured noise about the body axes, plus, while the latency is a state, its
  // variance times the body rate's direction.
  Eigen::Matrix3d StarTrackerCovarianceIn(const Eigen::Matrix3d& C_in_b_st) const;
  // The star tracker's noise variance about each body axis [rad^2]: the configured noise plus
  // that of the latency correction's rate, |rate extrapolation| (|latency| + its sigma) as a
  // 1-sigma about every axis.
  Eigen::Vector3d StarTrackerVarianceB() const;
  // D21: the configured model is known not to fit the data (the consistency monitor's latest
  // test failed, or the process noise is widened), and which of the two says so.
  bool ModelKnownNotToFit() const;
  const char* ModelMisfitEvidence() const;

  // session_attitude.cc
  // Attitude of a pair from predicted h_in and the given case-frame readings (nullopt if either
  // gyro has no reading), with its covariance in inertial axes when `covariance` is set.
  // When `jacobian_state` / `jacobian_readout` are set, also the linearisation of the attitude
  // error (inertial axes): 3 x state_size against the state error, 3 x 2 gyro_count against the
  // readout noise (columns 2i, 2i+1: TangentBasis(h_k) of gyros_[i]).
  std::optional<Eigen::Quaterniond> PairQuaternion(int a, int b, const Eigen::Vector3d& h_k_a,
                                                   const Eigen::Vector3d& h_k_b,
                                                   Eigen::Matrix3d* covariance_in,
                                                   Eigen::MatrixXd* jacobian_state = nullptr,
                                                   Eigen::MatrixXd* jacobian_readout = nullptr) const;
  AttitudeEstimate OutputAttitude(absl::Time time) const;
  // The pair the output and the drift mapping use: the working pair when both its gyros have a
  // reading in the latest frame, otherwise the first pair of running, not excluded gyros that
  // both have one (running order: working pair first), otherwise the working pair.
  std::array<int, 2> AttitudePair() const;

  // session.cc
  void UpdateState(const StepReport& report);
  // sqrt(P/P0) of state `idx`, as sqrt(P) / sqrt(P0): with P finite and P0 a positive normal
  // number (the configuration's prior sigmas and the checkpoint restore guarantee both) it is
  // finite, sqrt(DBL_MAX) / sqrt(DBL_MIN) being below DBL_MAX. The quotient P / P0 overflowed.
  double RelativeSigmaOf(int idx) const;
  // The frame as the session uses it: each gyro's reading corrected for its configured readout
  // distortion D, h_k = normalise((I + D)^-1 h_meas) (GyroConfig::readout_distortion); readings
  // of gyros without one are unchanged. The one place readings enter (AddFrame).
  TelemetryFrame CorrectedForReadout(const TelemetryFrame& frame) const;
  // Applies the options' coefficient releases whose time lies in (last_time_, frame_time].
  void ApplyCoefficientReleases(absl::Time frame_time);
  // Residual random-walk intensity of gyro `id` [rad/s/sqrt(s)] (options' per-gyro value or the
  // configuration's).
  double RandomWalkOf(int id) const;
  // A GYRO_READING_MISSING event per running, not excluded gyro without a reading in the latest
  // frame (after the output of `report` is set).
  void ReportMissingReadings(StepReport& report) const;
  // The state layout of `gyros` (each configured in `config`) under `model`: the free
  // coefficients and the misalignment states follow from the configured sigmas.
  static StateLayout LayoutFor(const SpacecraftConfig& config, const ModelSpec& model,
                               const std::vector<GyroState>& gyros);
  int gyro_count() const { return static_cast<int>(gyros_.size()); }
  // Index of gyro `id` in gyros_ (and in layout_), -1 if it is not running.
  int IndexOf(int id) const;
  GyroState* Find(int id);
  const GyroState* Find(int id) const;

  SpacecraftConfig config_;
  SessionOptions options_;
  std::vector<GyroState> gyros_;  // running gyros, working pair first
  StateLayout layout_;            // state indices of gyros_[i], rebuilt with gyros_
  Eigen::MatrixXd P_;
  Eigen::MatrixXd P0_;
  bool initialized_ = false;
  bool use_star_tracker_ = true;
  absl::Time last_time_ = absl::InfinitePast();
  absl::Time last_update_time_ = absl::InfinitePast();
  absl::Time start_time_ = absl::InfinitePast();
  std::array<int, 2> working_pair_ = {0, 0};
  std::array<int, 2> reserve_pair_ = {0, 0};
  SessionState state_ = SessionState::kNoData;
  int steps_without_star_tracker_ = 0;
  int consecutive_rejections_ = 0;
  // eq. (12) named the star tracker faulty during the current streak of rejections: the filter
  // reset must not re-anchor to it (docs/decisions.md D19). In the checkpoint from version 2.
  bool star_tracker_voted_faulty_ = false;
  // The star tracker has been accepted for kResetAfterRejections steps in a row since the filter
  // started (D19). In the checkpoint from version 2 (with consecutive_accepted_); a session
  // restored from version 1 counts as anchored.
  bool star_tracker_accepted_ = true;
  int consecutive_accepted_ = 0;
  // Predict integrates with substeps sized to the motion of the readings instead of the
  // configured rate (exact for an inertial hold, see Predict).
  bool adaptive_integration_ = false;
  int last_propagation_substeps_ = 0;
  // Relative-sigma history for the convergence test: (time, max ratio change reference).
  absl::Time convergence_mark_time_ = absl::InfinitePast();
  Eigen::VectorXd convergence_mark_sigma_;
  bool converged_ = false;
  ConsistencyMonitor consistency_;
  NoiseWidening widening_;
  // The gyro the three-pair isolation named at the measurement step suspect_time_ with evidence
  // below kImmediateIsolationStrength (D24): excluded if the next step names it again; 0: none.
  int suspect_gyro_ = 0;
  absl::Time suspect_time_ = absl::InfinitePast();
  // The per-gyro accumulated star-tracker test (D33). In the checkpoint from version 4.
  GyroChangeDetector change_detector_;
  // The star-tracker mount-shift test and the correction it found (D34): st_mount_b_ the
  // rotation [rad, body axes], st_mount_var_b_ its variance about each body axis [rad^2] (summed
  // over the corrections), st_mount_noise_var_b_ the part of it counted as star-tracker noise
  // (when some gyro's misalignment is not a state). In the checkpoint from version 5.
  StarTrackerMountMonitor mount_monitor_;
  // The held channels and lags the basis terms of kind channel read (channel_signal.h), advanced
  // at every frame after its interval is integrated; empty without such terms. In the checkpoint
  // from version 9.
  ChannelSignals channel_signals_;
  Eigen::Vector3d st_mount_b_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d st_mount_var_b_ = Eigen::Vector3d::Zero();
  Eigen::Vector3d st_mount_noise_var_b_ = Eigen::Vector3d::Zero();
  int st_realignments_ = 0;
  // Body rate over the interval of the current frame [rad/s], set by Propagate for the star-tracker
  // latency correction of MeasurementUpdate (recomputed every frame: not in the checkpoint).
  Eigen::Vector3d body_rate_b_ = Eigen::Vector3d::Zero();
  // The part of body_rate_b_ extrapolated from the previous interval's mean rate [rad/s]; its
  // size times the latency is taken as the 1-sigma error of the correction (transient).
  Eigen::Vector3d rate_extrapolation_b_ = Eigen::Vector3d::Zero();
  // The mean body rate of the last interval [rad/s] and its length [s] (0: none measured), the
  // extrapolation's second point. In the checkpoint from version 4.
  Eigen::Vector3d previous_mean_rate_b_ = Eigen::Vector3d::Zero();
  double previous_interval_s_ = 0.0;
  // The star-tracker latency the samples are corrected with [s]: the configured one, or its
  // estimate when layout_.has_latency() (fed back by ApplyCorrection). In the checkpoint from
  // version 4.
  double latency_s_ = 0.0;
  // The reading-fault monitor's tracks and each gyro's latest verdict (D94). In the checkpoint
  // from version 7.
  ReadingFaultMonitor reading_monitor_;
  std::map<int, AbruptRecord> abrupt_;
  // The gyro last named without a verdict and the step (WithholdUnverified). In the checkpoint
  // from version 7.
  int unverified_gyro_ = 0;
  absl::Time unverified_time_ = absl::InfinitePast();
  // The gyro the accumulated test (D33) named whose drift change is being measured, and when it
  // was named; 0: none (D94). In the checkpoint from version 7.
  int drift_change_gyro_ = 0;
  absl::Time drift_change_named_ = absl::InfinitePast();
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_SESSION_H_
