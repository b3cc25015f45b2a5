// The orbit of a discovery scenario's orbital segments (tests/testing/discovery_scenarios.h
// ScenarioOrbitalOptions), as `esg diagnose --orbit` would be given it: circular-orbit states
// every 60 s from a minute before the recording to a minute after it (orbit.h
// CircularOrbitState, FromArcs).
#pragma once

#include <cstdint>
#include <memory>
#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "estimator/attitude_profile.h"
#include "estimator/discovery/options.h"
#include "estimator/orbit.h"
#include "estimator/simulator.h"
#include "tests/testing/discovery_scenarios.h"

namespace esg::testing {

inline absl::StatusOr<std::shared_ptr<const estimator::Orbit>> ScenarioOrbit(
    const estimator::SimulationSpec& spec, uint64_t seed) {
  const estimator::OrbitalOptions o = ScenarioOrbitalOptions(seed);
  estimator::OrbitArc arc;
  for (double t = -60.0; t <= spec.duration + 60.0 + 1e-9; t += 60.0) {
    arc.states.push_back(estimator::CircularOrbitState(o.inclination, o.raan, o.period,
                                                       o.arg_latitude0, spec.start, t));
  }
  arc.from = arc.states.front().time;
  arc.to = arc.states.back().time;
  absl::StatusOr<estimator::Orbit> orbit = estimator::Orbit::FromArcs({std::move(arc)});
  if (!orbit.ok()) return orbit.status();
  return std::make_shared<const estimator::Orbit>(*std::move(orbit));
}

// Gives the diagnosis the scenario's orbit when the recording flies through the Earth's shadow
// (spec.earth_shadow: "eclipse_drift"), as `esg diagnose --orbit` would be given it; leaves
// options.orbit as it is otherwise. Errors: those of ScenarioOrbit.
inline absl::Status AddScenarioOrbit(const estimator::SimulationSpec& spec, uint64_t seed,
                                     estimator::discovery::DiagnoseOptions& options) {
  if (!spec.earth_shadow) return absl::OkStatus();
  absl::StatusOr<std::shared_ptr<const estimator::Orbit>> orbit = ScenarioOrbit(spec, seed);
  if (!orbit.ok()) return orbit.status();
  options.orbit = *std::move(orbit);
  return absl::OkStatus();
}

}  // namespace esg::testing
