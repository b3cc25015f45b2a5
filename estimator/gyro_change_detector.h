// GyroChangeDetector: the per-gyro accumulated star-tracker test that names a gyro whose drift
// changed (a drift step) before the filter absorbs it (docs/decisions.md D33).
//
// A drift step of a few hundredths of a deg/h in one gyro moves that gyro's own star-tracker
// difference of eq. (13) a little further at every measurement step. Each step alone stays below
// the per-step thresholds (eq. (14), the per-gyro test of D22) for tens of minutes, long enough
// for the process-noise widening (noise_widening.h) to absorb it as a model the data do not fit.
// Summed over steps the evidence is clear: with the filter consistent and the gyro healthy, its
// own star-tracker NIS (normalised by its exact covariance) is chi-square with 2 degrees of
// freedom per step, and the sum over the last W steps (every step with three running gyros and
// the star tracker present) is chi-square(2W). Each step's value enters capped at the 1 - 1e-3
// quantile of chi-square(2), so that a single outlier cannot fill a window by itself.
//
// A gyro is named when its window sum exceeds the 1 - alpha_fail quantile of chi-square(2W)
// while the other two gyros' sums stay below the 1 - alpha_pass quantile: a model that does not
// fit the data, or a star-tracker error, moves all three differences (a star-tracker rotation
// turns every rebuilt axis at once), not one. Not quite: the star tracker's noise is anisotropic
// (30 arcsec about its boresight, 5 across), so a star-tracker error can fail one gyro's
// normalised difference while the others pass; a window with a step where the star tracker was
// suspected (eq. (12) or the three-pair isolation named it, or named it a candidate) decides
// nothing; nor does a window with a step whose NIS is negative or NaN (a covariance that is not
// positive definite gives no chi-square value). The three gyros must be the same over the window;
// another set (an exclusion, a spare switched on) starts the windows again, as Clear() does. The
// session acts on a decision only once its consistency monitor has tested the model and while
// nothing says the model does not fit (D21): a drift term the model lacks can be larger in one
// gyro than in the others.
#ifndef ESG_ESTIMATOR_GYRO_CHANGE_DETECTOR_H_
#define ESG_ESTIMATOR_GYRO_CHANGE_DETECTOR_H_

#include <array>
#include <deque>
#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "absl/types/span.h"

namespace esg::estimator {

struct GyroChangeDetectorOptions {
  int window_steps = 10;      // W [measurement steps]
  double alpha_fail = 1e-7;   // per test and gyro: 3 tests a step, 4320 a day at 60 s
  double alpha_pass = 0.01;   // the other two gyros must pass at this level
};

class GyroChangeDetector {
 public:
  explicit GyroChangeDetector(GyroChangeDetectorOptions options = {});

  struct Decision {
    int gyro_id = 0;                          // the gyro named
    std::array<int, 3> gyro_ids = {0, 0, 0};  // the three gyros tested
    std::array<double, 3> sums = {0, 0, 0};   // their window sums (capped NIS)
    double fail_threshold = 0.0;              // chi2inv(1 - alpha_fail, 2W)
    double pass_threshold = 0.0;              // chi2inv(1 - alpha_pass, 2W)
    int steps = 0;                            // W
  };

  // Adds one measurement step: the own star-tracker NIS (2 dof each) of the running gyros
  // `gyro_ids`, and whether the star tracker was suspected at this step. Returns a decision when
  // the window is full, no step of it suspected the star tracker or had a NIS that is negative
  // or NaN, and exactly one gyro fails while the others pass (rule above).
  std::optional<Decision> Add(const std::array<int, 3>& gyro_ids, const std::array<double, 3>& nis,
                              bool star_tracker_suspected);
  // Starts the windows again (after an exclusion or a filter reset).
  void Clear();

  const GyroChangeDetectorOptions& options() const { return options_; }
  // The windows' state, for the session checkpoint: gyro ids (3), the step count, then per step
  // the three capped values (in [0, cap]) and the undecided flag (0 or 1: star tracker suspected,
  // or a NIS that was negative or NaN).
  std::vector<double> ExportState() const;
  // DataLoss naming the field if the state does not fit these options (the object is then
  // unchanged).
  absl::Status RestoreState(absl::Span<const double> state);

 private:
  GyroChangeDetectorOptions options_;
  double cap_ = 0.0;
  double fail_threshold_ = 0.0;
  double pass_threshold_ = 0.0;
  std::array<int, 3> gyro_ids_ = {0, 0, 0};
  std::deque<std::array<double, 4>> steps_;  // three capped NIS, step undecided (0/1)
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_GYRO_CHANGE_DETECTOR_H_
