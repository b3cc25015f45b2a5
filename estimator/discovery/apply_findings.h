// What a diagnosis's findings change in a configuration (docs/service.md "Applying a diagnosis"):
// the one mapping behind the configuration `esg diagnose --out` writes (model.json) and the
// service's ApplyDiagnosis. Findings that map:
//   rotor_displacement, fourth_harmonic, unequal_stiffness (gyro N): the coefficients the effect
//     names (estimator/model_terms.h `effect`) at their fitted values, freed with the prior the
//     diagnosis freed them with (DiagnoseOptions; a larger configured modelSigma is kept);
//   gyro_misalignment (gyro N): the gyro's misalignmentSigma set to the diagnosis's prior (the
//     filter estimates the misalignment; the mounting matrix is not changed);
//   star_tracker_latency: starTracker.latencyS set to the fitted latency (its sigma unchanged);
//   random_walk_drift common to all gyros: randomWalk set to the fitted intensity;
//   basis_term (gyro N): its basis terms and readout distortion (WithBasisFindings).
// Findings that do not: star_tracker_misalignment (the configuration holds no star-tracker
// mounting), random_walk_drift of one gyro (one intensity is configured for all), drift_step (a
// change in time, not a constant of the configuration), and unexplained mismatches. A verdict
// partly_explained applies the findings that map, its unexplained one among those that do not.
#ifndef ESG_ESTIMATOR_DISCOVERY_APPLY_FINDINGS_H_
#define ESG_ESTIMATOR_DISCOVERY_APPLY_FINDINGS_H_

#include <string>
#include <vector>

#include "estimator/discovery/options.h"
#include "estimator/discovery/report.h"
#include "estimator/spacecraft_config.h"

namespace esg::estimator::discovery {

struct AppliedFindings {
  SpacecraftConfig config;               // `config` with the findings that map
  std::vector<std::string> applied;      // one line per finding that maps: what it sets
  std::vector<std::string> not_applied;  // one line per finding that does not: why
};

// `config` with the report's findings that map to configuration (file comment), each freed with
// the prior `options` gives it. A finding whose gyro is not configured is not applied.
AppliedFindings WithFindings(const SpacecraftConfig& config, const DiagnosisReport& report,
                             const DiagnoseOptions& options = {});

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_APPLY_FINDINGS_H_
