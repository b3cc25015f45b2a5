// The open-ended stage (estimator/discovery/open_ended.h, docs/discovery.md "The open-ended
// stage") on simulated recordings.
#include <cstdio>
#include <cstdlib>

#include "estimator/discovery/deviation.h"
#include "estimator/discovery/diagnose.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/open_ended.h"
#include "estimator/discovery/regimes.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/discovery_scenarios.h"

namespace esg::estimator::discovery {
namespace {

struct StageRun {
  OpenEndedResult result;
  OpenEndedOptions options;
  int gyro = 0;
};

StageRun RunStage(const std::string& effect, uint64_t seed, double hours,
                  bool free_c = false) {
  SimulationSpec spec = ::esg::testing::DiscoveryScenario(effect, seed, hours);
  auto sim = Simulate(spec);
  EXPECT_TRUE(sim.ok());
  SpacecraftConfig config = spec.config;
  config.filter.fault_threshold = kPi;
  config.filter.integration_rate_hz = 0.2;
  if (free_c) {
    for (GyroConfig& g : config.gyros) {
      g.model_sigma.C1 = Eigen::Vector3d::Constant(DegPerHourToRadPerSec(0.1));
      g.model_sigma.C2 = Eigen::Vector3d::Constant(DegPerHourToRadPerSec(0.1));
    }
  }
  SessionOptions options;
  options.model.k0 = options.model.c1c2 = options.model.mu_nu = true;
  options.model.random_walk = true;
  const auto& frames = sim->recording.frames;
  auto run = RunModel(config, options, frames);
  EXPECT_TRUE(run.ok()) << run.status();
  const BodyRates rates = MeasureBodyRates(config, frames);
  auto series = MeasureDeviations(config, run->gyros, frames, rates, *run, {1, 2, 3});
  EXPECT_TRUE(series.ok()) << series.status();
  StageRun out;
  out.options.orbital_period_s = 5640.0;
  out.options.epoch = frames.front().time;
  const std::vector<double> rw(3, config.random_walk), w0(3, DegPerHourToRadPerSec(0.01));
  out.result = RunOpenEnded(*series, rw, w0, out.options);
  out.gyro = ::esg::testing::AffectedGyro(seed);
  std::printf("%s seed %d gyro %d: M %d best %s gyro %d 2lnB %.1f thr %.1f\n", effect.c_str(),
              static_cast<int>(seed), out.gyro, out.result.groups_tested,
              out.result.best_label.c_str(), out.result.best_gyro, out.result.best_evidence,
              out.result.best_threshold);
  for (const SelectedGroup& g : out.result.selected) {
    std::printf("  2lnB %.1f thr %.1f: %s\n", g.evidence, g.threshold,
                DescribeGroup(g, out.options).c_str());
  }
  return out;
}

TEST(OpenEnded, EffectFreeRecordingSelectsNothing) {
  const StageRun r = RunStage("none", 101, 24.0);
  EXPECT_TRUE(r.result.selected.empty());
}

TEST(OpenEnded, RotorDisplacementWithoutItsTermsIsACaseFixedDrift) {
  const StageRun r = RunStage("rotor_displacement", 102, 24.0);
  ASSERT_FALSE(r.result.selected.empty());
  EXPECT_EQ(r.result.selected.front().gyro, r.gyro);
}

TEST(OpenEnded, DriftStep) {
  const StageRun r = RunStage("drift_step", 103, 24.0);
}

}  // namespace
}  // namespace esg::estimator::discovery

namespace esg::estimator::discovery {
namespace {
TEST(OpenEndedExperiment, Classes) {
  const char* only = std::getenv("ESG_EXP_CLASSES");
  if (only == nullptr) GTEST_SKIP();
  for (const std::string& effect : ::esg::testing::DiscoveryBasisClasses()) {
    if (std::string(only) != "all" && std::string(only).find(effect) == std::string::npos) continue;
    const uint64_t seed = std::getenv("ESG_EXP_SEED") ? std::atoi(std::getenv("ESG_EXP_SEED")) : 101;
    const SimulationSpec spec = ::esg::testing::DiscoveryScenario(effect, seed, 30.0);
    auto sim = Simulate(spec);
    ASSERT_TRUE(sim.ok());
    auto report = Diagnose(spec.config, sim->recording.frames, DiagnoseOptions{});
    ASSERT_TRUE(report.ok()) << report.status();
    std::printf("== %s seed %d gyro %d: verdict %s\n", effect.c_str(), (int)seed,
                ::esg::testing::AffectedGyro(seed), report->verdict.c_str());
    for (const Finding& f : report->findings) {
      std::printf("  [%s gyro %d] %s\n", f.effect.c_str(), f.gyro, f.explanation.c_str());
      for (const std::string& n : f.evidence.notes) std::printf("     note: %s\n", n.c_str());
    }
  }
}
}  // namespace
}  // namespace esg::estimator::discovery
