// One physical term, one finding (docs/discovery.md, "One physical term, one finding"): a drift
// proportional to the body rate with one coefficient, dw_k = k w_k (case axes), is what the
// open-ended basis finds as three groups of one gyro, the body rate about case axis i along a
// direction the data choose (open_ended.h: rate[i] -> x, y, z). Their 3 x 3 gain matrix K (K_mi
// the drift along case axis m per unit of body rate about i, deg/h per deg/s) is then k I within
// its sigmas, and a physicist names one term, an isotropic coupling to the body rate, with the
// test of that equality. Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_RATE_COUPLING_H_
#define ESG_ESTIMATOR_DISCOVERY_RATE_COUPLING_H_

#include <vector>

#include "estimator/discovery/report.h"

namespace esg::estimator::discovery {

// The equality is accepted when its chi-square's p-value is above this (K = k I not rejected at
// 1%).
inline constexpr double kIsotropyP = 0.01;

// Where one gyro's findings (kEffectBasisTerm) hold the three body-rate groups, rate[1], rate[2]
// and rate[3], each along x, y and z: k the inverse-variance mean of K's diagonal, and chi2 =
// sum over the diagonal of ((K_ii - k) / sigma_ii)^2 plus sum off it of (K_mi / sigma_mi)^2 on 8
// degrees of freedom (the columns' sigmas taken as independent). With p above kIsotropyP the
// three findings become one, where the first of them was: "an isotropic coupling of the drift to
// the body rate", k with its sigma (parameters rateCouplingDegHPerDegS, isotropyChi2,
// isotropyP), the three groups' terms and parameters, their evidence summed; otherwise they are
// left as they are and the first gets a note with the test.
void MergeIsotropicRateCoupling(std::vector<Finding>& findings);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_RATE_COUPLING_H_
