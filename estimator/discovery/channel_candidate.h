// A drift that follows a housekeeping channel, as a candidate of every selection round (docs/
// discovery.md, "A drift that follows a housekeeping channel"): for gyro g and a channel the
// configuration declares, a case-fixed drift a (y(t) - r) in the three case axes, y the channel's
// held value, its first-order lag of time constant tau, or the lag's derivative (basis_term.h
// kChannel, channel_signal.h), r the channel's mean over the recording, plus a case-fixed drift b
// (three spin_axis_harmonic terms of degree 0, left out when the gyro's C1 is free: the drift at
// r, which r cannot tell from a constant drift). The three channel terms of a form are freed with
// the prior c_sigma_deg_h per 1-sigma of the channel over the recording (a drift of c_sigma where
// the channel departs by its own spread), b with c_sigma_deg_h, so that the filter calibrates a
// and b and each run's likelihood is their marginal likelihood. Runs: the value form once; the derivative
// form once (the derivative of a 10 min lag: a smoothed dx/dt); the lag form over kChannelLagCoarse
// time constants equally spaced in ln tau from 0.1 h to 10 h, refined twice half a spacing either
// side of the best, then the vertex of the parabola through the best and its neighbours (at most
// kChannelLagVertexRuns times); the lag's 95% interval is that parabola's. Evidence: the three forms equally likely a priori, the lag's tau uniform in
// ln tau (trapezoid rule on the time constants run). The form reported is the one of the largest
// evidence; its terms are the finding's model terms (Finding::basis_terms), which `esg model
// apply` adds to the gyro's basisTerms and the filter calibrates. Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_CHANNEL_CANDIDATE_H_
#define ESG_ESTIMATOR_DISCOVERY_CHANNEL_CANDIDATE_H_

#include <string>
#include <vector>

#include "absl/status/status.h"
#include "estimator/discovery/candidate.h"

namespace esg::estimator::discovery {

// The time behaviour of a drift that follows a channel (report.h TimeBehaviour::kind).
inline constexpr const char* kTimeFollowsChannel = "follows_channel";

inline constexpr double kChannelLagMinHours = 0.1;
inline constexpr double kChannelLagMaxHours = 10.0;
inline constexpr int kChannelLagCoarse = 5;
inline constexpr int kChannelLagRefine = 2;
inline constexpr int kChannelLagVertexRuns = 3;
inline constexpr double kChannelDerivativeSmoothingHours = 10.0 / 60.0;
// Filter runs of one candidate: value, derivative, the lag's coarse grid and refinement.
inline constexpr int kChannelCandidateRuns =
    2 + kChannelLagCoarse + 2 * kChannelLagRefine + kChannelLagVertexRuns;

// The channels a round tries for a gyro: those the configuration declares (a recording without
// channels, or a configuration without declarations, has none: the diagnosis is then as before).
std::vector<std::string> CandidateChannels(const SpacecraftConfig& config);

// Fits candidate (kChannelDrift, gyro, channel) on the context's model (above). A channel with no
// value in the recording, or constant over it, is no candidate: parameters 0 with a note.
// Errors: InvalidArgument for a gyro that is not configured; those of RunModel.
absl::Status FitChannelCandidate(const Candidate& candidate, const FitContext& ctx,
                                 CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_CHANNEL_CANDIDATE_H_
