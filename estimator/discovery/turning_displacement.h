// A rotor displacement that turns (docs/discovery.md, "A turning rotor displacement"), a
// candidate of every selection round per gyro, beside the library's effects.
//
// A rotor displaced along lambda gives C1 = (C10 + C20) lambda and C2 = -5 C20 lambda (eq. (8),
// (9) in the form of eq. (10); docs/physics.md). A displacement whose direction turns about an
// axis a at a steady rate, lambda(t) = R(a, 2 pi t / P) lambda_0, makes C1 and C2 turn with it:
// each is its part along a, constant (what the model's calibrated C1, C2 hold), plus
// u cos(phi) + (a x u) sin(phi), phi = 2 pi (t - t_0) / P. Only the part of the drift
// perpendicular to h moves the spin axis (dw = (h h^T - I)(C1 + C2 h^2), elementwise h^2), so
// the turning part is, per case axis m, the drift e_m (d_m + e_m' h_m^2) times cos(phi) and
// sin(phi): twelve cycling_harmonic terms of the basis (basis_term.h; degree 0 for C1, h_m^2 for
// C2), linear in their coefficients at a given period, whatever the axis a. So:
//
//   1. the period: the gyro's deviation from the current model (deviation.h), whitened by its
//      reduced filter (open_ended.h WhitenSeries), is regressed on the twelve signatures at each
//      period of a grid uniform in ln P from kTurnMinPeriodHours to kTurnMaxSpans times the
//      recording's span (a slower turn is a trend over the recording), refined at the
//      vertex of the parabola through the best period and its neighbours; the period's 95%
//      interval is where the regression's 2 ln B stays within 3.84 of its maximum;
//   2. the model with the twelve terms at the best period, freed with the prior c_sigma at each
//      regressor's RMS (the library's prior of C1, C2), refitted by the filter: its likelihood is
//      the terms' marginal likelihood;
//   3. its evidence 2 ln B = the refit's improvement less the period's Occam term: -2 ln of the
//      regression's Bayes factor averaged over the period's prior (uniform in ln P, trapezoid
//      rule) relative to its best (CandidateFit::occam), as the lag of a channel is integrated.
//
// Found, it is reported as a kEffectBasisTerm of time behaviour "turning": the axis a (from the
// cycling parts, u x v = |u|^2 a), the period with its interval, the amplitudes of C1's and C2's
// turning parts, and the twelve terms (Finding::basis_terms), which `esg model apply` adds to the
// gyro's basisTerms. Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_TURNING_DISPLACEMENT_H_
#define ESG_ESTIMATOR_DISCOVERY_TURNING_DISPLACEMENT_H_

#include "absl/status/status.h"
#include "estimator/discovery/candidate.h"

namespace esg::estimator::discovery {

// The time behaviour of a turning displacement (report.h TimeBehaviour::kind).
inline constexpr const char* kTimeTurning = "turning";

// The periods tried [h]: from 4 h (a turn of a few orbits; faster is the orbital harmonics') to
// the recording's span (a turn seen whole at least once; a slower one is, over the recording, a
// trend, a decay or a step, which the other time behaviours describe with fewer parameters),
// kTurnGridPerFactorTwo points per doubling.
inline constexpr double kTurnMinPeriodHours = 4.0;
inline constexpr double kTurnMaxSpans = 1.0;
inline constexpr int kTurnGridPerFactorTwo = 8;
// Vertex refinements of the period (regressions).
inline constexpr int kTurnVertexSteps = 3;
// Twelve terms: cos and sin, C1-like (degree 0) and C2-like (h_m^2), per case axis.
inline constexpr int kTurnTerms = 12;

// Fits candidate {Effect::kTurningDisplacement, gyro} into `fit` (whose model is the context's
// model with the candidate's name added). A recording shorter than two of the shortest periods,
// a gyro whose basis has no room for twelve terms, or a best period at an end of those searched
// (the recording cannot tell that turn from a trend or from the orbit's harmonics) gives no fit
// (parameters 0, a note).
// Errors: InvalidArgument for a gyro that is not configured; those of MeasureDeviations and
// RunModel.
absl::Status FitTurningDisplacement(const Candidate& candidate, const FitContext& ctx,
                                    CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_TURNING_DISPLACEMENT_H_
