#include "estimator/discovery/context.h"

#include <algorithm>

namespace esg::estimator::discovery {

DiagnosisContext::DiagnosisContext(const std::vector<TelemetryFrame>& frames,
                                   const DiagnoseOptions& options,
                                   const DiagnoseProgressFn& progress)
    : frames_(frames), options_(options), progress_(progress) {}

void DiagnosisContext::MeasureRecording(const SpacecraftConfig& config) {
  rates_ = MeasureBodyRates(config, frames_);
  regimes_ = FindRegimes(frames_, rates_, options_.regimes);
  gaps_ = ChooseGaps(regimes_, frames_, options_);
  held_out_options_ = WithheldOver(gaps_);
}

void DiagnosisContext::Say(double fraction, const std::string& stage) {
  if (!progress_) return;
  std::lock_guard<std::mutex> lock(progress_mu_);
  said_ = std::max(said_, std::clamp(fraction, 0.0, 1.0));
  progress_(said_, stage);
}

bool DiagnosisContext::Stop() {
  if (stopped_.load()) return true;
  if (options_.cancelled && options_.cancelled()) stopped_.store(true);
  return stopped_.load();
}

absl::Status DiagnosisContext::Cancelled() { return absl::CancelledError("diagnosis cancelled"); }

void DiagnosisContext::ForEach(int count, const std::function<void(int)>& job) const {
  const int tasks = std::max(1, std::min(options_.threads, count));
  if (tasks == 1 || !options_.run_parallel) {
    for (int i = 0; i < count; ++i) job(i);
    return;
  }
  // Each task takes the next unstarted job: the costly ones, listed first, spread over the tasks.
  std::atomic<int> next{0};
  options_.run_parallel(tasks, [&](int) {
    for (int i = next++; i < count; i = next++) job(i);
  });
}

absl::StatusOr<ModelRun> DiagnosisContext::Run(const ModelState& model, bool held_out) const {
  const std::vector<TelemetryFrame> corrected = CorrectStarTracker(frames_, rates_, model.correction);
  return held_out ? RunModel(model.config, model.options, corrected, held_out_options_)
                  : RunModel(model.config, model.options, corrected);
}

absl::StatusOr<ModelRun> DiagnosisContext::CheckedRun(const ModelState& model, bool held_out) {
  if (Stop()) return Cancelled();
  ++filter_runs_;
  return Run(model, held_out);
}

}  // namespace esg::estimator::discovery
