// The sun's illumination of the body faces as regressors of the open-ended stage (docs/discovery.md,
// "A drift that follows the sun"): a gyro heated through a panel the sun shines on drifts with
// that panel's temperature, which follows the illumination through a thermal lag.
//
// Face f of the body (outward normal n_f = +-e_i, body axes) is lit by
//
//     u_f(t) = max(0, n_f . s_b(t)),   s_b = C_b_in(t) s_in(t)
//
// s_in the unit vector to the sun in inertial (J2000) axes (sun_direction.h, ERFA) and C_b_in the
// attitude the deviation uses (deviation.h AttitudeAlongRecording: the star tracker the model's
// filter applied, carried by the gyros' measured rotation through outages; within arcseconds of
// the filter's estimate, far below what changes an illumination). The face's temperature, and with
// it the drift, follows u_f through a first-order lag of time constant tau,
//
//     tau dy/dt = u_f - y,   y(t_0) = u_f(t_0) (the face in equilibrium at the start),
//
// stepped exactly for u_f constant over a substep: y <- u + (y - u) exp(-dt / tau). With the
// spacecraft's orbit (orbit.h) u_f is multiplied by the fraction nu of the sun's disc the
// spacecraft sees (eclipse.h: 0 in the Earth's umbra), averaged over each substep by Simpson's
// rule; without it nu = 1. The drift is
// a y(t), a a vector in case axes (deg/h at full illumination). tau is not known: it is profiled
// over a grid of 41 values log-spaced from 0.1 h to 10 h (20 per decade, neighbours 12% apart),
// as the onset of a drift step is. Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_SUN_REGRESSORS_H_
#define ESG_ESTIMATOR_DISCOVERY_SUN_REGRESSORS_H_

#include <array>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "estimator/discovery/deviation.h"
#include "estimator/orbit.h"

namespace esg::estimator::discovery {

// Faces 0..5: +x, -x, +y, -y, +z, -z (body axes).
inline constexpr int kSunFaces = 6;
// With the orbit, one family more: the sunlit fraction nu itself (1 in sunlight, 0 in the Earth's
// umbra), whatever the attitude: a drift that changes with the eclipses (heaters switching, the
// whole spacecraft cooling in the shadow) rather than with one face's illumination. Its index
// follows the faces'; it has no normal.
inline constexpr int kSunlitFamily = kSunFaces;
// The families a gyro's sun regressors have: the six faces, and `sunlit` with the orbit.
inline constexpr int SunFamilies(bool with_orbit) { return kSunFaces + (with_orbit ? 1 : 0); }
std::string SunFaceName(int face);            // "+x", ..., "-z"; "sunlit" for kSunlitFamily
Eigen::Vector3d SunFaceNormal_b(int face);    // the outward normal, body axes [1]; 0 for sunlit
double FaceIllumination(const Eigen::Vector3d& s_b, int face);  // max(0, n_f . s_b) [1]

// The lag grid [h]: 0.1 h to 10 h, 41 values log-spaced.
std::vector<double> SunLagGridHours();

// The lagged illumination y at each of `u`'s substeps (midpoints), u constant over each substep of
// length dt[i] [s]; tau [s] > 0; y starts at u[0].
std::vector<double> LaggedIllumination(const std::vector<double>& u, const std::vector<double>& dt,
                                       double tau_s);

// One gyro's sun regressors: values[face][lag][step], the lagged illumination of each face at each
// substep of the gyro's deviation series (TrajectoryStep, its midpoint) for each lag of lag_hours;
// with the orbit also values[kSunlitFamily], the lagged sunlit fraction.
struct SunRegressors {
  int gyro = 0;
  std::vector<double> lag_hours;
  std::vector<std::vector<std::vector<double>>> values;
};

// The sun's direction in inertial axes at the series' substeps: computed every 600 s over the
// series and interpolated linearly between (normalised; the sun moves 0.007 deg in 600 s).
// InvalidArgument when the recording lies outside the ephemeris's years (sun_direction.h).
absl::StatusOr<std::vector<Eigen::Vector3d>> SunAlongSeries_in(const DeviationSeries& series);

// The fraction nu of the sun's disc seen from the orbit at the series' substeps, each averaged
// over its substep by Simpson's rule (start, midpoint, end). The sun's position is computed every
// 600 s and interpolated linearly (it moves 0.007 deg and 0.1% of its distance's yearly change in
// that time). Errors: OutOfRange from the orbit where it does not cover a substep;
// SunPosition_in_km's.
absl::StatusOr<std::vector<double>> SunlitAlongSeries(const DeviationSeries& series,
                                                      const Orbit& orbit);

// The regressors of `series` (whose mounting is C_b_k, with the model's misalignment, as
// MeasureDeviations used it), for the lags of SunLagGridHours; with `orbit` (may be null) the
// illumination is zero in the Earth's shadow. Errors: SunAlongSeries_in's, SunlitAlongSeries'.
absl::StatusOr<SunRegressors> ComputeSunRegressors(const DeviationSeries& series,
                                                   const Eigen::Matrix3d& C_b_k,
                                                   const Orbit* orbit = nullptr);

// The regressors of `gyro` in `sun`, nullptr when it has none.
const SunRegressors* FindSunRegressors(const std::vector<SunRegressors>& sun, int gyro);

// The label of a face's group at one lag: "sun -y lag 1.26 h" ("sun sunlit lag 1.26 h" for the
// sunlit fraction).
std::string SunGroupLabel(int face, double lag_hours);

// The signature (deviation.h Signature) of the drift s[i] e_m, s given at every substep of the
// series [rad per unit of the drift], and the time-weighted RMS of s over the substeps.
std::vector<Eigen::Vector2d> TabulatedSignature(const DeviationSeries& series,
                                                const std::vector<double>& s,
                                                const Eigen::Vector3d& e_m);
double TabulatedRms(const DeviationSeries& series, const std::vector<double>& s);
// TabulatedSignature along each case axis x, y, z (index 0, 1, 2), the same bits, in one pass
// over the substeps: what a regressor's three columns need.
std::array<std::vector<Eigen::Vector2d>, 3> TabulatedSignatures(const DeviationSeries& series,
                                                                const std::vector<double>& s);

// The motion of the spin axis the drift s[i] a_k caused, integral (C_in_k a_k s) x h_in dt from the
// series' first sample, in inertial axes at every substep's end [rad].
std::vector<Eigen::Vector3d> TabulatedMotion_in(const DeviationSeries& series,
                                                const std::vector<double>& s,
                                                const Eigen::Vector3d& a_k);

// 2 ln of the mean of exp(e / 2) over `evidence` (2 ln B at each point of a grid, the points
// equally likely a priori): the Bayes factor averaged over the grid. -infinity when empty.
double AverageEvidence(const std::vector<double>& evidence);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_SUN_REGRESSORS_H_
