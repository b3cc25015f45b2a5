// Discovery (docs/discovery.md): speed and the confusion matrix.
//
// BM_Diagnose30h: one diagnosis of a 30 h recording at 60 s telemetry (rotor displacement in one
// gyro: two selection rounds), both cores. Target under 60 s.
//
// BM_DiscoveryConfusionMatrix: ESG_DISCOVERY_SEEDS (default 10) simulated recordings per true
// effect (tests/testing/discovery_scenarios.h: mostly orbital, outliers and an outage, the
// effect in one gyro where that applies), each diagnosed; prints the verdict table to stdout and
// reports per effect the share of correct verdicts (verdict and gyro right) as counters.
// ESG_DISCOVERY_ROWS=library or =time selects the library's rows or the time behaviours' (with
// `none`), =basis the open-ended stage's classes; ESG_DISCOVERY_TRUTHS=a,b exactly these rows;
// ESG_DISCOVERY_NOTES=1 adds each finding's notes to its line; ESG_DISCOVERY_FIRST_SEED=k starts
// at seed 100 + k. Run:
//   <build>/tests/bench/esg_bench --benchmark_filter=Confusion
// (scripts/confusion_matrix.sh). Takes a few minutes.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <functional>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_split.h"
#include "benchmark/benchmark.h"
#include "estimator/discovery/diagnose.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "tests/testing/discovery_scenarios.h"
#include "tests/testing/scenario_orbit.h"

namespace esg::estimator::discovery {
namespace {

// The estimator starts no threads: the bench lends it options.threads, the calling one included,
// as esg diagnose does.
void RunOnThreads(int count, const std::function<void(int)>& task) {
  std::vector<std::thread> helpers;
  for (int i = 1; i < count; ++i) helpers.emplace_back(task, i);
  task(0);
  for (std::thread& t : helpers) t.join();
}

void BM_Diagnose30h(benchmark::State& state) {
  const SimulationSpec spec = ::esg::testing::DiscoveryScenario("rotor_displacement", 1, 30.0);
  const SimulationResult sim = *Simulate(spec);
  DiagnoseOptions options;
  options.threads = static_cast<int>(state.range(0));
  options.run_parallel = RunOnThreads;
  int runs = 0;
  for (auto _ : state) {
    auto report = Diagnose(spec.config, sim.recording.frames, options);
    if (!report.ok()) {
      state.SkipWithError(std::string(report.status().message()).c_str());
      return;
    }
    runs = report->filter_runs;
    benchmark::DoNotOptimize(report);
  }
  state.counters["frames"] = static_cast<double>(sim.recording.frames.size());
  state.counters["filter_runs"] = runs;
}
BENCHMARK(BM_Diagnose30h)->Arg(1)->Arg(2)->Unit(benchmark::kSecond)->Iterations(1)->UseRealTime();

void BM_DiscoveryConfusionMatrix(benchmark::State& state) {
  const char* env = std::getenv("ESG_DISCOVERY_SEEDS");
  const int seeds = env != nullptr ? std::max(1, std::atoi(env)) : 10;
  // ESG_DISCOVERY_FIRST_SEED=k: seeds 100 + k, ... (default 1: 101, 102, ...).
  const char* first_env = std::getenv("ESG_DISCOVERY_FIRST_SEED");
  const int first_seed = first_env != nullptr ? std::max(1, std::atoi(first_env)) : 1;
  // ESG_DISCOVERY_ROWS=time: only the time-behaviour rows (and `none`); =library: only the
  // library's rows; default both.
  const char* rows_env = std::getenv("ESG_DISCOVERY_ROWS");
  const std::string rows = rows_env != nullptr ? rows_env : "";
  // =basis: `none` and the classes of the open-ended stage (docs/discovery.md); =combined: a
  // drift that returns to its mean beside an effect of the library.
  std::vector<std::string> truths;
  // ESG_DISCOVERY_TRUTHS=a,b: exactly these rows (any scenario of discovery_scenarios.h).
  const char* truths_env = std::getenv("ESG_DISCOVERY_TRUTHS");
  if (truths_env != nullptr && *truths_env != '\0') {
    for (absl::string_view t : absl::StrSplit(truths_env, ',', absl::SkipEmpty())) {
      truths.emplace_back(t);
    }
  } else if (rows == "basis") {
    truths.push_back("none");
    for (const std::string& t : ::esg::testing::DiscoveryBasisClasses()) truths.push_back(t);
  } else if (rows == "combined") {  // a wandering drift beside a library effect
    for (const std::string& t : ::esg::testing::DiscoveryCombinedClasses()) truths.push_back(t);
  } else {
    if (rows != "time") {
      truths = ::esg::testing::DiscoveryEffects();
      truths.push_back("two");
    } else {
      truths.push_back("none");
    }
    if (rows != "library") {
      for (const std::string& t : ::esg::testing::DiscoveryTimeBehaviours()) truths.push_back(t);
    }
    if (rows != "time") {
      for (const std::string& t : ::esg::testing::DiscoveryStarTrackerClasses()) {
        truths.push_back(t);
      }
    }
  }
  const std::vector<std::string> verdicts = {"none",
                                             "rotor_displacement",
                                             "fourth_harmonic",
                                             "unequal_stiffness",
                                             "gyro_misalignment",
                                             "star_tracker_misalignment",
                                             "star_tracker_latency",
                                             "star_tracker_orbital_misalignment",
                                             "random_walk_drift",
                                             "drift_step",
                                             "basis_term",
                                             "partly_explained",
                                             "unexplained"};
  std::map<std::string, std::map<std::string, int>> table;
  std::map<std::string, int> correct;
  std::map<std::string, double> gap_ratio_sum;
  std::map<std::string, int> step_onset_inside;  // drift step: the true onset in the interval
  const char* notes_env = std::getenv("ESG_DISCOVERY_NOTES");
  const bool notes = notes_env != nullptr && std::string(notes_env) == "1";
  double seconds = 0.0;
  int diagnoses = 0;
  for (auto _ : state) {
    for (const std::string& truth : truths) {
      for (int seed = first_seed; seed < first_seed + seeds; ++seed) {
        const SimulationSpec spec = ::esg::testing::DiscoveryScenario(truth, 100 + seed, 30.0);
        const SimulationResult sim = *Simulate(spec);
        DiagnoseOptions options;  // default threads, lent as esg diagnose does
        options.run_parallel = RunOnThreads;
        // the orbit the recording flies, as esg diagnose --orbit
        if (absl::Status s = ::esg::testing::AddScenarioOrbit(spec, 100 + seed, options);
            !s.ok()) {
          state.SkipWithError(std::string(s.message()).c_str());
          return;
        }
        const auto start = std::chrono::steady_clock::now();
        auto report = Diagnose(spec.config, sim.recording.frames, options);
        seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
        ++diagnoses;
        if (!report.ok()) {
          state.SkipWithError(std::string(report.status().message()).c_str());
          return;
        }
        ++table[truth][report->verdict];
        std::string detail;
        for (const Finding& f : report->findings) {
          detail += " " + f.effect + "[" + std::to_string(f.gyro) + "]";
          if (notes) {
            if (!f.description.empty()) detail += " {" + f.description + "}";
            // What an `unexplained` finding says is in its explanation, not in its notes.
            if (f.effect == kVerdictUnexplained) detail += " {" + f.explanation + "}";
            for (const std::string& n : f.evidence.notes) detail += " <" + n + ">";
          }
          if (f.time.kind == "step") {
            const double truth_hours = 0.4 * 30.0;
            const bool inside = f.time.onset_lower_hours <= truth_hours &&
                                truth_hours <= f.time.onset_upper_hours;
            if ((truth == "drift_step" || truth == "c1_step") && f.effect == "drift_step") {
              step_onset_inside[truth] += inside;
            }
            char text[160];
            std::snprintf(text, sizeof text, " onset %.2f h [%.2f, %.2f]", f.time.onset_hours,
                          f.time.onset_lower_hours, f.time.onset_upper_hours);
            detail += text;
          }
          if (f.time.kind == "transient") {
            const Parameter* tau = FindParameter(f.parameters, "tauHours");
            const Parameter* lo = FindParameter(f.parameters, "tauLowerHours");
            const Parameter* hi = FindParameter(f.parameters, "tauUpperHours");
            const bool inside = f.time.onset_lower_hours <= 0.4 * 30.0 &&
                                0.4 * 30.0 <= f.time.onset_upper_hours;
            if (truth == "transient") step_onset_inside[truth] += inside;
            double worst = 0.0;  // the largest error of a component of A in its sigma
            for (int i = 0; i < 3; ++i) {
              const Parameter* a =
                  FindParameter(f.parameters, "transientDegH[" + std::to_string(i) + "]");
              if (a != nullptr && a->sigma > 0) {
                worst = std::max(worst, std::abs(a->value - ::esg::testing::WarmUpAmplitudeDegH()(i)) /
                                            a->sigma);
              }
            }
            if (tau != nullptr && lo != nullptr && hi != nullptr) {
              char text[200];
              std::snprintf(text, sizeof text,
                            " onset %.2f h [%.2f, %.2f] tau %.2f h [%.2f, %.2f] A error <= %.2f "
                            "sigma",
                            f.time.onset_hours, f.time.onset_lower_hours,
                            f.time.onset_upper_hours, tau->value, lo->value, hi->value, worst);
              detail += text;
            }
          }
          if (f.time.kind == "coefficient_step") {
            // The onset with its interval; each step's parameter, and for k0_step its error
            // against the truth in its sigma (the other groups' errors: the row's verdict).
            char onset[120];
            std::snprintf(onset, sizeof onset, " onset %.2f h [%.2f, %.2f]", f.time.onset_hours,
                          f.time.onset_lower_hours, f.time.onset_upper_hours);
            detail += onset;
            if (::esg::testing::IsCoefficientStepScenario(truth) &&
                f.time.onset_lower_hours <= 0.4 * 30.0 &&
                0.4 * 30.0 <= f.time.onset_upper_hours) {
              ++step_onset_inside[truth];
            }
            if (truth == "k0_step") {
              const Parameter* k0 = FindParameter(f.parameters, "k0StepDegH");
              if (k0 != nullptr && k0->sigma > 0) {
                char text[80];
                std::snprintf(text, sizeof text, " error %.2f sigma",
                              (k0->value - ::esg::testing::kK0StepDegH) / k0->sigma);
                detail += text;
              }
            }
            for (const Parameter& p : f.parameters) {
              if (p.name.find("StepDegH") == std::string::npos) continue;
              char text[120];
              std::snprintf(text, sizeof text, " %s %.4f+-%.4f deg/h", p.name.c_str(), p.value,
                            p.sigma);
              detail += text;
            }
          }
          if (f.time.kind == "follows_channel" && !f.basis_terms.empty()) {
            // The channel and form; each gain component with its sigma and its error against
            // the scenario's truth in sigma; the lag and its interval.
            const BasisTerm& t = f.basis_terms.front();
            detail += " " + t.channel + " " + std::string(ChannelFormName(t.form));
            for (int i = 0; i < 3; ++i) {
              const Parameter* a =
                  FindParameter(f.parameters, "channelGainDegH[" + std::to_string(i) + "]");
              if (a == nullptr) continue;
              char text[120];
              std::snprintf(text, sizeof text, " a%d %.4f+-%.4f (%.1f sigma)", i, a->value,
                            a->sigma,
                            a->sigma > 0
                                ? (a->value - ::esg::testing::ChannelGainDegHPerK()(i)) / a->sigma
                                : 0.0);
              detail += text;
            }
            const Parameter* lag = FindParameter(f.parameters, "channelLagHours");
            const Parameter* lo = FindParameter(f.parameters, "channelLagLowerHours");
            const Parameter* hi = FindParameter(f.parameters, "channelLagUpperHours");
            if (lag != nullptr && lo != nullptr && hi != nullptr) {
              char text[100];
              std::snprintf(text, sizeof text, " lag %.0f min [%.0f, %.0f]", lag->value * 60.0,
                            lo->value * 60.0, hi->value * 60.0);
              detail += text;
            }
          }
          if (f.time.kind == "warm_up") {
            const Parameter* tau = FindParameter(f.parameters, "tauHours");
            const Parameter* lo = FindParameter(f.parameters, "tauLowerHours");
            const Parameter* hi = FindParameter(f.parameters, "tauUpperHours");
            const Parameter* size = FindParameter(f.parameters, "warmUpSizeDegH");
            if (tau != nullptr && lo != nullptr && hi != nullptr && size != nullptr) {
              // The largest error of a component of A against the scenario's truth, in its sigma.
              double worst = 0.0;
              for (int i = 0; i < 3; ++i) {
                const Parameter* a =
                    FindParameter(f.parameters, "warmUpDegH[" + std::to_string(i) + "]");
                if (a != nullptr && a->sigma > 0) {
                  worst = std::max(worst, std::abs(a->value -
                                                   ::esg::testing::WarmUpAmplitudeDegH()(i)) /
                                              a->sigma);
                }
              }
              char text[200];
              std::snprintf(text, sizeof text,
                            " tau %.2f h [%.2f, %.2f] size %.4f+-%.4f deg/h max|dA_i|/sigma_i %.2f",
                            tau->value, lo->value, hi->value, size->value, size->sigma, worst);
              detail += text;
            }
          }
        }
        if (truth == "star_tracker_cycle" && !report->findings.empty()) {
          // The largest error of a cos or sin component against the truth, in its sigma.
          const Finding& f = report->findings.front();
          const double phase = ::esg::testing::StarTrackerCyclePhaseRad(100 + seed);
          const Eigen::Vector3d a =
              ::esg::testing::kStarTrackerCycleArcsec * ::esg::testing::StarTrackerCycleAxis();
          double worst = 0.0;
          for (int i = 0; i < 3; ++i) {
            const Parameter* c = FindParameter(f.parameters, "cycleCosArcsec[" + std::to_string(i) + "]");
            const Parameter* s = FindParameter(f.parameters, "cycleSinArcsec[" + std::to_string(i) + "]");
            if (c != nullptr && c->sigma > 0) {
              worst = std::max(worst, std::abs(c->value - a(i) * std::sin(phase)) / c->sigma);
            }
            if (s != nullptr && s->sigma > 0) {
              worst = std::max(worst, std::abs(s->value - a(i) * std::cos(phase)) / s->sigma);
            }
          }
          const Parameter* amp = FindParameter(f.parameters, "cycleAmplitudeArcsec");
          char text[160];
          std::snprintf(text, sizeof text, " amplitude %.2f+-%.2f arcsec max|dc,ds|/sigma %.2f",
                        amp != nullptr ? amp->value : 0.0, amp != nullptr ? amp->sigma : 0.0,
                        worst);
          detail += text;
        }
        const bool ok = ::esg::testing::DiscoveryVerdictCorrect(
            truth, ::esg::testing::AffectedGyro(100 + seed), *report, 100 + seed);
        correct[truth] += ok ? 1 : 0;
        if (report->before.gap_drift_rate_deg_h > 0) {
          gap_ratio_sum[truth] +=
              report->after.gap_drift_rate_deg_h / report->before.gap_drift_rate_deg_h;
        }
        std::fprintf(stderr, "%-26s seed %3d (gyro %d): %-26s%s;%s\n", truth.c_str(), 100 + seed,
                     ::esg::testing::AffectedGyro(100 + seed), report->verdict.c_str(),
                     ok ? "" : "  (wrong)", detail.c_str());
      }
    }
  }
  // The table: rows true effect, columns verdict; then the share correct (verdict and gyro).
  std::printf("\n| true effect \\ verdict |");
  for (const std::string& v : verdicts) std::printf(" %s |", v.c_str());
  std::printf(" correct | held-out drift after/before |\n|---|");
  for (size_t i = 0; i < verdicts.size(); ++i) std::printf("---|");
  std::printf("---|---|\n");
  for (const std::string& truth : truths) {
    std::printf("| %s |", truth.c_str());
    for (const std::string& v : verdicts) {
      const int n = table[truth][v];
      std::printf(" %s |", n > 0 ? std::to_string(n).c_str() : "");
    }
    std::printf(" %d/%d (%.0f%%) | %.2f |\n", correct[truth], seeds, 100.0 * correct[truth] / seeds,
                gap_ratio_sum[truth] / seeds);
    state.counters["correct_" + truth] = static_cast<double>(correct[truth]) / seeds;
  }
  std::printf(
      "\n(%d seeds per row, 30 h recordings; correct = verdict right, and the gyro for per-gyro "
      "effects; `two` = rotor displacement and star-tracker misalignment both found; the time "
      "behaviours `drift_step`, `random_walk_one_gyro` (found as random_walk_drift in that gyro) "
      "and `random_walk_15x` (random_walk_drift common to all) are correct with exactly that one "
      "finding; `readout_jump` = a fault outside the library, correct when unexplained)\n",
      seeds);
  for (const char* row :
       {"drift_step", "c1_step", "k0_step", "c2_step", "mu_step", "nu_step", "transient"}) {
    if (!table.count(row)) continue;
    std::printf("%s: the true onset (12.0 h) inside the stated onset interval in %d of %d\n", row,
                step_onset_inside[row], seeds);
  }
  std::printf("mean diagnosis time %.2f s over %d diagnoses\n", seconds / std::max(1, diagnoses),
              diagnoses);
  std::fflush(stdout);
}
BENCHMARK(BM_DiscoveryConfusionMatrix)->Unit(benchmark::kSecond)->Iterations(1)->UseRealTime();

}  // namespace
}  // namespace esg::estimator::discovery
