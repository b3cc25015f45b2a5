// Which drift model the filter calibrates (models 1, 10, 11 of the paper) and which of its
// coefficients are free. Model strings: "1" (eq. (1): k0, mu, nu), "10" (eq. (10): k0, C1, C2;
// plus mu, nu of the full model when configured), "11" (random walk of the residual drift in
// `int` axes only, eq. (11)), and "+"-joined sets such as "10+11" or "1+11". Which fixed terms
// "1" and "10" take is the term table's (model_terms.h model_parts).
//
// A coefficient of a term in the model is free (estimated) when its configured modelSigma is
// positive, otherwise held at the configured value. Terms outside the model are zero, except
// with model "11" alone, where the configured (bench) model is applied as it is and nothing is
// estimated but the random walk. The configured basis terms (GyroConfig::basis_terms, drift terms
// beyond eq. (1)/(10)) are outside the model string: each adds its drift under every model, and
// one with sigma > 0 is estimated.
#ifndef ESG_ESTIMATOR_CALIBRATION_MODEL_H_
#define ESG_ESTIMATOR_CALIBRATION_MODEL_H_

#include <array>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "estimator/drift_model.h"
#include "estimator/model_terms.h"
#include "estimator/spacecraft_config.h"

namespace esg::estimator {

struct ModelSpec {
  // The model-string parts that take fixed terms (model_terms.h kModelPart*: "1" eq. (1), "10"
  // eq. (10)); which terms each part takes is the descriptors' model_parts.
  unsigned parts = 0;
  bool random_walk = false;  // eq. (11)

  // Some fixed term is in the model (false for model "11" alone).
  bool HasFixedTerms() const { return parts != 0; }
  // Canonical name, e.g. "10+11".
  std::string Name() const;
  // Mask over theta (drift_model.h offsets): true where the term is in the model.
  std::array<bool, kNumDriftCoefficients> TermMask() const;
};

// InvalidArgument naming the bad part, e.g. "model: unknown term '12' (use 1, 10, 11 or a '+' set)".
absl::StatusOr<ModelSpec> ParseModel(absl::string_view name);

// The model's coefficient vector for a gyro: configured values on the model's terms, zero
// elsewhere (all configured values for model "11" alone) [rad/s].
DriftVector ModelCoefficients(const ModelSpec& spec, const GyroConfig& gyro);

// Indices into theta of the free coefficients of a gyro (term in the model and sigma > 0).
std::vector<int> FreeCoefficients(const ModelSpec& spec, const GyroConfig& gyro);

// Indices into gyro.basis_terms of its free basis terms (sigma > 0). Basis terms are outside the
// model string: held terms always add their drift, free ones are always estimated.
std::vector<int> FreeBasisTerms(const GyroConfig& gyro);

// Names of theta entries as in the JSON ("k0DegH", "c1DegH[0]", ...), for reports.
const char* CoefficientName(int theta_index);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_CALIBRATION_MODEL_H_
