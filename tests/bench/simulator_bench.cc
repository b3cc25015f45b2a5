// Simulator throughput: 24 h of four running gyros at 8 Hz integration with 60 s telemetry on the
// paper's calibration profile (target: under 0.5 s on one core).
#include "benchmark/benchmark.h"
#include "estimator/attitude_profile.h"
#include "estimator/rotation.h"
#include "estimator/simulator.h"
#include "estimator/units.h"

namespace esg::estimator {
namespace {

using Eigen::Vector3d;

// An RDK-1-like configuration (deploy/examples/rdk1.json): case frames turned to each other.
SpacecraftConfig BenchConfig() {
  SpacecraftConfig c;
  c.spacecraft_id = "BENCH-1";
  const Vector3d mountings[4] = {Vector3d(0, 0, 0), Vector3d(0.0, DegToRad(90.0), 0.0),
                                 Vector3d(DegToRad(-90.0), 0.0, 0.0), Vector3d(0.5, 0.6, -0.7)};
  for (int id = 1; id <= 4; ++id) {
    GyroConfig g;
    g.id = id;
    g.C_b_k = ExpMatrix(mountings[id - 1]);
    g.model.k0 = DegPerHourToRadPerSec(0.2 + 0.05 * id);
    g.model.C1 = DegPerHourToRadPerSec(0.05) * Vector3d(1.0, -0.5, 0.2);
    g.model.C2 = DegPerHourToRadPerSec(0.03) * Vector3d(-0.3, 0.4, 1.0);
    c.gyros.push_back(g);
  }
  c.star_tracker.noise = ArcsecToRad(1.0) * Vector3d(5, 5, 30);
  c.readout_noise = ArcsecToRad(3.0);
  c.random_walk = DegPerHourSqrtHourToSi(0.0015);
  return c;
}

void BM_Simulate24hFourGyrosCalibration(benchmark::State& state) {
  SimulationSpec spec;
  spec.config = BenchConfig();
  spec.duration = HoursToSeconds(24.0);
  spec.profile = *MakeNamedProfile("calibration", spec.duration);
  for (int g = 0; g < 4; ++g) spec.gyros[g].running = true;
  spec.star_tracker.outlier_probability = 0.01;
  spec.star_tracker.outlier_size = ArcminToRad(2.0);
  for (auto _ : state) {
    auto result = Simulate(spec);
    if (!result.ok()) state.SkipWithError(std::string(result.status().message()).c_str());
    benchmark::DoNotOptimize(result);
  }
  state.counters["steps_per_s"] = benchmark::Counter(spec.duration * spec.integration_rate_hz,
                                                     benchmark::Counter::kIsIterationInvariantRate);
}
BENCHMARK(BM_Simulate24hFourGyrosCalibration)->Unit(benchmark::kMillisecond);

void BM_CalibrationProfileAttitude(benchmark::State& state) {
  const ProfilePtr p = *MakeNamedProfile("calibration", HoursToSeconds(24.0));
  double t = 0.0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(p->Attitude(t));
    t += 0.125;
    if (t > 86400.0) t = 0.0;
  }
}
BENCHMARK(BM_CalibrationProfileAttitude);

}  // namespace
}  // namespace esg::estimator
