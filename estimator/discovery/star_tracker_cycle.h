// The star tracker's side of a mismatch common to every gyro (docs/discovery.md, "The star
// tracker's side"): the star tracker's mount turning with the orbital phase, a thermo-elastic
// misalignment, candidate {Effect::kStarTrackerCycle, 0}.
//
// The star tracker reports q_st = q_in_b (x) Exp(m(t)) with
//
//     m(t) = c cos(phi) + s sin(phi),   phi = 2 pi (t - t_0) / P,
//
// c and s rotation vectors in body axes, P the orbital period (DiagnoseOptions::orbital_period_s,
// the orbit's, or the recording's orbital-orientation spans), t_0 the recording's first frame.
// It moves every gyro's measured inertial spin axis at once, h_in = C_in_b_st C_b_k h_k, by
// (C_in_b m(t)) x h_in: one rotation seen by all gyros, through each gyro's own mounting and spin
// axis, and not integrated in time as a drift is. So:
//
//   1. each running gyro's deviation from the current model (deviation.h) is whitened by its
//      reduced filter with its nuisance groups (open_ended.h WhitenSeries), and the six signatures
//      (C_in_b e_i cos(phi)) x h_in, (C_in_b e_i sin(phi)) x h_in, relative to the first sample,
//      beside it; the gyros' rows stack into one regression of the six coefficients shared by
//      all gyros (priors DiagnoseOptions::misalignment_sigma_arcsec each); its covariance
//      cluster-robust over half-hour blocks of samples, since the star tracker's own noise is
//      one rotation per sample common to every gyro's rows;
//   2. the star tracker corrected by the fitted m(t) (StarTrackerCorrection's cycle), the model
//      refitted by the filter; while the step was significant (its chi-square on the six
//      coefficients' covariance beyond the 0.99 quantile) the deviation of the refitted model is
//      regressed again, at most kCycleIterations times in all (the filter re-estimates its other
//      states with m held, so a first regression may leave part of it);
//   3. its evidence 2 ln B = the refit's improvement of -2 log L less Laplace's Occam term of the
//      six coefficients (open_ended.h LaplaceOccam), as for the basis's groups.
//
// Found, it is reported as the star tracker's (gyro 0) with the cos and sin amplitudes, the
// amplitude and axis of the largest turn and the period. A recording without a known orbital
// period gives no fit (parameters 0, a note). Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_STAR_TRACKER_CYCLE_H_
#define ESG_ESTIMATOR_DISCOVERY_STAR_TRACKER_CYCLE_H_

#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/time/time.h"
#include "estimator/discovery/candidate.h"
#include "estimator/discovery/deviation.h"

namespace esg::estimator::discovery {

// At most this many regressions and filter runs.
inline constexpr int kCycleIterations = 3;

// The six signatures of the cycle on a gyro's series, in the order c_x, c_y, c_z, s_x, s_y, s_z
// [rad per rad of rotation]: (C_in_b e_i f(t_k)) x h_in(t_k) less its value at the first sample,
// projected on the series' (u1, u2); f = cos(phi) or sin(phi), phi = 2 pi t / period_s, t since
// the recording's first frame (DeviationSeries::hours). C_b_k: the gyro's mounting as the
// deviation used it (sun_terms.h ModelMounting_b_k).
std::vector<std::vector<Eigen::Vector2d>> CycleSignatures(const DeviationSeries& series,
                                                          const Eigen::Matrix3d& C_b_k,
                                                          double period_s);

// Fits candidate {Effect::kStarTrackerCycle, 0} into `fit` (whose model is the context's model
// with the candidate's name added): parameters, occam, run, fitted values and notes.
// Errors: those of MeasureDeviations and RunModel.
absl::Status FitStarTrackerCycle(const Candidate& candidate, const FitContext& ctx,
                                 CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_STAR_TRACKER_CYCLE_H_
