// ReadingFaultMonitor: tells an abrupt fault of a gyro's readings from a drift the model lacks
// (docs/decisions.md D94). Every exclusion of a gyro needs its verdict: a drift the model lacks,
// however it behaves in time, is never a reason to exclude a gyro; a reading that jumps, freezes
// while the spacecraft turns, turns erratic, or a drift that changes by more than the configured
// limit is.
//
// THE TRACK. At each measurement step with a star-tracker sample, a running gyro g with a reading
// gives the star-tracker rebuild of its spin axis, h_et_in = C_in_b(star tracker) C_b_k h_k
// (eq. (13)). Its track is the rebuild minus the spin axis the model carries:
//   x_g(k) = x_g(k-1) + u_g(k),
//   u_g(k) = [h_et_in(k) - h_prior(k)] - [h_et_in(k-1) - h_post(k-1)] + J_k (d(k-1) - d_ref)
// (inertial axes [rad]). h_prior(k) - h_post(k-1) is the motion the model predicted over the
// interval with its drivers d(k-1) (residual drift, coefficients, basis terms), J_k that
// motion's derivative against them, and d_ref the drivers when the track started: the track
// measures against one model, not against a model the filter keeps correcting. The filter's
// own state errors cancel exactly and u_g(k) = (true motion - model motion) + n(k) - n(k-1), n the
// rebuild's white noise (star tracker and readout, covariance N_k from the noise map of the
// update). The track is x_g(k) = a + (integral of the model's rate error) + n(k): a curve whose
// slope is whatever the model lacks, plus white noise of known covariance. It restarts when the
// previous measurement step gave no rebuild (a star-tracker outage: other measurements then move
// the spin axis) or the spin axes were re-initialised.
//
// THE HYPOTHESES over the window of the last W + 1 samples x_0..x_N (times t_j), projected on
// the spin axis's current tangent plane and weighted by N_j^-1:
//   line   x = a + b t                         the model's rate error b, constant over the window
//   drift  x = a + b t + c (t - t_on)+         the rate changes by c at some t_on: any sample
//                                              time of the window, or 3 points inside the
//                                              interval before the jump's (an onset inside an
//                                              interval); also a quadratic (a steady change)
//   jump   x = a + b t + J [t >= t_j]          the reading jumps by J between t_{j-1} and t_j, for
//                                              j = N-1 and N-2 (two or three samples after it)
// A drift the model lacks changes the spin axis's rate, never its position: constant, growing,
// cycling or wandering, over two measurement steps it is a line or a rate change. A reading
// fault displaces the reading. Verdicts for gyro g at the step:
//   kJump     the jump beats every drift alternative by k_d^2 and the line by k_d^2
//             (generalised likelihood ratios, chi-square with 2 degrees of freedom: 3.7e-6 each
//             at k_d = 5); decided at the second or third step after the jump;
//   kBeyond   the last increment departs from the window's rate by more than any drift change
//             within the bound moves the axis in one step: |c| - bound > k_d sigma_c along c,
//             c = (u_N - b dt)/dt, bound = the drift-change limit plus the model's own rate
//             uncertainty (the session's) plus a slow reading error (an unconfigured
//             misalignment or scale error, kSlowReadingErrorRad) times the reading's turn over
//             the interval divided by dt (the rate such an error gives a turning reading). A reading jump of arcminutes, a reading frozen while
//             the spacecraft turns, a drift change beyond the limit;
//   kErratic  the window's weighted residual about the smooth curves a drift gives (a
//             quadratic; a line with a rate change at any sample) exceeds chi2inv(1 - 1e-7,
//             2 (N + 1) - 6) and 9 per degree of freedom: readings scattered at least three
//             times beyond their noise.
// A verdict is the gyro's only when no other gyro with a rebuild at the step has one: an error of
// the star tracker turns every rebuild at once (a gyro whose axis lies along the error's axis
// can miss it, so one passing gyro is not enough to blame the star tracker; two with a verdict
// are enough to blame nothing).
// DriftChange(g) estimates the rate change over the window (the best onset among its samples),
// with its covariance and the bound, for the drift-change alert (the accumulated test,
// gyro_change_detector.h, names the gyro; this says by how much, and whether beyond the limit).
#ifndef ESG_ESTIMATOR_READING_FAULT_MONITOR_H_
#define ESG_ESTIMATOR_READING_FAULT_MONITOR_H_

#include <deque>
#include <map>
#include <optional>
#include <vector>

#include "Eigen/Core"
#include "absl/container/inlined_vector.h"
#include "absl/status/status.h"
#include "absl/time/time.h"
#include "absl/types/span.h"
#include "estimator/units.h"

namespace esg::estimator {

// A reading error that changes only as the reading turns (an unconfigured misalignment of the
// gyro's case, a readout scale error): allowed up to this angle per radian of turn [rad]. 2
// arcmin covers misalignments of 40-80 arcsec and scale errors of 300 ppm (62 arcsec at most)
// with room; a configured misalignment is a filter state, its uncertainty in the bound instead.
// On the paper's calibration profile (a turn of 6 deg a minute) it adds 0.21 deg/h to the bound.
inline constexpr double kSlowReadingErrorRad = 2.0 * 60.0 * kRadPerArcsec;

// The largest turn of a reading over one interval the monitor keeps [rad]: beyond any real one
// (a spacecraft turning at 1 rad/s for 11 days between two measurement steps). A larger or
// overflowing turn (a corrupt body rate restored from a checkpoint) is kept as this, so the
// monitor's state stays finite and its checkpoint restores.
inline constexpr double kMaxTurnRad = 1e6;

struct ReadingFaultOptions {
  int window_steps = 20;        // W: increments in the window (W + 1 samples)
  double decision_chi2 = 25.0;  // k_d^2: each likelihood ratio and the beyond test
  double erratic_alpha = 1e-7;  // the erratic test's level per gyro and step
  double erratic_scale = 3.0;   // and scatter at least this many times the stated noise
};

enum class ReadingVerdict { kNone, kJump, kBeyond, kErratic };
const char* ReadingVerdictName(ReadingVerdict v);

class ReadingFaultMonitor {
 public:
  explicit ReadingFaultMonitor(ReadingFaultOptions options = {});

  // One gyro's sample at a measurement step: the prior rebuild residual h_et_in - h_prior
  // (inertial, in the tangent plane [rad]), its noise covariance N (inertial [rad^2]), the
  // tangent basis T (3 x 2) of the current spin axis, the drift bound for the interval since the
  // last sample [rad/s], the reading's turn over it [rad] and that turn as a rotation vector in
  // inertial axes (the body rate carried to inertial axes times the interval [rad]; |turn_in| =
  // turn, or zero with turn_in_known false when no attitude gives its axis).
  // Where the rebuild's attitude comes from: the star tracker, or the pair of the two other
  // running gyros (free of the star tracker; its noise the three gyros' readout noise, its drift
  // bound the three gyros'). A gyro has one window per source; a verdict of either counts.
  enum class Source { kStarTracker = 0, kPair = 1 };
  struct Sample {
    int gyro_id = 0;
    Source source = Source::kStarTracker;
    Eigen::Vector3d prior_residual_in = Eigen::Vector3d::Zero();
    Eigen::Matrix3d noise_in = Eigen::Matrix3d::Zero();
    Eigen::Matrix<double, 3, 2> T = Eigen::Matrix<double, 3, 2>::Zero();
    double drift_bound = 0.0;
    double turn = 0.0;
    Eigen::Vector3d turn_in = Eigen::Vector3d::Zero();
    bool turn_in_known = false;
    // The model's drivers (the filter's estimates of what moves the spin axis: residual drift,
    // coefficients, basis terms) and the motion over the interval against them, 3 x drivers
    // [rad per unit]: the track measures the motion against the model as it was when the track
    // started (drivers_ref), so that the filter's corrections of its coefficients, large after
    // they are re-opened, do not move the track: u += motion_jacobian_in (drivers - drivers_ref).
    Eigen::VectorXd drivers;
    Eigen::MatrixXd motion_jacobian_in;
  };
  struct Result {
    int gyro_id = 0;
    Source source = Source::kStarTracker;
    ReadingVerdict verdict = ReadingVerdict::kNone;
    // kJump: |J| [rad] and its likelihood ratio over the best rate change; kBeyond: |c| [rad/s],
    // the bound [rad/s] and the test's chi-square; kErratic: the residual chi-square and its
    // threshold.
    double value = 0.0;
    double threshold = 0.0;
    double statistic = 0.0;
  };

  // Adds the step's samples (every running gyro with a rebuild at time `t`, per source) and
  // returns each gyro's verdicts (one per source; the star tracker's after the "only one gyro"
  // rule above: the pair source does not involve the star tracker, and a reading fault of one
  // gyro moves the pair rebuilds of the others too). A window without a sample at this step, or
  // without a posterior at the previous step, restarts.
  std::vector<Result> AddStep(absl::Time t, const std::vector<Sample>& samples);
  // After the step's update: a gyro's posterior residual (rebuild - h_post) [rad], the next
  // increment's start.
  void SetPosterior(int gyro_id, Source source, const Eigen::Vector3d& posterior_residual_in);
  // Every window restarts (spin axes re-initialised, the star tracker re-referenced).
  void Clear();
  const ReadingFaultOptions& options() const { return options_; }

  struct DriftChange {
    Eigen::Vector2d c = Eigen::Vector2d::Zero();  // in the tangent basis T of the last sample [rad/s]
    Eigen::Matrix2d cov = Eigen::Matrix2d::Zero();
    double magnitude = 0.0;  // |c| [rad/s]
    double bound = 0.0;      // [rad/s]
    double beyond_chi2 = 0.0;
    absl::Time onset;
    bool beyond = false;     // beyond_chi2 >= decision_chi2
    bool below = false;      // |c| below the bound by 3 sigma along c
    // The reading's mean turn rate over the window's intervals before and after the onset
    // [rad/s] (both the window's mean when the change began before the window). A reading error
    // that changes only as the reading turns (an unconfigured misalignment delta of the gyro's
    // case, a readout scale error: kSlowReadingErrorRad per radian) gives a rate error of at
    // most kSlowReadingErrorRad times the turn rate: for a misalignment, the rebuild's error
    // delta_in x h_in moves at (w_in x delta_in) x h_in, linear in the body rate w_in. So where
    // the turn changes at the onset (a slew's end, an attitude-mode switch, the turn's axis
    // moving at the same rate) such an error changes the fitted rate by up to
    // kSlowReadingErrorRad max |w_m - w_k| over the intervals k before and m after the onset,
    // w the interval's mean body rate in inertial axes (slow_reading_change [rad/s]; the fitted
    // rates are weighted means of the intervals'; a misalignment turning with the body within
    // the window is left out); turn_axis_change the angle between the mean rates before and
    // after [rad] (0 when either is zero). A window holding a point without the turn's axis (restored
    // from a checkpoint before version 9) uses the scalar rates, |after - before|.
    // may_be_slow_reading_error: |c| minus 3 sigma along c is within slow_reading_change, the
    // change as large as such an error gives there.
    double turn_rate_before = 0.0;
    double turn_rate_after = 0.0;
    double turn_axis_change = 0.0;
    double slow_reading_change = 0.0;
    bool may_be_slow_reading_error = false;
    // Neither: undecided, more steps after the onset will tell (the estimate's sigma falls as
    // the steps after it to the power 1.5).
  };
  // The best rate change of gyro `gyro_id`'s window (nullopt with fewer than 4 samples).
  std::optional<DriftChange> EstimateDriftChange(int gyro_id, Source source) const;

  // How far gyro `gyro_id`'s window departs from the model (the model-consistency alert's
  // location, mismatch_location.h). Under the model, the track is x_j = a + b tau_j + n_j: a free
  // offset a, a rate error b drawn from the model's own rate uncertainty N(0, rate_cov) (2 x 2
  // in the tangent basis of the last sample [(rad/s)^2], the session's covariance of its drivers
  // carried to the spin axis's rate) and the white noise n_j of known covariance. The statistic
  // is min over a, b of sum (y_j - a - b tau_j)^T W_j (...) + b^T rate_cov^-1 b, which under the
  // model is chi-square with 2 (n - 1) degrees of freedom (the Gaussian marginal of b, a
  // profiled): a rate beyond the model's uncertainty (a drift it lacks) and scatter beyond the
  // configured noise (a noisier star tracker) both raise it. nullopt with fewer than 4 samples.
  // The drift random walk within the window is left out: over the default 20 steps of 60 s at
  // 0.0015 deg/h/sqrt(h) it moves the track by about 0.5 arcsec, against 5-30 arcsec of noise.
  struct Misfit {
    double chi2 = 0.0;
    int dof = 0;
    int samples = 0;
  };
  std::optional<Misfit> ModelMisfit(int gyro_id, Source source,
                                    const Eigen::Matrix2d& rate_cov) const;

  // A window projected on the tangent plane: y_j = T^T x_j, weights W_j = (T^T N_j T)^-1 (cov
  // their inverse), times tau_j [s] relative to the last point.
  // A window's points in the track's tangent plane, inline up to 32 (the default window is 21):
  // the monitor projects every window at every step.
  struct Projected {
    absl::InlinedVector<Eigen::Vector2d, 32> y;
    absl::InlinedVector<Eigen::Matrix2d, 32> W;
    absl::InlinedVector<Eigen::Matrix2d, 32> cov;
    absl::InlinedVector<double, 32> tau;
  };

  // State for the session checkpoint; RestoreState returns DataLoss naming the field (the
  // object unchanged) if the values do not fit.
  std::vector<double> ExportState() const;
  absl::Status RestoreState(absl::Span<const double> state);
  // The turns' axes of the window's points (checkpoint version 9, after ExportState's block):
  // per track in ExportState's order, per point, turn_in (3) and turn_in_known. RestoreTurnAxes
  // after RestoreState; DataLoss naming the field (the object unchanged) when the count is not
  // 4 per point or a value does not fit. Points restored without it have no axis.
  std::vector<double> ExportTurnAxes() const;
  absl::Status RestoreTurnAxes(absl::Span<const double> state);

 private:
  struct Point {
    absl::Time time;
    Eigen::Vector3d x_in = Eigen::Vector3d::Zero();
    Eigen::Matrix3d noise_in = Eigen::Matrix3d::Zero();
    double drift_bound = 0.0;
    double turn = 0.0;
    Eigen::Vector3d turn_in = Eigen::Vector3d::Zero();
    bool turn_in_known = false;
  };
  struct Track {
    std::deque<Point> points;
    Eigen::Matrix<double, 3, 2> T = Eigen::Matrix<double, 3, 2>::Zero();
    Eigen::VectorXd drivers_ref;
    bool has_posterior = false;
    Eigen::Vector3d posterior_in = Eigen::Vector3d::Zero();
    absl::Time posterior_time = absl::InfinitePast();
  };
  static Projected Project(const Track& track);
  static int Key(int gyro_id, Source source) { return 2 * gyro_id + static_cast<int>(source); }
  // A window's verdict: beyond any drift, else a jump, else erratic (Judgement's steps).
  struct Judgement;
  Result Judge(int gyro_id, Source source, const Track& track) const;

  ReadingFaultOptions options_;
  std::vector<double> erratic_threshold_;  // by number of points (0 below 4)
  std::map<int, Track> tracks_;  // by Key
  absl::Time last_step_ = absl::InfinitePast();
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_READING_FAULT_MONITOR_H_
