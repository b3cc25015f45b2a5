// JSON form of a model-discrepancy diagnosis (estimator/discovery/diagnose.h, docs/discovery.md),
// shared by `esg diagnose --json` and the server's Diagnose RPC (stored in SQLite beside the
// coefficient histories): `verdict`, `findings` (most important first, each with `effect`, `gyro`
// where it applies, `parameters`, `explanation`, `evidence`), `mismatch` (where: gyro, time span,
// regime, size), `fit.before` and `fit.after` (each with `residualRmsArcsec` and
// `gapDriftRateDegH`), the regimes found and every candidate tried. Times are RFC 3339 UTC; units
// are in the key names (docs/discovery.md).
#ifndef ESG_PROTO_DIAGNOSIS_JSON_H_
#define ESG_PROTO_DIAGNOSIS_JSON_H_

#include <string>
#include <string_view>

#include "absl/status/statusor.h"

#include "estimator/discovery/diagnose.h"
#include "nlohmann/json.hpp"

namespace esg::proto_convert {

// The document as a JSON value (ordered keys). With `include_series`, also the residual and
// held-out time series of the plots (large: one entry per gyro and step).
nlohmann::ordered_json DiagnosisJsonValue(const estimator::discovery::DiagnosisReport& report,
                                          bool include_series = false);

// The document as text, indented by 2.
std::string DiagnosisToJson(const estimator::discovery::DiagnosisReport& report,
                            bool include_series = false);

// The verdict and the findings of a document written by DiagnosisToJson (each finding's effect,
// gyro, parameters, modelTerms and readoutDistortion; the rest is not read): what a stored
// diagnosis applies (estimator/discovery/apply_findings.h). InvalidArgument naming the field for a
// document that is not one.
absl::StatusOr<estimator::discovery::DiagnosisReport> DiagnosisFindingsFromJson(
    std::string_view json);

}  // namespace esg::proto_convert

#endif  // ESG_PROTO_DIAGNOSIS_JSON_H_
