// The warm-up at the longest time constant searched (docs/decisions.md D130): a drift changing
// linearly shows no decay, and the candidate does not name one.
#include <string>
#include <vector>

#include "estimator/attitude_profile.h"
#include "estimator/discovery/candidates.h"
#include "estimator/simulator.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/discovery_scenarios.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator::discovery {
namespace {

using ::esg::testing::IsOk;
using ::testing::HasSubstr;

// Gyro 2's rotor displacement grows from 0 to 0.3 of the rotor_displacement scenario's 1.4 um over
// a 12 h inertial hold: its spin axis stays put in case axes, so its drift of eq. (8) + (9) grows
// linearly, r t with r t about 0.03 deg/h at the end. An exponential A e^(-t/tau) beside the
// model's free k0 takes a ramp as A (1 - t/tau), A = -r tau: 0.06 deg/h at tau = 24 h, inside
// the amplitude's prior 1-sigma of 0.1 deg/h (a ramp three times steeper needs A = 0.18 deg/h
// there, and the prior then puts the best tau inside the span). The best time constant of an
// exponential from the start is then the longest searched, and no warm-up is fitted.
TEST(WarmUp, ADriftGrowingLinearlyIsNoWarmUp) {
  constexpr double kHours = 12.0;
  constexpr uint64_t kSeed = 4;
  SimulationSpec spec = ::esg::testing::DiscoveryScenario("none", kSeed, kHours);
  auto profile = MakeNamedProfile("inertial", spec.duration, kSeed);
  ASSERT_THAT(profile, IsOk());
  spec.profile = *profile;
  const int gyro = 2;
  spec.gyros[gyro - 1].rotor_displacement_rate_k_m_s =
      0.3 * Eigen::Vector3d(0.8e-6, -1.0e-6, 0.6e-6) / spec.duration;
  auto fitting = ::esg::testing::PrepareCandidateFit(spec);
  ASSERT_THAT(fitting, IsOk());
  const FitContext ctx = (*fitting)->Context();
  auto fit = FitCandidate({Effect::kWarmUp, gyro}, ctx);
  ASSERT_THAT(fit, IsOk());
  std::string notes;
  for (const std::string& n : fit->notes) notes += "\n" + n;
  SCOPED_TRACE(notes);
  EXPECT_EQ(fit->parameters, 0);
  EXPECT_THAT(fit->not_fitted, HasSubstr("is the longest searched (0.5-24 h)"));
  EXPECT_GT(fit->runs, 0);  // searched, then refused
}

}  // namespace
}  // namespace esg::estimator::discovery
