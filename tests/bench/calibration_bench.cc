// Calibration speed (issue: EKF): 24 h of 60 s telemetry, 8 Hz integration, model 10+11, three
// running gyros, one core. Target under 1 s (real-time factor 86,400). The recording is simulated
// once outside the timed loop.
#include "benchmark/benchmark.h"
#include "estimator/calibration_model.h"
#include "estimator/offline.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "tests/testing/paper_setup.h"

namespace esg::estimator {
namespace {

const SimulationResult& Flight24h() {
  static const SimulationResult* flight = [] {
    SimulationSpec spec;
    spec.config = testing::PaperConfig();
    spec.duration = HoursToSeconds(24.0);
    spec.seed = 1;
    spec.profile = *MakeNamedProfile("calibration", spec.duration, 1);
    spec.gyros[0].rotor_displacement_k = Eigen::Vector3d(1.0e-6, -1.5e-6, 0.8e-6);
    spec.star_tracker.outlier_probability = 0.01;
    spec.star_tracker.outlier_size = ArcminToRad(1.0);
    return new SimulationResult(*Simulate(spec));
  }();
  return *flight;
}

void BM_Calibrate24hModel10Plus11(benchmark::State& state) {
  const SimulationResult& flight = Flight24h();
  SessionOptions options;
  options.model = *ParseModel("10+11");
  const SpacecraftConfig config = testing::PaperConfig();
  for (auto _ : state) {
    auto result = RunCalibration(config, options, flight.recording.frames);
    benchmark::DoNotOptimize(result);
    if (!result.ok()) state.SkipWithError(std::string(result.status().message()).c_str());
  }
  state.counters["frames"] = static_cast<double>(flight.recording.frames.size());
  state.counters["realtime_factor"] = benchmark::Counter(
      HoursToSeconds(24.0), benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_Calibrate24hModel10Plus11)->Unit(benchmark::kMillisecond)->MinTime(3.0);

// Long-gap prediction from a calibrated state: 6 h at 60 s along an inertial hold.
void BM_Predict6hAt60s(benchmark::State& state) {
  const SimulationResult& flight = Flight24h();
  SessionOptions options;
  options.model = *ParseModel("10+11");
  const SpacecraftConfig config = testing::PaperConfig();
  EstimationSession session = *EstimationSession::Create(config, options);
  (void)RunCalibration(config, options, flight.recording.frames, {}, &session);
  std::vector<absl::Time> times;
  for (int i = 1; i <= 360; ++i) times.push_back(session.last_frame_time() + absl::Seconds(60 * i));
  for (auto _ : state) {
    auto predicted = session.Predict(times, nullptr, absl::InfinitePast());
    benchmark::DoNotOptimize(predicted);
  }
}
BENCHMARK(BM_Predict6hAt60s)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace esg::estimator
