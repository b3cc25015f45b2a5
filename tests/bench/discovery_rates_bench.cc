// Discovery (docs/discovery.md, "Proof"): the false-alarm rate over many effect-free recordings
// and the detection power against effect size. Scripts, not CI: each diagnosis of a 30 h
// recording takes seconds.
//
// BM_DiscoveryFalseAlarms: ESG_FALSE_ALARM_SEEDS (default 300) effect-free 30 h recordings of
// tests/testing/discovery_scenarios.h, seeds from ESG_FALSE_ALARM_FIRST_SEED (default 1001, apart
// from the confusion matrix's 101-110 and the tests'), each diagnosed with the default options.
// A false alarm is any finding (verdict other than `none`). Prints every recording's verdict to
// stderr, and the count, the rate and its exact (Clopper-Pearson) one-sided 95% upper bound.
// ESG_FALSE_ALARM_EFFECT names another scenario to read its diagnoses the same way.
// ESG_FALSE_ALARM_ORBIT=1 gives each diagnosis the spacecraft's orbit, as `esg diagnose --orbit`
// does (a circular orbit of the scenario's orbital elements, orbit.h CircularOrbitState, states
// every 60 s over the recording): the sun's regressors then see the Earth's shadow and the
// `sunlit` family is tried.
// Run: scripts/false_alarm_rate.sh (ORBIT=1 for the orbit).
//
// BM_DiscoveryPower: per effect of the scenarios, ESG_POWER_SEEDS (default 5) recordings at each
// size factor of ESG_POWER_SCALES (default 0.125,0.25,0.5,1; 1 = the confusion matrix's size),
// seeds from 2001; prints the share found (the right verdict in the right gyro, as the confusion
// matrix counts it) per effect and size as a Markdown table and a data file for the plot;
// ESG_POWER_EFFECTS a comma list of effects, ESG_DISCOVERY_NOTES=1 every finding's notes too.
// Run: scripts/power_curves.sh.
//
// Both spread the diagnoses over ESG_DISCOVERY_JOBS (default 2) threads, one diagnosis each;
// ESG_DISCOVERY_INTEGRATION_RATE sets DiagnoseOptions::integration_rate_hz (<= 0: the
// configuration's rate).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <map>
#include <memory>
#include <mutex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "benchmark/benchmark.h"
#include "estimator/attitude_profile.h"
#include "estimator/discovery/diagnose.h"
#include "estimator/orbit.h"
#include "estimator/simulator.h"
#include "tests/testing/discovery_scenarios.h"
#include "tests/testing/scenario_orbit.h"

namespace esg::estimator::discovery {
namespace {

int EnvInt(const char* name, int fallback) {
  const char* v = std::getenv(name);
  return v != nullptr ? std::max(1, std::atoi(v)) : fallback;
}

// Runs job(0) ... job(count - 1) on `threads` threads, each taking the next job.
void RunJobs(int count, int threads, const std::function<void(int)>& job) {
  std::atomic<int> next{0};
  std::vector<std::thread> workers;
  for (int t = 0; t < threads; ++t) {
    workers.emplace_back([&] {
      for (int i = next++; i < count; i = next++) job(i);
    });
  }
  for (std::thread& w : workers) w.join();
}

// P(X <= x) for X ~ Binomial(n, p).
double BinomialCdf(int x, int n, double p) {
  double sum = 0.0;
  for (int k = 0; k <= x; ++k) {
    const double log_term = std::lgamma(n + 1.0) - std::lgamma(k + 1.0) - std::lgamma(n - k + 1.0) +
                            k * std::log(p) + (n - k) * std::log1p(-p);
    sum += std::exp(log_term);
  }
  return sum;
}

// Exact one-sided upper confidence bound (Clopper-Pearson) of a rate seen x times in n at
// `level`: the p with P(X <= x | p) = 1 - level.
double UpperBound(int x, int n, double level) {
  if (x >= n) return 1.0;
  double lo = 0.0, hi = 1.0;
  for (int i = 0; i < 100; ++i) {
    const double mid = 0.5 * (lo + hi);
    (BinomialCdf(x, n, mid) > 1.0 - level ? lo : hi) = mid;
  }
  return hi;
}

// One diagnosis of a scenario with the default options on the calling thread.
absl::StatusOr<DiagnosisReport> DiagnoseScenario(const std::string& effect, uint64_t seed,
                                                 double scale) {
  const SimulationSpec spec = ::esg::testing::DiscoveryScenario(effect, seed, 30.0, scale);
  auto sim = Simulate(spec);
  if (!sim.ok()) return sim.status();
  DiagnoseOptions options;
  options.threads = 1;
  if (EnvInt("ESG_FALSE_ALARM_ORBIT", 0) != 0) {
    auto orbit = ::esg::testing::ScenarioOrbit(spec, seed);
    if (!orbit.ok()) return orbit.status();
    options.orbit = *std::move(orbit);
  }
  if (const char* rate = std::getenv("ESG_DISCOVERY_INTEGRATION_RATE")) {
    options.integration_rate_hz = std::atof(rate);
  }
  return Diagnose(spec.config, sim->recording.frames, options);
}

std::string Findings(const DiagnosisReport& r) {
  std::string text;
  for (const Finding& f : r.findings) {
    text += " " + f.effect + (f.gyro > 0 ? "[" + std::to_string(f.gyro) + "]" : "");
  }
  return text;
}

void BM_DiscoveryFalseAlarms(benchmark::State& state) {
  const int seeds = EnvInt("ESG_FALSE_ALARM_SEEDS", 300);
  const int first = EnvInt("ESG_FALSE_ALARM_FIRST_SEED", 1001);
  const int jobs = EnvInt("ESG_DISCOVERY_JOBS", 2);
  // Another scenario in place of the effect-free one, to read its diagnoses (not a rate then).
  const char* effect_env = std::getenv("ESG_FALSE_ALARM_EFFECT");
  const std::string effect = effect_env != nullptr ? effect_env : "none";
  std::atomic<int> alarms{0}, failed{0};
  std::mutex out;
  for (auto _ : state) {
    RunJobs(seeds, jobs, [&](int i) {
      const uint64_t seed = first + i;
      auto report = DiagnoseScenario(effect, seed, 1.0);
      std::lock_guard<std::mutex> lock(out);
      if (!report.ok()) {
        ++failed;
        std::fprintf(stderr, "seed %4llu: error %s\n", static_cast<unsigned long long>(seed),
                     std::string(report.status().message()).c_str());
        return;
      }
      const bool alarm = report->verdict != kVerdictNone;
      alarms += alarm ? 1 : 0;
      std::fprintf(stderr, "seed %4llu: %-26s%s\n", static_cast<unsigned long long>(seed),
                   report->verdict.c_str(), alarm ? Findings(*report).c_str() : "");
      for (const Finding& f : report->findings) {
        std::fprintf(stderr, "    %s\n", f.explanation.c_str());
        for (const std::string& note : f.evidence.notes) std::fprintf(stderr, "      - %s\n", note.c_str());
      }
    });
  }
  const int n = seeds - failed.load();
  const double rate = n > 0 ? static_cast<double>(alarms) / n : 0.0;
  const double bound = n > 0 ? UpperBound(alarms, n, 0.95) : 1.0;
  std::printf(
      "\nfalse alarms: %d of %d effect-free 30 h recordings (seeds %d-%d, %d failed): rate %.2f%%, "
      "one-sided 95%% upper bound %.2f%% (Clopper-Pearson)\n",
      alarms.load(), n, first, first + seeds - 1, failed.load(), 100.0 * rate, 100.0 * bound);
  std::fflush(stdout);
  state.counters["false_alarms"] = alarms.load();
  state.counters["recordings"] = n;
  state.counters["rate"] = rate;
  state.counters["upper95"] = bound;
}
BENCHMARK(BM_DiscoveryFalseAlarms)->Unit(benchmark::kSecond)->Iterations(1)->UseRealTime();

void BM_DiscoveryPower(benchmark::State& state) {
  const int seeds = EnvInt("ESG_POWER_SEEDS", 5);
  const int jobs = EnvInt("ESG_DISCOVERY_JOBS", 2);
  std::vector<double> scales = {0.125, 0.25, 0.5, 1.0};
  if (const char* v = std::getenv("ESG_POWER_SCALES"); v != nullptr && *v != '\0') {
    scales.clear();
    std::stringstream in(v);
    for (std::string item; std::getline(in, item, ',');) scales.push_back(std::atof(item.c_str()));
  }
  std::vector<std::string> effects = ::esg::testing::DiscoveryEffects();
  effects.erase(effects.begin());  // not "none"
  effects.push_back("drift_step");
  effects.push_back("random_walk_one_gyro");
  if (const char* v = std::getenv("ESG_POWER_EFFECTS"); v != nullptr && *v != '\0') {
    effects.clear();
    std::stringstream in(v);
    for (std::string item; std::getline(in, item, ',');) effects.push_back(item);
  }
  struct Job {
    std::string effect;
    double scale;
    uint64_t seed;
  };
  std::vector<Job> all;
  for (const std::string& e : effects) {
    for (double x : scales) {
      for (int k = 0; k < seeds; ++k) all.push_back({e, x, static_cast<uint64_t>(2001 + k)});
    }
  }
  std::map<std::pair<std::string, double>, int> found;
  // ESG_DISCOVERY_NOTES=1: every finding's explanation and notes under its line.
  const char* notes_env = std::getenv("ESG_DISCOVERY_NOTES");
  const bool notes = notes_env != nullptr && std::string(notes_env) == "1";
  std::mutex out;
  for (auto _ : state) {
    RunJobs(static_cast<int>(all.size()), jobs, [&](int i) {
      const Job& j = all[i];
      auto report = DiagnoseScenario(j.effect, j.seed, j.scale);
      std::lock_guard<std::mutex> lock(out);
      const bool ok = report.ok() && ::esg::testing::DiscoveryVerdictCorrect(
                                         j.effect, ::esg::testing::AffectedGyro(j.seed), *report);
      found[{j.effect, j.scale}] += ok ? 1 : 0;
      std::fprintf(stderr, "%-26s x%-6.3g seed %4llu: %-26s%s\n", j.effect.c_str(), j.scale,
                   static_cast<unsigned long long>(j.seed),
                   report.ok() ? report->verdict.c_str() : "error",
                   report.ok() ? Findings(*report).c_str() : "");
      if (notes && report.ok()) {
        for (const Finding& f : report->findings) {
          std::fprintf(stderr, "    %s\n", f.explanation.c_str());
          for (const std::string& n : f.evidence.notes) std::fprintf(stderr, "      - %s\n", n.c_str());
        }
      }
    });
  }
  std::printf("\n| effect \\ size factor |");
  for (double x : scales) std::printf(" %g |", x);
  std::printf("\n|---|");
  for (size_t i = 0; i < scales.size(); ++i) std::printf("---|");
  std::printf("\n");
  for (const std::string& e : effects) {
    std::printf("| %s |", e.c_str());
    for (double x : scales) std::printf(" %d/%d |", found[{e, x}], seeds);
    std::printf("\n");
  }
  // Data for the plot: effect, size factor, share found.
  std::printf("\n# data: effect scale found_share\n");
  for (const std::string& e : effects) {
    for (double x : scales) {
      std::printf("%s %g %.4f\n", e.c_str(), x, static_cast<double>(found[{e, x}]) / seeds);
    }
  }
  std::printf("(%d recordings per point, 30 h, seeds 2001-%d)\n", seeds, 2000 + seeds);
  std::fflush(stdout);
}
BENCHMARK(BM_DiscoveryPower)->Unit(benchmark::kSecond)->Iterations(1)->UseRealTime();

}  // namespace
}  // namespace esg::estimator::discovery
