// Calibration speed (issue: EKF): 24 h of 60 s telemetry, model 10+11, three running gyros, one
// core, with the default substeps (motion-bounded under the configured 8 Hz, D125); the same at
// fixed rates (8 Hz the reference), with motion-bounded substeps at other bounds (D120), and the
// cost of one measurement step. Target under 1 s (real-time factor 86,400). The recording is
// simulated once outside the timed loop.
#include <algorithm>
#include <cmath>

#include "benchmark/benchmark.h"
#include "estimator/calibration_model.h"
#include "estimator/offline.h"
#include "estimator/rotation.h"
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
  state.counters["realtime_factor"] =
      benchmark::Counter(HoursToSeconds(24.0), benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_Calibrate24hModel10Plus11)->Unit(benchmark::kMillisecond)->MinTime(3.0);

// The integration rate against the filter's floor (docs/performance.md "Integration rate"): the
// same calibration with the spin axes propagated at 8 Hz (the paper's), 1 Hz and 0.1 Hz, the
// last one substep per 60 s frame, so its time is close to what the measurement updates alone
// cost. Arg: the rate in tenths of a Hz. Counters, against the 8 Hz run: the largest difference
// of a free coefficient in units of its 8 Hz 1-sigma (coef_diff_sigma), and of the final
// attitude about a body axis in units of that axis' 8 Hz 1-sigma (attitude_diff_sigma).
void Calibrate24hAgainst8Hz(benchmark::State& state, const SpacecraftConfig& config,
                            const SessionOptions& options) {
  const SimulationResult& flight = Flight24h();
  static const CalibrationResult* reference = [] {
    SessionOptions reference_options;
    reference_options.model = *ParseModel("10+11");
    reference_options.substeps = SessionOptions::Substeps::kFixedRate;
    absl::StatusOr<CalibrationResult> r =
        RunCalibration(testing::PaperConfig(), reference_options, Flight24h().recording.frames);
    return r.ok() ? new CalibrationResult(*std::move(r)) : nullptr;
  }();
  if (reference == nullptr) {
    state.SkipWithError("the 8 Hz reference calibration failed");
    return;
  }
  absl::StatusOr<CalibrationResult> result;
  for (auto _ : state) {
    result = RunCalibration(config, options, flight.recording.frames);
    benchmark::DoNotOptimize(result);
    if (!result.ok()) {
      state.SkipWithError(std::string(result.status().message()).c_str());
      return;
    }
  }
  double coef_diff_sigma = 0.0;
  for (size_t g = 0; g < reference->gyros.size() && g < result->gyros.size(); ++g) {
    const DriftVector ref = reference->gyros[g].coefficients.AsVector();
    const DriftVector sigma = reference->gyros[g].sigma.AsVector();
    const DriftVector got = result->gyros[g].coefficients.AsVector();
    for (int k = 0; k < kNumDriftCoefficients; ++k) {
      if (sigma(k) > 0) {
        coef_diff_sigma = std::max(coef_diff_sigma, std::abs(got(k) - ref(k)) / sigma(k));
      }
    }
  }
  // The attitude difference in body axes, q_b_diff = q_ref^-1 q.
  const AttitudeEstimate& a_ref = reference->final_attitude;
  const Eigen::Vector3d diff_b =
      LogQuaternion(a_ref.q_in_b.conjugate() * result->final_attitude.q_in_b);
  double attitude_diff_sigma = 0.0;
  for (int i = 0; i < 3; ++i) {
    if (a_ref.sigma_b(i) > 0) {
      attitude_diff_sigma = std::max(attitude_diff_sigma, std::abs(diff_b(i)) / a_ref.sigma_b(i));
    }
  }
  state.counters["coef_diff_sigma"] = coef_diff_sigma;
  state.counters["attitude_diff_sigma"] = attitude_diff_sigma;
  state.counters["measurement_steps"] = result->measurement_steps;
}

// The integration rate against the filter's floor (docs/performance.md "Integration rate"): the
// same calibration with the spin axes propagated at 8 Hz (the paper's), 1 Hz and 0.1 Hz, the
// last one substep per 60 s frame, so its time is close to what the measurement updates alone
// cost. Arg: the rate in tenths of a Hz. Counters, against the 8 Hz run: the largest difference
// of a free coefficient in units of its 8 Hz 1-sigma (coef_diff_sigma), and of the final
// attitude about a body axis in units of that axis' 8 Hz 1-sigma (attitude_diff_sigma).
void BM_Calibrate24hAtIntegrationRate(benchmark::State& state) {
  SessionOptions options;
  options.model = *ParseModel("10+11");
  options.substeps = SessionOptions::Substeps::kFixedRate;
  SpacecraftConfig config = testing::PaperConfig();
  config.filter.integration_rate_hz = static_cast<double>(state.range(0)) / 10.0;
  Calibrate24hAgainst8Hz(state, config, options);
  state.counters["rate_hz"] = config.filter.integration_rate_hz;
}
BENCHMARK(BM_Calibrate24hAtIntegrationRate)
    ->Arg(80)
    ->Arg(10)
    ->Arg(1)
    ->Unit(benchmark::kMillisecond)
    ->MinTime(3.0);

// The same calibration with substeps bounded by the motion over each interval
// (SessionOptions::Substeps::kMotionBounded, docs/decisions.md D120) at the configured 8 Hz
// rate as their ceiling. Arg: max_substep_turn_deg in tenths of a degree. Counters as above,
// against the 8 Hz run.
void BM_Calibrate24hMotionBounded(benchmark::State& state) {
  SessionOptions options;
  options.model = *ParseModel("10+11");
  options.substeps = SessionOptions::Substeps::kMotionBounded;
  options.max_substep_turn_deg = static_cast<double>(state.range(0)) / 10.0;
  Calibrate24hAgainst8Hz(state, testing::PaperConfig(), options);
  state.counters["max_substep_turn_deg"] = options.max_substep_turn_deg;
}
BENCHMARK(BM_Calibrate24hMotionBounded)
    ->Arg(5)
    ->Arg(20)
    ->Unit(benchmark::kMillisecond)
    ->MinTime(3.0);

// The cost of one frame at the floor: a session calibrated over the first 24 h less a minute
// adds the last frame, a measurement step (propagation in one substep: motion-bounded at 10 deg,
// the calibration profile turns 6 deg a minute; then the Joseph update, the fault tests of eq.
// (12) and (14), the monitors). Each iteration copies the calibrated session first, and AddFrame
// copies it once more (its transactional step); BM_SessionCopy times one copy.
const EstimationSession& CalibratedBeforeLastFrame(const SessionOptions& options) {
  static const EstimationSession* session = [&] {
    const std::vector<TelemetryFrame>& frames = Flight24h().recording.frames;
    const std::vector<TelemetryFrame> head(frames.begin(), frames.end() - 1);
    auto s = new EstimationSession(*EstimationSession::Create(testing::PaperConfig(), options));
    (void)RunCalibration(testing::PaperConfig(), options, head, {}, s);
    return s;
  }();
  return *session;
}

SessionOptions FloorOptions() {
  SessionOptions options;
  options.model = *ParseModel("10+11");
  options.substeps = SessionOptions::Substeps::kMotionBounded;
  options.max_substep_turn_deg = 10.0;
  return options;
}

void BM_MeasurementStep(benchmark::State& state) {
  const EstimationSession& calibrated = CalibratedBeforeLastFrame(FloorOptions());
  const TelemetryFrame& last = Flight24h().recording.frames.back();
  int substeps = 0;
  bool measured = false;
  for (auto _ : state) {
    EstimationSession s = calibrated;
    auto report = s.AddFrame(last);
    benchmark::DoNotOptimize(report);
    if (!report.ok()) {
      state.SkipWithError(std::string(report.status().message()).c_str());
      return;
    }
    substeps = s.last_propagation_substeps();
    measured = report->measurement_step;
  }
  state.counters["substeps"] = substeps;
  state.counters["measurement_step"] = measured;
}
BENCHMARK(BM_MeasurementStep)->Unit(benchmark::kMicrosecond)->MinTime(2.0);

void BM_SessionCopy(benchmark::State& state) {
  const EstimationSession& calibrated = CalibratedBeforeLastFrame(FloorOptions());
  for (auto _ : state) {
    EstimationSession s = calibrated;
    benchmark::DoNotOptimize(s);
  }
}
BENCHMARK(BM_SessionCopy)->Unit(benchmark::kMicrosecond)->MinTime(2.0);

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
