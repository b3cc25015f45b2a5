// What the stages of one diagnosis share (docs/discovery.md, "Method"): the recording with what is
// measured on it (body rates, regimes, held-out spans), the options, progress, the latched
// cancellation, the caller's runner for independent model runs, and the count of filter runs.
// Starts no thread: concurrent work goes through DiagnoseOptions::run_parallel.
#ifndef ESG_ESTIMATOR_DISCOVERY_CONTEXT_H_
#define ESG_ESTIMATOR_DISCOVERY_CONTEXT_H_

#include <atomic>
#include <functional>
#include <mutex>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "estimator/discovery/candidate.h"
#include "estimator/discovery/held_out.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/options.h"
#include "estimator/discovery/regimes.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"

namespace esg::estimator::discovery {

class DiagnosisContext {
 public:
  // Keeps references to all three; they must outlive the context.
  DiagnosisContext(const std::vector<TelemetryFrame>& frames, const DiagnoseOptions& options,
                   const DiagnoseProgressFn& progress);

  const std::vector<TelemetryFrame>& frames() const { return frames_; }
  const DiagnoseOptions& options() const { return options_; }

  // Measures the body rates and the regimes, and chooses the held-out spans (ChooseGaps).
  void MeasureRecording(const SpacecraftConfig& config);
  const BodyRates& rates() const { return rates_; }
  const std::vector<RegimeSpan>& regimes() const { return regimes_; }
  const std::vector<Gap>& gaps() const { return gaps_; }

  // Reports progress, fraction clamped to [0, 1] and never below a fraction said before (parallel
  // fits finish in any order). Thread-safe.
  void Say(double fraction, const std::string& stage);

  // Cancellation, latched: polls options.cancelled; once it returned true every later call
  // agrees, so a task skipped for it is never mistaken for a finished one. Thread-safe.
  bool Stop();
  // The latch alone, without polling.
  bool Stopped() const { return stopped_.load(); }
  // The status of a cancelled diagnosis: Cancelled "diagnosis cancelled".
  static absl::Status Cancelled();

  // Runs job(0) ... job(count - 1) through options.run_parallel on at most options.threads
  // tasks, or one after another on this thread; returns when all are done.
  void ForEach(int count, const std::function<void(int)>& job) const;

  // One run of `model` over the recording with its star-tracker correction, the star tracker
  // withheld over the held-out spans when `held_out`. Neither polls cancellation nor counts: for
  // jobs of ForEach, whose caller counts.
  absl::StatusOr<ModelRun> Run(const ModelState& model, bool held_out) const;
  // The same run after a cancellation check, counted.
  absl::StatusOr<ModelRun> CheckedRun(const ModelState& model, bool held_out);

  void CountRuns(int runs) { filter_runs_ += runs; }
  int filter_runs() const { return filter_runs_; }

 private:
  const std::vector<TelemetryFrame>& frames_;
  const DiagnoseOptions& options_;
  const DiagnoseProgressFn& progress_;
  BodyRates rates_;
  std::vector<RegimeSpan> regimes_;
  std::vector<Gap> gaps_;
  ModelRunOptions held_out_options_;
  std::mutex progress_mu_;
  double said_ = 0.0;  // the largest fraction said, under progress_mu_
  std::atomic<bool> stopped_{false};
  int filter_runs_ = 0;
};

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_CONTEXT_H_
