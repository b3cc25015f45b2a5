// A candidate effect and its fit: the helpers the fits share (candidate.h).
#include "estimator/discovery/candidate.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <utility>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/statistics.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

void AddVectorParameters(const std::string& name, const Eigen::Vector3d& value,
                         const Eigen::Vector3d& sigma,
                         double scale, const std::string& unit, std::vector<Parameter>& out) {
  for (int i = 0; i < 3; ++i) {
    out.push_back(
        Parameter{absl::StrFormat("%s[%d]", name, i), value(i) * scale, sigma(i) * scale, unit});
  }
}

std::pair<int, int> FixedTermsOf(Effect effect) {
  const absl::string_view id = EffectId(effect);
  int first = -1, count = 0;
  for (const FixedTermDescriptor& term : kFixedTerms) {
    if (term.effect != id) continue;
    if (first < 0) first = term.theta_index;
    ++count;
  }
  return {std::max(first, 0), count};
}

GyroConfig* FindGyroMutable(SpacecraftConfig& c, int id) {
  for (GyroConfig& g : c.gyros) {
    if (g.id == id) return &g;
  }
  return nullptr;
}

absl::StatusOr<GyroConfig*> CandidateGyro(SpacecraftConfig& c, int gyro) {
  GyroConfig* g = FindGyroMutable(c, gyro);
  if (g == nullptr) {
    return absl::InvalidArgumentError(absl::StrCat("candidate gyro ", gyro, " is not configured"));
  }
  return g;
}

void ReleaseHeldCoefficients(SpacecraftConfig& config, int gyro, int first, int count,
                             double sigma) {
  GyroConfig* g = FindGyroMutable(config, gyro);
  DriftVector s = g->model_sigma.AsVector();
  for (int i = first; i < first + count; ++i) {
    if (!(s(i) > 0.0)) s(i) = sigma;
  }
  g->model_sigma = DriftCoefficients::FromVector(s);
}

const GyroEstimate* FindEstimate(const std::vector<GyroEstimate>& gyros, int id) {
  for (const GyroEstimate& g : gyros) {
    if (g.id == id) return &g;
  }
  return nullptr;
}

std::string CandidateName(const Candidate& c) {
  if (c.effect == Effect::kChannelDrift) {
    return absl::StrCat(EffectId(c.effect), "[", c.gyro, ":", c.channel, "]");
  }
  if (c.gyro > 0) return absl::StrCat(EffectId(c.effect), "[", c.gyro, "]");
  return EffectId(c.effect);
}

double ModelRandomWalk(const ModelState& m, int id) {
  return m.options.model.random_walk ? ResidualRandomWalk(m.config, m.options, id) : 0.0;
}

double ModelInitialDriftSigma(const ModelState& m) {
  return m.options.model.random_walk ? InitialResidualDriftSigma(m.options) : 0.0;
}

ProfiledDeviance Profile(const ModelRun& run) {
  const Deviance d = ComputeDeviance(run);
  ProfiledDeviance p;
  p.components = d.components;
  p.steps = d.steps;
  if (d.components == 0) return p;
  p.dispersion = std::max(d.nis_sum / d.components, 1e-12);
  const double log_det = d.value - d.nis_sum;
  // -2 log L with S -> phi S, minimised over phi: N ln phi + sum log det S + N.
  p.value = d.components * std::log(p.dispersion) + log_det + d.components;
  return p;
}

std::optional<FreedCoefficients> FreedDriftCoefficients(Effect effect,
                                                        const DiagnoseOptions& options) {
  double sigma_deg_h = 0.0;
  switch (effect) {
    case Effect::kRotorDisplacement:
      sigma_deg_h = options.c_sigma_deg_h;
      break;
    case Effect::kFourthHarmonic:
      sigma_deg_h = options.k0_sigma_deg_h;
      break;
    case Effect::kUnequalStiffness:
      sigma_deg_h = options.unequal_stiffness_sigma_deg_h;
      break;
    default:
      return std::nullopt;
  }
  const auto [first, count] = FixedTermsOf(effect);
  if (count == 0) return std::nullopt;
  return FreedCoefficients{first, count, DegPerHourToRadPerSec(sigma_deg_h)};
}

}  // namespace esg::estimator::discovery
