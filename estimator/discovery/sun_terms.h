// A drift that follows the sun, as the open-ended stage finds and reports it (docs/discovery.md,
// "A drift that follows the sun"): the regressors (sun_regressors.h) for each gyro of a stage, a
// selected face's lag and its interval, the finding's words and parameters, and the drift held in
// the model as a correction of the gyro's readings (model_run.h ReadingShift: the filter has no
// state for the lag, so the term is held at its fitted value, as a readout distortion is, and
// scored by the refit's likelihood less its Occam term), and the names of the held groups. The
// sun as a candidate of every selection round: readout_candidate.h FitSunCandidate. Pure
// computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_SUN_TERMS_H_
#define ESG_ESTIMATOR_DISCOVERY_SUN_TERMS_H_

#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "estimator/discovery/candidate.h"
#include "estimator/discovery/deviation.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/open_ended.h"
#include "estimator/discovery/report.h"
#include "estimator/discovery/sun_regressors.h"
#include "estimator/spacecraft_config.h"

namespace esg::estimator::discovery {

// The time behaviour of a drift that follows the sun (report.h TimeBehaviour::kind).
inline constexpr const char* kTimeFollowsSun = "follows_sun";

// The sun's regressors of each series, the mounting that of `config` with the misalignment of
// `estimates` (as MeasureDeviations used it); with `orbit` (may be null) the illumination is zero
// in the Earth's shadow. A recording outside the ephemeris's years, or not covered by the orbit,
// has none: `note` then says why.
std::vector<SunRegressors> SunRegressorsOf(const std::vector<DeviationSeries>& series,
                                           const SpacecraftConfig& config,
                                           const std::vector<GyroEstimate>& estimates,
                                           std::string* note, const Orbit* orbit = nullptr);

// A selected sun group's lag [h]: the best of the grid, and the 95% interval where its 2 ln B
// stays within 3.84 (chi-square(1) 95%) of its maximum, linear in log(lag) between the grid's
// points, clipped to the grid.
struct LagInterval {
  double best = 0.0, lower = 0.0, upper = 0.0;
};
LagInterval SunLagInterval(const SelectedGroup& group);

// The drift at full illumination in case axes [rad/s] and its covariance [(rad/s)^2], averaged
// over the lags (SelectedGroup::lag_averaged_k); and the drift at the best lag, the one held in
// the model (the group's columns).
Eigen::Vector3d SunAmplitude_k(const SelectedGroup& group);
Eigen::Vector3d SunAmplitudeAtBestLag_k(const SelectedGroup& group);
Eigen::Matrix3d SunAmplitudeCovariance_k(const SelectedGroup& group);

// "drift along (x, y, z) (case axes) follows the sun on body face -y with a 1.4 h lag (95%
// interval a-b h), A +- s deg/h at full illumination ..." (without the gyro and the list of
// alternatives, open_ended.h DescribeAlternatives), naming what the recording cannot tell it
// from: an orbital harmonic, a constant. `shadowed`: the illumination was zero in the Earth's
// shadow (the orbit was given, sun_regressors.h), which the words say.
std::string DescribeSunGroup(const SelectedGroup& group, bool shadowed = false);

// The finding's parameters: sunDriftDegH[0..2] (case axes, deg/h at full illumination),
// sunDriftSizeDegH, sunLagHours (1-sigma: half its interval), sunLagLowerHours, sunLagUpperHours,
// sunFaceNormalB[0..2] (the face's outward normal, body axes).
std::vector<Parameter> SunParameters(const SelectedGroup& group);

// The selected sun group held in the model: the spin-axis motion its drift caused, in case axes
// at every frame of the recording (zero before the series' first sample, held after its last),
// for CorrectStarTracker. `attitude` from AttitudeAlongRecording on the same frames; C_b_k the
// gyro's mounting as the series used it.
ReadingShift SunReadingShift(const SelectedGroup& group, const DeviationSeries& series,
                             const SunRegressors& sun, const std::vector<TelemetryFrame>& frames,
                             const CarriedAttitude& attitude, const Eigen::Matrix3d& C_b_k);

// The gyro's mounting as MeasureDeviations uses it: Exp(misalignment) C_b_k of `config`.
Eigen::Matrix3d ModelMounting_b_k(const SpacecraftConfig& config,
                                  const std::vector<GyroEstimate>& estimates, int gyro);

// The name a model gives a held sun group of `gyro` (ModelState::added): "basis_term[2] sun -y
// lag 1.26 h", as the open-ended stage's and the round candidate's; and the faces of `gyro` a
// model holds, read back from those names.
std::string HeldSunGroupName(int gyro, const std::string& label);
std::vector<int> HeldSunFaces(const ModelState& model, int gyro);


}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_SUN_TERMS_H_
