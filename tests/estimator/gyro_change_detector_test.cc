// The per-gyro accumulated star-tracker test (estimator/gyro_change_detector.h) against
// chi-square data with known statistics, and its checkpoint state.
#include "estimator/gyro_change_detector.h"

#include <cmath>
#include <limits>
#include <optional>
#include <random>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

constexpr std::array<int, 3> kIds = {1, 2, 3};

// Feeds `steps` steps where gyro k's NIS is scale[k] x chi-square(2); returns the decisions.
std::vector<GyroChangeDetector::Decision> Feed(GyroChangeDetector& d, std::mt19937_64& rng,
                                               int steps, std::array<double, 3> scale,
                                               bool suspected = false) {
  std::chi_squared_distribution<double> chi2(2.0);
  std::vector<GyroChangeDetector::Decision> out;
  for (int s = 0; s < steps; ++s) {
    const std::array<double, 3> nis = {scale[0] * chi2(rng), scale[1] * chi2(rng),
                                       scale[2] * chi2(rng)};
    if (auto r = d.Add(kIds, nis, suspected)) out.push_back(*r);
  }
  return out;
}

// 30 days of 60 s steps of a consistent filter: P(a sum of 10 chi-square(2) values, each capped,
// above the 1 - 1e-7 quantile) is below 1e-7 per gyro and step, so 129600 tests of three gyros
// name one with probability below 0.04.
TEST(GyroChangeDetector, ConsistentDifferencesNameNoGyroIn30Days) {
  GyroChangeDetector d;
  std::mt19937_64 rng(5);
  EXPECT_TRUE(Feed(d, rng, 30 * 1440, {1.0, 1.0, 1.0}).empty());
}

// A gyro whose differences carry a persistent bias (NIS 4 times chi-square(2): a 1.7-sigma
// offset on average) is named within the first full window; the others are not.
TEST(GyroChangeDetector, OneGyroInconsistentIsNamedAfterOneWindow) {
  GyroChangeDetector d;
  std::mt19937_64 rng(7);
  EXPECT_TRUE(Feed(d, rng, d.options().window_steps - 1, {1.0, 1.0, 4.0}).empty());
  const auto named = Feed(d, rng, 5, {1.0, 1.0, 4.0});
  ASSERT_FALSE(named.empty());
  EXPECT_EQ(named.front().gyro_id, 3);
  EXPECT_GT(named.front().sums[2], named.front().fail_threshold);
  EXPECT_LT(named.front().sums[0], named.front().pass_threshold);
  EXPECT_EQ(named.front().steps, 10);
}

// The same inconsistency in every gyro (a model that does not fit, a star-tracker error) names
// none; nor does one gyro's while the star tracker is suspected in the window.
TEST(GyroChangeDetector, CommonInconsistencyOrASuspectedStarTrackerNamesNone) {
  GyroChangeDetector d;
  std::mt19937_64 rng(9);
  EXPECT_TRUE(Feed(d, rng, 500, {4.0, 4.0, 4.0}).empty());
  GyroChangeDetector e;
  EXPECT_TRUE(Feed(e, rng, 500, {1.0, 1.0, 4.0}, /*suspected=*/true).empty());
  // One suspected step holds the decision for a window.
  EXPECT_TRUE(Feed(e, rng, 9, {1.0, 1.0, 4.0}).empty());
  EXPECT_FALSE(Feed(e, rng, 3, {1.0, 1.0, 4.0}).empty());
}

// Another set of gyros (an exclusion, a spare) starts the window again.
TEST(GyroChangeDetector, AnotherSetOfGyrosStartsTheWindowAgain) {
  GyroChangeDetector d;
  for (int s = 0; s < 9; ++s) EXPECT_FALSE(d.Add(kIds, {0, 0, 100}, false).has_value());
  EXPECT_FALSE(d.Add({1, 2, 4}, {0, 0, 100}, false).has_value());
  for (int s = 0; s < 8; ++s) EXPECT_FALSE(d.Add({1, 2, 4}, {0, 0, 100}, false).has_value());
  const auto named = d.Add({1, 2, 4}, {0, 0, 100}, false);
  ASSERT_TRUE(named.has_value());
  EXPECT_EQ(named->gyro_id, 4);
}

TEST(GyroChangeDetector, StateRoundTripsAndCorruptStateIsDataLoss) {
  GyroChangeDetector d;
  std::mt19937_64 rng(3);
  Feed(d, rng, 7, {1.0, 1.0, 1.0});
  const std::vector<double> state = d.ExportState();
  GyroChangeDetector restored;
  ASSERT_TRUE(restored.RestoreState(state).ok());
  EXPECT_EQ(restored.ExportState(), state);
  // The same next steps give the same decisions.
  std::mt19937_64 a(11), b(11);
  const auto da = Feed(d, a, 20, {1.0, 1.0, 6.0});
  const auto db = Feed(restored, b, 20, {1.0, 1.0, 6.0});
  ASSERT_EQ(da.size(), db.size());
  for (size_t i = 0; i < da.size(); ++i) EXPECT_EQ(da[i].sums, db[i].sums);
  for (size_t i = 0; i < state.size(); ++i) {
    std::vector<double> bad = state;
    bad[i] = -1.0;
    GyroChangeDetector r;
    EXPECT_EQ(r.RestoreState(bad).code(), absl::StatusCode::kDataLoss) << "value " << i;
  }
  std::vector<double> truncated(state.begin(), state.end() - 1);
  EXPECT_EQ(GyroChangeDetector().RestoreState(truncated).code(), absl::StatusCode::kDataLoss);
}

// A NIS that is negative or NaN (a covariance that is not positive definite, as a corrupt but
// accepted checkpoint can leave) is no chi-square value: its window decides nothing, the state
// stays within what a restore accepts, and +inf (a real, huge difference) still counts at the cap.
TEST(GyroChangeDetector, ANegativeOrNaNValueDecidesNothingAndItsStateRestores) {
  GyroChangeDetector d;
  EXPECT_FALSE(d.Add(kIds, {0.5, -0.0058, 100}, false).has_value());
  for (int s = 0; s < 8; ++s) EXPECT_FALSE(d.Add(kIds, {0.5, 0.5, 100}, false).has_value());
  EXPECT_FALSE(d.Add(kIds, {0.5, 0.5, 100}, false).has_value()) << "the window holds the value";
  GyroChangeDetector restored;
  EXPECT_TRUE(restored.RestoreState(d.ExportState()).ok());
  // Once the undecided step has left the window, the same evidence names gyro 3.
  EXPECT_TRUE(d.Add(kIds, {0.5, 0.5, 100}, false).has_value());

  GyroChangeDetector e;
  EXPECT_FALSE(e.Add(kIds, {std::nan(""), 0.5, 100}, false).has_value());
  EXPECT_TRUE(GyroChangeDetector().RestoreState(e.ExportState()).ok());
  for (int s = 0; s < 9; ++s) EXPECT_FALSE(e.Add(kIds, {0.5, 0.5, 100}, false).has_value());
  const auto named = e.Add(kIds, {0.5, 0.5, std::numeric_limits<double>::infinity()}, false);
  ASSERT_TRUE(named.has_value());
  EXPECT_EQ(named->gyro_id, 3);
}

}  // namespace
}  // namespace esg::estimator
