#include "estimator/spacecraft_config.h"

#include <cmath>
#include <set>

#include "Eigen/LU"
#include "absl/strings/str_format.h"
#include "estimator/conventions.h"

namespace esg::estimator {

const GyroConfig* SpacecraftConfig::FindGyro(int id) const {
  for (const GyroConfig& g : gyros) {
    if (g.id == id) return &g;
  }
  return nullptr;
}

namespace {

bool AllFinite(const DriftCoefficients& c) { return c.AsVector().allFinite(); }

absl::Status CheckPair(const SpacecraftConfig& config, const std::array<int, 2>& pair,
                       const char* field) {
  for (int id : pair) {
    if (config.FindGyro(id) == nullptr) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s: gyro %d is not among the configured gyros", field, id));
    }
  }
  if (pair[0] == pair[1]) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: a pair needs two different gyros, got [%d, %d]", field, pair[0],
                        pair[1]));
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status ValidateConfig(const SpacecraftConfig& config) {
  if (config.spacecraft_id.empty()) {
    return absl::InvalidArgumentError("spacecraftId: must not be empty");
  }
  if (config.gyros.size() < 2 || config.gyros.size() > static_cast<size_t>(kMaxGyros)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "gyros: between 2 and %d gyros are needed, got %d", kMaxGyros, config.gyros.size()));
  }
  std::set<int> ids;
  for (size_t i = 0; i < config.gyros.size(); ++i) {
    const GyroConfig& g = config.gyros[i];
    if (g.id < 1 || g.id > kMaxGyros) {
      return absl::InvalidArgumentError(
          absl::StrFormat("gyros[%d].id: %d is outside 1..%d", i, g.id, kMaxGyros));
    }
    if (!ids.insert(g.id).second) {
      return absl::InvalidArgumentError(
          absl::StrFormat("gyros[%d].id: gyro %d is configured twice", i, g.id));
    }
    const Eigen::Matrix3d should_be_identity = g.C_b_k.transpose() * g.C_b_k;
    if (!g.C_b_k.allFinite() || !should_be_identity.isIdentity(1e-6) ||
        g.C_b_k.determinant() < 0.0) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "gyros[%d].caseToBody: not a proper rotation matrix (orthonormal to 1e-6, det +1)", i));
    }
    if (!AllFinite(g.model)) {
      return absl::InvalidArgumentError(absl::StrFormat("gyros[%d].model: non-finite value", i));
    }
    if (!AllFinite(g.model_sigma) || (g.model_sigma.AsVector().array() < 0.0).any()) {
      return absl::InvalidArgumentError(
          absl::StrFormat("gyros[%d].modelSigma: values must be finite and >= 0", i));
    }
    if (!std::isfinite(g.misalignment_sigma) || g.misalignment_sigma < 0.0) {
      return absl::InvalidArgumentError(
          absl::StrFormat("gyros[%d].misalignmentSigmaArcsec: must be finite and >= 0", i));
    }
  }
  if (auto s = CheckPair(config, config.working_pair, "workingPair"); !s.ok()) return s;
  if (auto s = CheckPair(config, config.reserve_pair, "reservePair"); !s.ok()) return s;
  if (!config.star_tracker.noise.allFinite() || (config.star_tracker.noise.array() < 0.0).any()) {
    return absl::InvalidArgumentError("starTracker.noiseArcsec: values must be finite and >= 0");
  }
  if (!std::isfinite(config.readout_noise) || config.readout_noise < 0.0) {
    return absl::InvalidArgumentError("readoutNoiseArcsec: must be finite and >= 0");
  }
  if (!std::isfinite(config.random_walk) || config.random_walk < 0.0) {
    return absl::InvalidArgumentError("randomWalkDegHSqrtH: must be finite and >= 0");
  }
  const SuspensionConfig& s = config.suspension;
  if (!(s.amplifier_gain > 0.0) || !(s.reference_voltage > 0.0) || !(s.gap > 0.0) ||
      !std::isfinite(s.amplifier_gain + s.reference_voltage + s.gap)) {
    return absl::InvalidArgumentError(
        "suspension: amplifierGain, referenceVoltageV and gapUm must be finite and > 0");
  }
  const FilterConfig& f = config.filter;
  if (!(f.integration_rate_hz > 0.0) || !std::isfinite(f.integration_rate_hz)) {
    return absl::InvalidArgumentError("filter.integrationRateHz: must be finite and > 0");
  }
  if (!(f.measurement_step > 0.0) || !std::isfinite(f.measurement_step)) {
    return absl::InvalidArgumentError("filter.measurementStepS: must be finite and > 0");
  }
  if (!(f.innovation_kd > 0.0) || !std::isfinite(f.innovation_kd)) {
    return absl::InvalidArgumentError("filter.innovationKd: must be finite and > 0");
  }
  if (!std::isfinite(f.fault_threshold) || f.fault_threshold < 0.0) {
    return absl::InvalidArgumentError("filter.faultThresholdArcsec: must be finite and >= 0");
  }
  return absl::OkStatus();
}

}  // namespace esg::estimator
