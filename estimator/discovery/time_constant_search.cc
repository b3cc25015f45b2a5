#include "estimator/discovery/time_constant_search.h"

#include <algorithm>
#include <cmath>
#include <optional>

#include "estimator/basis_term.h"
#include "estimator/statistics.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

namespace {

// The refinements: kTauRefine times the two points half a spacing either side of the best so far.
constexpr int kTauRefine = 2;
// While the drift is significant at the time constants searched (as the step's onset search
// goes on only then), the two time constants that bracket each end of the interval are bisected
// in ln tau down to kTauResolution apart, at most kTauIntervalRuns runs: linear interpolation
// between points further apart puts the end inside a convex profile, the interval too narrow.
constexpr double kTauResolution = 0.02;  // in ln tau: 2% of tau
constexpr int kTauIntervalRuns = 10;

}  // namespace

TauGrid WarmUpTauGrid() {
  TauGrid grid;
  grid.log_min = std::log(kWarmUpMinTauHours);
  grid.log_max = std::log(kWarmUpMaxTauHours);
  grid.spacing = (grid.log_max - grid.log_min) / (kTauCoarse - 1);
  return grid;
}

ModelState WithWarmUp(const ModelState& model, int gyro, absl::Time t0, double tau_h,
                      double sigma) {
  ModelState m = model;
  GyroConfig* g = FindGyroMutable(m.config, gyro);
  for (int axis = 1; axis <= kWarmUpTerms; ++axis) {
    BasisTerm t;
    t.kind = BasisKind::kExponentialDecay;
    t.axis = axis;
    t.time_constant = tau_h * kSecondsPerHour;
    t.epoch = t0;
    t.value = 0.0;
    t.sigma = sigma;
    g->basis_terms.push_back(t);
  }
  return m;
}

absl::Status SearchTimeConstants(const TauGrid& grid,
                                 const std::function<absl::Status(double log_tau)>& evaluate,
                                 const std::map<double, double>& value,
                                 const std::function<double()>& best_log, double base_value,
                                 double alpha) {
  const double log_min = grid.log_min, log_max = grid.log_max, spacing = grid.spacing;
  auto evaluate_new = [&](double log_tau) -> absl::Status {
    log_tau = std::clamp(log_tau, log_min, log_max);
    for (const auto& [x, v] : value) {
      if (std::abs(x - log_tau) < 1e-9) return absl::OkStatus();
    }
    return evaluate(log_tau);
  };
  for (int k = 0; k < kTauCoarse; ++k) RETURN_IF_ERROR(evaluate_new(log_min + k * spacing));
  for (int r = 1; r <= kTauRefine; ++r) {
    const double half = spacing / std::pow(2.0, r);
    const double centre = best_log();
    if (centre - half >= log_min - 1e-12) RETURN_IF_ERROR(evaluate_new(centre - half));
    if (centre + half <= log_max + 1e-12) RETURN_IF_ERROR(evaluate_new(centre + half));
  }
  // The interval's ends resolved (kTauResolution) while the drift is significant: the chord
  // between coarse points lies above the convex profile.
  if (base_value - value.at(best_log()) > EvidenceThreshold(alpha, 1)) {
    for (int extra = 0; extra < kTauIntervalRuns; ++extra) {
      const std::optional<double> middle = WidestEndBracketMiddle(
          ProfilePoints(value.begin(), value.end()), kProfileIntervalDrop, kTauResolution);
      if (!middle.has_value()) break;
      RETURN_IF_ERROR(evaluate_new(*middle));
    }
  }
  return absl::OkStatus();
}

double AddDecayParameters(const std::string& name, const Eigen::Vector3d& a,
                          const Eigen::Vector3d& a_sigma, double tau_h, double lower_h,
                          double upper_h, double& size_sigma, CandidateFit& fit) {
  const double deg_h = RadPerSecToDegPerHour(1.0);
  AddVectorParameters(name + "DegH", a, a_sigma, deg_h, "deg/h", fit.fitted);
  const double size = a.norm();
  size_sigma =
      size > 0 ? std::sqrt((a.cwiseProduct(a_sigma)).squaredNorm()) / size : a_sigma.norm();
  fit.fitted.push_back({name + "SizeDegH", RadPerSecToDegPerHour(size),
                        RadPerSecToDegPerHour(size_sigma), "deg/h"});
  fit.fitted.push_back({"tauHours", tau_h, 0.5 * (upper_h - lower_h), "h"});
  fit.fitted.push_back({"tauLowerHours", lower_h, 0.0, "h"});
  fit.fitted.push_back({"tauUpperHours", upper_h, 0.0, "h"});
  return size;
}

}  // namespace esg::estimator::discovery
