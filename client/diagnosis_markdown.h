// The Markdown report of `esg diagnose --out DIR` (docs/discovery.md, "The report"): the verdict,
// the findings with their parameters and evidence, where the configured model and the recording
// disagree, the fit before and after, the held-out spans, every candidate tried and the regimes,
// with each plot of diagnosis_plots.h referenced beside what it shows and one sentence saying what
// to look at.
#ifndef ESG_CLIENT_DIAGNOSIS_MARKDOWN_H_
#define ESG_CLIENT_DIAGNOSIS_MARKDOWN_H_

#include <string>
#include <vector>

#include "client/diagnosis_plots.h"
#include "estimator/discovery/report.h"

namespace esg::client {

// The report's text. `plots`: those WriteDiagnosisPlots wrote; `plotted` false when gnuplot
// failed or is missing (the report then says so and where its messages are).
std::string DiagnosisMarkdown(const estimator::discovery::DiagnosisReport& report,
                              const std::vector<DiagnosisPlot>& plots, bool plotted);

}  // namespace esg::client

#endif  // ESG_CLIENT_DIAGNOSIS_MARKDOWN_H_
