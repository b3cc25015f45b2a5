// The human-readable text `esg diagnose` prints without --format json/csv (docs/discovery.md):
// the verdict, each finding with its physics and supporting notes, where the configured model and
// the recording disagree, and the fit before and after.
#ifndef ESG_CLIENT_DIAGNOSIS_TEXT_H_
#define ESG_CLIENT_DIAGNOSIS_TEXT_H_

#include <string>

#include "estimator/discovery/report.h"

namespace esg::client {

// The text, one line per item, each ending in a newline; UTC times in RFC 3339.
std::string DiagnosisText(const estimator::discovery::DiagnosisReport& report);

}  // namespace esg::client

#endif  // ESG_CLIENT_DIAGNOSIS_TEXT_H_
