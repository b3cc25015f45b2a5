// Fuzz target: the scenario JSON of the simulator (client::ParseScenarioJson) and what the CLI
// does with a parsed scenario: ApplyScenario on the example configuration
// deploy/examples/rdk1.json, the scenario's attitude profile, and a short simulation.
// Property: a text is refused with InvalidArgument, or gives a scenario that applies to the
// configuration (or is refused with InvalidArgument naming a gyro it lacks) into a valid
// simulation spec, whose profile (or a clean InvalidArgument) gives unit finite attitudes, and
// whose simulation runs (or is refused with InvalidArgument) to a recording the recording rules
// accept.
#include <cstddef>
#include <cstdint>
#include <string>

#include "client/scenario.h"
#include "estimator/simulator.h"
#include "fuzz/fuzz_util.h"
#include "proto/convert.h"

namespace {

const esg::estimator::SpacecraftConfig& Config() {
  static const esg::estimator::SpacecraftConfig* config = [] {
    absl::StatusOr<esg::estimator::SpacecraftConfig> c =
        esg::proto_convert::ReadConfigFile(ESG_SOURCE_DIR "/deploy/examples/rdk1.json");
    ESG_FUZZ_CHECK(c.ok(), c.status().ToString());
    return new esg::estimator::SpacecraftConfig(*c);
  }();
  return *config;
}

constexpr double kDuration = 60.0;  // [s] of simulation per input: two telemetry frames

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace esg;
  absl::StatusOr<client::Scenario> scenario = client::ParseScenarioJson(fuzz::AsText(data, size));
  if (!scenario.ok()) {
    fuzz::CheckCleanError(scenario.status(), absl::StatusCode::kInvalidArgument);
    return 0;
  }
  estimator::SimulationSpec spec;
  spec.config = Config();
  spec.duration = kDuration;
  if (absl::Status applied = client::ApplyScenario(*scenario, &spec); !applied.ok()) {
    fuzz::CheckCleanError(applied, absl::StatusCode::kInvalidArgument);
    return 0;
  }
  absl::StatusOr<estimator::ProfilePtr> profile =
      client::MakeScenarioProfile(*scenario, "", kDuration);
  if (!profile.ok()) {
    fuzz::CheckCleanError(profile.status(), absl::StatusCode::kInvalidArgument);
    return 0;
  }
  for (double t : {0.0, 0.5 * kDuration, kDuration}) {
    const Eigen::Quaterniond q = (*profile)->Attitude(t);
    ESG_FUZZ_CHECK(q.coeffs().allFinite() && fuzz::IsUnit(q.norm()), "unit profile attitude");
  }
  spec.profile = *profile;
  const absl::Status valid = estimator::ValidateSimulationSpec(spec);
  ESG_FUZZ_CHECK(valid.ok(), valid.ToString());
  absl::StatusOr<estimator::SimulationResult> result = estimator::Simulate(spec);
  ESG_FUZZ_CHECK(result.ok(), result.status().ToString());
  fuzz::CheckRecordingInvariants(result->recording);
  return 0;
}
