// NoiseWidening: the bounded adaptive process noise of the operational filter (issue 9, item 2;
// docs/decisions.md D20). When the star-tracker innovations stay larger than the filter's own
// covariance says, the configured model is short of the truth (a drift term left out, a random
// walk stronger than configured); rejecting the data and re-anchoring the spin axes then only
// hides it, and excluding a healthy gyro on mismatches measured against an overconfident
// covariance is wrong. The filter instead widens its process noise, announced by an event,
// bounded, and off in diagnosis runs (whose likelihoods must be those of the model as
// configured). The widening is white noise on every spin-axis angle adding a variance v [rad^2]
// over each measurement step T: the spin-axis error an unmodelled drift of sqrt(v) / T builds in
// a step. It acts on the spin axes, not on the residual drift of eq. (11): a widened random walk
// lets the drift state chase whatever the model lacks at the current orientation and carry it,
// wrongly, across a later gap (measured: the model (1)+(11) gap rate grew from 0.04 to
// 0.13-0.70 deg/h that way); white noise lets the star tracker hold the spin axes while the
// calibrated coefficients keep their meaning.
//
// STATISTIC
//   One value per measurement step with star-tracker differences formed (eq. (13), before the
//   eq. (14) decision; steps whose star tracker eq. (12) named faulty do not enter): the step's
//   normalised innovation squared NIS with its d degrees of freedom, capped at chi2inv(1 - 1e-3, d)
//   so that one outlier cannot decide a window, and the mean innovation variance per degree of
//   freedom sbar (the diagonal of S). Windows of N consecutive such steps, disjoint, with the sum
//   X of the capped NIS and D = sum d. For a consistent filter X <= chi-square(D) (capping only
//   lowers it). At the end of a window:
//     widen   when X > chi2inv(1 - alpha, D) in this window and in the one before it (a misfit
//             confined to one window, such as the hour after a fast slew that 60 s readings
//             interpolate poorly, is left to the consistency monitor and the alerts):
//             v <- min(v + (X / D - 1) mean(sbar), v_max), the moment estimate of the variance
//             per component the filter's S lacks;
//     narrow  when X < chi2inv(alpha_narrow, D): v <- v / 2 (0 below (0.01 arcsec)^2): halved,
//             not the moment estimate, since the window after a transient misfit (a slew the
//             model misses) is calm and subtracting its deficit would undo the widening at once.
//   False widening: the two disjoint windows are independent, alpha^2 per window; with the
//   defaults (N = 30 steps of 60 s, alpha = 1e-3) 48 windows a day give 4.8e-5 false widenings
//   per day. Detection: with six degrees of freedom a step (three gyros, D = 180) the threshold
//   is 1.36 D, so innovations whose variance is 1.5x what the filter claims widen it after two
//   windows (1 h). Narrowing
//   (alpha_narrow = 1e-3: X < 0.72 D at D = 180) needs a covariance clearly larger than the
//   innovations, so a filter right at its current widening rarely narrows and re-widens.
#ifndef ESG_ESTIMATOR_NOISE_WIDENING_H_
#define ESG_ESTIMATOR_NOISE_WIDENING_H_

#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "absl/types/span.h"

namespace esg::estimator {

struct NoiseWideningOptions {
  int window_steps = 30;        // N, > 0
  // Steps after start that do not enter (the linearisation about the a-priori model is not yet
  // exact there, as for the consistency monitor), >= 0.
  int warmup_steps = 60;
  double alpha = 1e-3;          // level of the widening test per window, in (0, 1)
  double alpha_narrow = 1e-3;   // level of the narrowing test per window, in (0, 1)
  // Bound of the widening as an unmodelled drift [deg/h] (sqrt(v_max) / T).
  double max_drift_deg_h = 0.5;
};

class NoiseWidening {
 public:
  struct Decision {
    enum class Change { kNone, kWidened, kNarrowed };
    Change change = Change::kNone;
    double added_variance = 0.0;    // v after the decision [rad^2 per step]
    double nis_sum = 0.0;           // X: sum of the capped NIS over the window
    int dof = 0;                    // D
    double widen_threshold = 0.0;   // chi2inv(1 - alpha, D)
    double narrow_threshold = 0.0;  // chi2inv(alpha_narrow, D)
    int steps = 0;                  // N
  };

  // `measurement_step_s` is T [s], > 0.
  explicit NoiseWidening(double measurement_step_s = 60.0,
                         const NoiseWideningOptions& options = {});

  // Adds one step's NIS with dof in [1, 8] and the mean of the diagonal of its innovation
  // covariance S [rad^2] (the step is ignored otherwise, or when a value is not finite). Returns
  // the window's decision when this step completes a window.
  std::optional<Decision> Add(double nis, int dof, double mean_variance);

  // Variance added to every spin-axis angle per measurement step [rad^2]; 0 as configured.
  double added_variance() const { return added_variance_; }
  bool widened() const { return added_variance_ > 0.0; }
  bool at_max() const { return added_variance_ >= max_variance_; }
  // The widening as an unmodelled drift [deg/h]: sqrt(v) / T.
  double EquivalentDriftDegH() const;
  // The window that widened the filter from v = 0 (its test of the filter as configured), while
  // widened.
  const std::optional<Decision>& trigger() const { return trigger_; }
  const NoiseWideningOptions& options() const { return options_; }

  // State as doubles for the session checkpoint: v, steps seen (up to warmup_steps), whether the
  // previous window exceeded (0/1), the trigger (present 0/1, X, D, threshold, N), window length
  // w, then w x (capped NIS, d, mean variance).
  std::vector<double> ExportState() const;
  // DataLoss naming the field if the state does not fit these options (the object is then
  // unchanged).
  absl::Status RestoreState(absl::Span<const double> state);

 private:
  struct Step {
    double nis = 0.0;  // capped
    int dof = 0;
    double mean_variance = 0.0;
  };
  NoiseWideningOptions options_;
  double measurement_step_s_ = 60.0;
  double max_variance_ = 0.0;
  double added_variance_ = 0.0;
  std::vector<Step> window_;  // the current window
  int steps_seen_ = 0;        // steps offered to Add, up to warmup_steps
  bool previous_exceeded_ = false;  // the window before exceeded the widening threshold
  std::optional<Decision> trigger_;
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_NOISE_WIDENING_H_
