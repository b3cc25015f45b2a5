// The bounded adaptive process noise (estimator/noise_widening.h): its tests against chi-square
// data with known statistics, its bounds, and its checkpoint state.
#include "estimator/noise_widening.h"

#include <random>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

using ::testing::HasSubstr;

NoiseWideningOptions NoWarmup() {
  NoiseWideningOptions o;
  o.warmup_steps = 0;
  return o;
}

// Feeds `steps` steps of NIS = scale x chi-square(dof) with innovation variance `variance`;
// returns the decisions.
std::vector<NoiseWidening::Decision> Feed(NoiseWidening& w, std::mt19937_64& rng, int steps,
                                          int dof, double scale, double variance) {
  std::chi_squared_distribution<double> chi2(dof);
  std::vector<NoiseWidening::Decision> out;
  for (int k = 0; k < steps; ++k) {
    if (auto d = w.Add(scale * chi2(rng), dof, variance)) out.push_back(*d);
  }
  return out;
}

TEST(NoiseWidening, ConsistentInnovationsNeverWiden) {
  // 2000 windows of 30 steps of chi-square(6): P(two consecutive windows above the 1 - 1e-3
  // quantile) = 1e-6 per window, so a widening here has probability < 2e-3.
  NoiseWidening w(60.0, NoWarmup());
  std::mt19937_64 rng(11);
  const auto decisions = Feed(w, rng, 2000 * 30, 6, 1.0, 1e-9);
  ASSERT_EQ(decisions.size(), 2000u);
  int exceeded = 0;
  for (const auto& d : decisions) {
    EXPECT_EQ(d.change, NoiseWidening::Decision::Change::kNone);
    exceeded += d.nis_sum > d.widen_threshold ? 1 : 0;
  }
  EXPECT_FALSE(w.widened());
  // Single windows above the quantile happen at about its level (binomial(2000, 1e-3): mean 2).
  EXPECT_LE(exceeded, 9);
}

TEST(NoiseWidening, PersistentExcessWidensByTheMomentEstimateAfterTwoWindows) {
  NoiseWidening w(60.0, NoWarmup());
  std::mt19937_64 rng(12);
  const double variance = 1e-9;
  // NIS twice what the filter's S allows: the first window only marks the excess.
  auto first = Feed(w, rng, 30, 6, 2.0, variance);
  ASSERT_EQ(first.size(), 1u);
  EXPECT_GT(first[0].nis_sum, first[0].widen_threshold);
  EXPECT_EQ(first[0].change, NoiseWidening::Decision::Change::kNone);
  EXPECT_FALSE(w.widened());
  auto second = Feed(w, rng, 30, 6, 2.0, variance);
  ASSERT_EQ(second.size(), 1u);
  EXPECT_EQ(second[0].change, NoiseWidening::Decision::Change::kWidened);
  // v = (X / D - 1) x variance, X / D about 2 (sd of X / D: sqrt(2 / 180) x 2 = 0.21).
  EXPECT_NEAR(w.added_variance() / variance, second[0].nis_sum / second[0].dof - 1.0, 1e-12);
  EXPECT_NEAR(w.added_variance() / variance, 1.0, 0.7);
  ASSERT_TRUE(w.trigger().has_value());
  EXPECT_EQ(w.trigger()->nis_sum, second[0].nis_sum);
}

TEST(NoiseWidening, AnOutlierBurstInOneWindowDoesNotWiden) {
  NoiseWidening w(60.0, NoWarmup());
  std::mt19937_64 rng(13);
  // Five huge NIS (outliers) in the middle of otherwise consistent data: each enters capped at
  // chi2inv(0.999, 6) = 22.5 and the excess is confined to one window.
  Feed(w, rng, 40, 6, 1.0, 1e-9);
  for (int k = 0; k < 5; ++k) w.Add(1e6, 6, 1e-9);
  const auto decisions = Feed(w, rng, 200, 6, 1.0, 1e-9);
  for (const auto& d : decisions) EXPECT_NE(d.change, NoiseWidening::Decision::Change::kWidened);
  EXPECT_FALSE(w.widened());
}

TEST(NoiseWidening, IsBoundedAndNarrowsByHalvesWhenTheCovarianceIsTooLarge) {
  NoiseWideningOptions o = NoWarmup();
  o.max_drift_deg_h = 0.01;
  NoiseWidening w(60.0, o);
  std::mt19937_64 rng(14);
  // A gross excess pushes v to its bound: (0.01 deg/h x 60 s)^2.
  Feed(w, rng, 30 * 6, 6, 100.0, 1e-8);
  EXPECT_TRUE(w.at_max());
  EXPECT_NEAR(w.EquivalentDriftDegH(), 0.01, 1e-12);
  const double v_max = w.added_variance();
  // Innovations far below S: each window halves v.
  auto d = Feed(w, rng, 30, 6, 0.3, 1e-8);
  ASSERT_EQ(d.size(), 1u);
  EXPECT_EQ(d[0].change, NoiseWidening::Decision::Change::kNarrowed);
  EXPECT_DOUBLE_EQ(w.added_variance(), v_max / 2.0);
  Feed(w, rng, 30 * 60, 6, 0.3, 1e-8);
  EXPECT_FALSE(w.widened());
  EXPECT_FALSE(w.trigger().has_value());
}

TEST(NoiseWidening, WarmupStepsDoNotEnter) {
  NoiseWidening w(60.0);  // default warm-up of 60 steps
  std::mt19937_64 rng(15);
  EXPECT_TRUE(Feed(w, rng, 60, 6, 100.0, 1e-9).empty());
  EXPECT_EQ(Feed(w, rng, 30, 6, 1.0, 1e-9).size(), 1u);
}

TEST(NoiseWidening, StateRoundTripsAndCorruptStateIsDataLoss) {
  NoiseWidening w(60.0, NoWarmup());
  std::mt19937_64 rng(16);
  Feed(w, rng, 30 * 2 + 7, 6, 3.0, 1e-9);  // widened, 7 steps into a window
  ASSERT_TRUE(w.widened());
  const std::vector<double> state = w.ExportState();
  NoiseWidening r(60.0, NoWarmup());
  ASSERT_TRUE(r.RestoreState(state).ok());
  EXPECT_EQ(r.ExportState(), state);
  // Both continue identically.
  std::mt19937_64 rng_a(17), rng_b(17);
  const auto da = Feed(w, rng_a, 100, 6, 1.5, 1e-9);
  const auto db = Feed(r, rng_b, 100, 6, 1.5, 1e-9);
  ASSERT_EQ(da.size(), db.size());
  for (size_t i = 0; i < da.size(); ++i) EXPECT_EQ(da[i].added_variance, db[i].added_variance);

  auto corrupt = [&](size_t index, double value) {
    std::vector<double> bad = state;
    bad[index] = value;
    NoiseWidening x(60.0, NoWarmup());
    return x.RestoreState(bad);
  };
  EXPECT_THAT(corrupt(0, -1.0).message(), HasSubstr("added variance"));
  EXPECT_THAT(corrupt(2, 0.5).message(), HasSubstr("previous-window flag"));
  EXPECT_THAT(corrupt(3, 2.0).message(), HasSubstr("trigger flag"));
  EXPECT_THAT(corrupt(8, 31.0).message(), HasSubstr("window length"));
  EXPECT_THAT(corrupt(10, 9.0).message(), HasSubstr("window step 0"));
  std::vector<double> truncated(state.begin(), state.end() - 1);
  NoiseWidening keep(60.0, NoWarmup());
  ASSERT_TRUE(keep.RestoreState(state).ok());
  EXPECT_EQ(keep.RestoreState(truncated).code(), absl::StatusCode::kDataLoss);
  EXPECT_EQ(keep.ExportState(), state) << "a refused state leaves the object unchanged";
}

}  // namespace
}  // namespace esg::estimator
