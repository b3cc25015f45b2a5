// ReadingFaultMonitor (estimator/reading_fault_monitor.h): tracks built the way the session
// builds them (a prior residual per step, the posterior after an update that absorbs part of it),
// with white noise of the stated covariance, and the verdicts each hypothesis must give. Drifts
// the model lacks (constant, cycling, wandering, a change below the limit) must give none; a
// reading jump, a reading frozen while the spacecraft turns, erratic readings and a drift change
// beyond the limit must give theirs.
#include "estimator/reading_fault_monitor.h"

#include <cmath>
#include <functional>
#include <optional>
#include <random>
#include <vector>

#include "estimator/units.h"
#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector2d;
using Eigen::Vector3d;
using Source = ReadingFaultMonitor::Source;

constexpr double kStep = 60.0;                          // [s]
const double kLimit = DegPerHourToRadPerSec(1.0);       // the default drift-change limit
const double kNoise = 5.0 * kRadPerArcsec;              // rebuild noise per axis, 1-sigma

// One gyro's spin axis along z: the tangent plane is x-y. The truth moves at rate(t) (the part
// the model lacks, [rad/s] in x, y); the reading adds offset(t) (a reading fault) and noise.
// Each step the "filter" absorbs a fraction of the prior residual into its estimate, as an
// update would, which the track must see through.
struct Truth {
  std::function<Vector2d(double)> rate = [](double) { return Vector2d::Zero(); };
  std::function<Vector2d(double)> offset = [](double) { return Vector2d::Zero(); };
  double noise_scale = 1.0;
  double turn = 0.0;  // the reading's turn per step [rad]
  // The turn over the step ending at t [rad], when it varies (a slew); else `turn`.
  std::function<double(double)> turn_at;
  // The turn over the step ending at t as a rotation vector in inertial axes [rad], when the
  // session knows its axis; its norm is the turn.
  std::function<Vector3d(double)> turn_in_at;
};

struct Outcome {
  std::vector<std::pair<int, ReadingVerdict>> verdicts;  // step, verdict
  std::optional<ReadingFaultMonitor::DriftChange> last_change;
};

Outcome Simulate(const Truth& run, int steps, unsigned seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal;
  ReadingFaultMonitor monitor;
  Eigen::Matrix<double, 3, 2> T = Eigen::Matrix<double, 3, 2>::Zero();
  T(0, 0) = 1.0;
  T(1, 1) = 1.0;
  const Matrix3d N = kNoise * kNoise * T * T.transpose();
  Vector2d truth = Vector2d::Zero(), estimate = Vector2d::Zero();
  const absl::Time t0 = absl::FromUnixSeconds(1551398400);
  Outcome out;
  for (int k = 1; k <= steps; ++k) {
    const double t = k * kStep;
    // The truth integrates the rate over the step (midpoint).
    truth += run.rate(t - kStep / 2) * kStep;
    const Vector2d noise(normal(rng), normal(rng));
    const Vector2d rebuilt = truth + run.offset(t) + run.noise_scale * kNoise * noise;
    const Vector2d prior = rebuilt - estimate;
    ReadingFaultMonitor::Sample s;
    s.gyro_id = 2;
    s.T = T;
    s.prior_residual_in = T * prior;
    s.noise_in = N;
    s.drift_bound = kLimit;
    s.turn = run.turn_at ? run.turn_at(t) : run.turn;
    if (run.turn_in_at) {
      s.turn_in = run.turn_in_at(t);
      s.turn_in_known = true;
      s.turn = s.turn_in.norm();
    }
    for (const auto& r : monitor.AddStep(t0 + absl::Seconds(t), {s})) {
      if (r.verdict != ReadingVerdict::kNone) out.verdicts.emplace_back(k, r.verdict);
    }
    estimate += 0.3 * prior;  // the update's correction
    monitor.SetPosterior(2, Source::kStarTracker, T * (rebuilt - estimate));
  }
  out.last_change = monitor.EstimateDriftChange(2, Source::kStarTracker);
  return out;
}

Vector2d DegH(double x, double y) {
  return Vector2d(DegPerHourToRadPerSec(x), DegPerHourToRadPerSec(y));
}

TEST(ReadingFaultMonitor, DriftsTheModelLacksGiveNoVerdict) {
  const std::vector<std::pair<const char*, Truth>> drifts = {
      {"constant 0.15 deg/h", Truth{[](double) { return DegH(0.15, -0.1); }}},
      {"growing to 0.3 deg/h over 10 h",
       Truth{[](double t) { return DegH(0.3 * t / 36000.0, 0.0); }}},
      {"cycling 0.15 deg/h at a 90 min period",
       Truth{[](double t) {
         const double w = 2.0 * M_PI / 5400.0;
         return DegH(0.15 * std::sin(w * t), 0.15 * std::cos(w * t));
       }}},
      {"step of 0.9 deg/h (below the limit) at 5 h",
       Truth{[](double t) { return t < 18000.0 ? DegH(0.05, 0.0) : DegH(0.05, 0.9); }}},
      {"constant 0.1 deg/h, reading turning 6 deg a step", Truth{[](double) { return DegH(0.1, 0.1); },
                                                                [](double) { return Vector2d::Zero().eval(); },
                                                                1.0, 6.0 * kRadPerDeg}},
  };
  for (const auto& [name, run] : drifts) {
    for (unsigned seed = 1; seed <= 10; ++seed) {
      const Outcome o = Simulate(run, 600, seed);
      EXPECT_TRUE(o.verdicts.empty())
          << name << ", seed " << seed << ": verdict " << ReadingVerdictName(o.verdicts[0].second)
          << " at step " << o.verdicts[0].first;
    }
  }
}

TEST(ReadingFaultMonitor, AWanderingDriftGivesNoVerdict) {
  // A random walk of 0.01 deg/h/sqrt(h) on top of a 0.1 deg/h drift, fixed per seed.
  for (unsigned seed = 1; seed <= 10; ++seed) {
    std::mt19937_64 rng(1000 + seed);
    std::normal_distribution<double> normal;
    std::vector<Vector2d> walk(700, DegH(0.1, 0.0));
    const double q = DegPerHourToRadPerSec(0.01) / 60.0 * std::sqrt(kStep);  // per step
    for (size_t k = 1; k < walk.size(); ++k) walk[k] = walk[k - 1] + q * Vector2d(normal(rng), normal(rng));
    Truth run;
    run.rate = [walk](double t) { return walk[static_cast<size_t>(t / kStep)]; };
    const Outcome o = Simulate(run, 600, seed);
    EXPECT_TRUE(o.verdicts.empty()) << "seed " << seed;
  }
}

TEST(ReadingFaultMonitor, AReadingJumpIsAJumpByTheSecondStep) {
  for (unsigned seed = 1; seed <= 10; ++seed) {
    Truth run;
    run.rate = [](double) { return DegH(0.1, 0.05); };
    // 2 arcmin at 5 h - 30 s (between steps 299 and 300).
    run.offset = [](double t) {
      return t >= 17970.0 ? Vector2d(120.0 * kRadPerArcsec, 0.0) : Vector2d::Zero();
    };
    const Outcome o = Simulate(run, 320, seed);
    ASSERT_FALSE(o.verdicts.empty()) << "seed " << seed;
    EXPECT_GE(o.verdicts[0].first, 300) << "seed " << seed;
    EXPECT_LE(o.verdicts[0].first, 301) << "seed " << seed;
  }
}

TEST(ReadingFaultMonitor, ADisplacementDuringAFastSlewIsNoJump) {
  // The reading turns 3.6 rad (3.5 deg/s) over the step to 300: a slow reading error of up to
  // 2 arcmin (kSlowReadingErrorRad) moves the rebuild by up to 4 arcmin then. A displacement of
  // 140 arcsec in that step is no verdict; the same displacement where the reading turns 0.1 rad
  // over the step (6 deg/min) is a jump by the second step.
  for (const double turn : {3.6, 0.1}) {
    for (unsigned seed = 1; seed <= 10; ++seed) {
      Truth run;
      run.rate = [](double) { return DegH(0.1, 0.05); };
      run.offset = [](double t) {
        return t >= 17970.0 ? Vector2d(100.0 * kRadPerArcsec, 100.0 * kRadPerArcsec)
                            : Vector2d::Zero();
      };
      run.turn_at = [turn](double t) { return std::abs(t - 18000.0) < 1.0 ? turn : 0.0; };
      const Outcome o = Simulate(run, 320, seed);
      if (turn > 2.0) {
        EXPECT_TRUE(o.verdicts.empty())
            << "seed " << seed << ": verdict " << ReadingVerdictName(o.verdicts[0].second)
            << " at step " << o.verdicts[0].first;
      } else {
        ASSERT_FALSE(o.verdicts.empty()) << "seed " << seed;
        EXPECT_GE(o.verdicts[0].first, 300) << "seed " << seed;
        EXPECT_LE(o.verdicts[0].first, 301) << "seed " << seed;
      }
    }
  }
}

TEST(ReadingFaultMonitor, AJumpOfArcminutesIsBeyondAnyDriftAtOnce) {
  for (unsigned seed = 1; seed <= 10; ++seed) {
    Truth run;
    run.offset = [](double t) {
      return t >= 17970.0 ? Vector2d(0.0, -300.0 * kRadPerArcsec) : Vector2d::Zero();
    };
    const Outcome o = Simulate(run, 320, seed);
    ASSERT_FALSE(o.verdicts.empty()) << "seed " << seed;
    EXPECT_EQ(o.verdicts[0].first, 300) << "seed " << seed;
    EXPECT_EQ(o.verdicts[0].second, ReadingVerdict::kBeyond) << "seed " << seed;
  }
}

TEST(ReadingFaultMonitor, AReadingFrozenWhileTheSpacecraftTurnsIsBeyondAnyDrift) {
  // Frozen at step 300: from then on the reading stays while the truth turns with the body
  // (6 deg per step, the calibration profile's rotation), so the rebuild runs away.
  Truth run;
  run.turn = 6.0 * kRadPerDeg;
  run.offset = [](double t) {
    return t >= 18000.0 ? Vector2d((t - 17970.0) / kStep * 6.0 * kRadPerDeg, 0.0)
                        : Vector2d::Zero();
  };
  const Outcome o = Simulate(run, 305, 3);
  ASSERT_FALSE(o.verdicts.empty());
  EXPECT_EQ(o.verdicts[0].first, 300);
  EXPECT_EQ(o.verdicts[0].second, ReadingVerdict::kBeyond);
}

TEST(ReadingFaultMonitor, ReadingsTenTimesNoisierAreErratic) {
  Truth run;
  run.rate = [](double) { return DegH(0.1, 0.0); };
  run.noise_scale = 10.0;
  const Outcome o = Simulate(run, 60, 4);
  ASSERT_FALSE(o.verdicts.empty());
  bool erratic = false;
  for (const auto& [step, v] : o.verdicts) erratic |= v == ReadingVerdict::kErratic;
  EXPECT_TRUE(erratic);
}

TEST(ReadingFaultMonitor, ADriftChangeIsMeasuredAndJudgedAgainstTheLimit) {
  // Changes at step 300; the window at step 312 holds the onset. The filter's absorption
  // (estimate += 0.3 prior) does not enter the track.
  for (const auto& [change_deg_h, beyond] : {std::pair{0.9, false}, std::pair{1.2, true}}) {
    for (unsigned seed = 1; seed <= 5; ++seed) {
      Truth run;
      const double c = change_deg_h;
      run.rate = [c](double t) { return t < 17970.0 ? DegH(0.05, 0.0) : DegH(0.05, c); };
      const Outcome o = Simulate(run, 312, seed);
      ASSERT_TRUE(o.last_change.has_value());
      EXPECT_NEAR(RadPerSecToDegPerHour(o.last_change->magnitude), change_deg_h, 0.1)
          << change_deg_h << " deg/h, seed " << seed;
      EXPECT_EQ(o.last_change->beyond, beyond) << change_deg_h << " deg/h, seed " << seed
                                               << ": chi-square "
                                               << o.last_change->beyond_chi2;
    }
  }
}

TEST(ReadingFaultMonitor, ARateChangeWhereTheTurnStopsMayBeASlowReadingError) {
  // The reading turns 6 deg a step (0.1 deg/s, the paper's calibration profile) until step 300
  // and then holds. A case misalignment of 1 arcmin moves the rebuild by 1 arcmin per radian of
  // turn: a rate error of 0.105 deg/h while it turns, none after, so the rate "changes" by 0.105
  // deg/h at the stop. A slow reading error of up to 2 arcmin (kSlowReadingErrorRad) gives up to
  // 0.21 deg/h there: the change may be one. A drift step of 0.6 deg/h at the same stop, or of
  // 0.2 deg/h while the turn goes on unchanged, is larger than such an error can give there.
  const double turn_step = 6.0 * kRadPerDeg;
  const double stop = 300 * kStep;
  auto turn_at = [=](double t) { return t <= stop ? turn_step : 0.0; };
  const double misalignment_rad = 60.0 * kRadPerArcsec;
  struct Case {
    const char* name;
    Truth run;
    bool may_be;
  };
  std::vector<Case> cases;
  {
    Truth run;
    run.turn_at = turn_at;
    run.offset = [=](double t) {
      return Vector2d(misalignment_rad * turn_step * std::min(t, stop) / kStep, 0.0);
    };
    cases.push_back({"1 arcmin misalignment, the turn stops", run, true});
  }
  {
    Truth run;
    run.turn_at = turn_at;
    run.rate = [=](double t) { return t < stop ? DegH(0.0, 0.0) : DegH(0.0, 0.6); };
    cases.push_back({"drift step 0.6 deg/h where the turn stops", run, false});
  }
  {
    Truth run;
    run.turn = turn_step;
    run.rate = [=](double t) { return t < stop ? DegH(0.0, 0.0) : DegH(0.0, 0.2); };
    cases.push_back({"drift step 0.2 deg/h, the turn unchanged", run, false});
  }
  for (const Case& c : cases) {
    for (unsigned seed = 1; seed <= 5; ++seed) {
      const Outcome o = Simulate(c.run, 312, seed);
      ASSERT_TRUE(o.last_change.has_value()) << c.name;
      const auto& d = *o.last_change;
      EXPECT_EQ(d.may_be_slow_reading_error, c.may_be)
          << c.name << ", seed " << seed << ": change " << RadPerSecToDegPerHour(d.magnitude)
          << " deg/h, a slow reading error gives up to "
          << RadPerSecToDegPerHour(d.slow_reading_change) << " deg/h";
      if (c.run.turn_at) {
        // The onset is estimated within a few steps of the stop (a change of 0.1 deg/h is a few
        // arcsec a step against 5 arcsec of noise): mostly turning before it, mostly at rest
        // after it.
        EXPECT_GT(RadToDeg(d.turn_rate_before), 0.06) << c.name << ", seed " << seed;
        EXPECT_LE(RadToDeg(d.turn_rate_before), 0.1 + 1e-12) << c.name << ", seed " << seed;
        EXPECT_LT(RadToDeg(d.turn_rate_after), 0.04) << c.name << ", seed " << seed;
      } else {
        EXPECT_NEAR(RadToDeg(d.turn_rate_after), 0.1, 1e-9) << c.name << ", seed " << seed;
        EXPECT_LT(RadPerSecToDegPerHour(d.slow_reading_change), 1e-9) << c.name << ", seed " << seed;
      }
    }
  }
}

TEST(ReadingFaultMonitor, ATurnAboutANewAxisAtTheSameRateMayBeASlowReadingError) {
  // The spacecraft turns 6 deg a step about inertial x until step 300, then at the same rate
  // about y. A case misalignment delta (1 arcmin, along the spin axis z here) moves the rebuild
  // at (w x delta) x h: (-w eps, 0) while turning about x, (0, -w eps) about y, so the rate
  // "changes" by sqrt(2) 0.105 deg/h with the scalar turn rate unchanged. The turn's axis tells
  // it: a slow reading error of up to 2 arcmin gives up to 2 arcmin |w_after - w_before| = 0.30
  // deg/h there. A drift step of 0.6 deg/h at the same change is larger than that.
  const double w_step = 6.0 * kRadPerDeg;  // [rad per step]
  const double change = 300 * kStep;
  auto turn_in_at = [=](double t) {
    return t <= change ? Vector3d(w_step, 0.0, 0.0) : Vector3d(0.0, w_step, 0.0);
  };
  const double eps = 60.0 * kRadPerArcsec;
  auto misaligned = [=](double t) {
    const double before = std::min(t, change) / kStep, after = std::max(t - change, 0.0) / kStep;
    return Vector2d(-eps * w_step * before, -eps * w_step * after);
  };
  struct Case {
    const char* name;
    Truth run;
    bool may_be;
  };
  std::vector<Case> cases;
  {
    Truth run;
    run.turn_in_at = turn_in_at;
    run.offset = misaligned;
    cases.push_back({"1 arcmin misalignment, the turn's axis turns by 90 deg", run, true});
  }
  {
    Truth run;
    run.turn_in_at = turn_in_at;
    run.rate = [=](double t) { return t < change ? DegH(0.0, 0.0) : DegH(0.6, 0.0); };
    cases.push_back({"drift step 0.6 deg/h where the turn's axis turns", run, false});
  }
  for (const Case& c : cases) {
    for (unsigned seed = 1; seed <= 5; ++seed) {
      const Outcome o = Simulate(c.run, 312, seed);
      ASSERT_TRUE(o.last_change.has_value()) << c.name;
      const auto& d = *o.last_change;
      EXPECT_EQ(d.may_be_slow_reading_error, c.may_be)
          << c.name << ", seed " << seed << ": change " << RadPerSecToDegPerHour(d.magnitude)
          << " deg/h, a slow reading error gives up to "
          << RadPerSecToDegPerHour(d.slow_reading_change) << " deg/h";
      // The scalar rate is the same on both sides. The axes are 90 deg apart, less where the
      // estimated onset is a step or two off the change and one side's mean mixes both turns.
      EXPECT_NEAR(RadToDeg(d.turn_rate_before), 0.1, 1e-9) << c.name << ", seed " << seed;
      EXPECT_NEAR(RadToDeg(d.turn_rate_after), 0.1, 1e-9) << c.name << ", seed " << seed;
      EXPECT_GT(RadToDeg(d.turn_axis_change), 60.0) << c.name << ", seed " << seed;
      EXPECT_LE(RadToDeg(d.turn_axis_change), 90.0 + 1e-9) << c.name << ", seed " << seed;
      const double full = kSlowReadingErrorRad * std::sqrt(2.0) * w_step / kStep;
      EXPECT_GT(d.slow_reading_change, 0.8 * full) << c.name << ", seed " << seed;
      EXPECT_LE(d.slow_reading_change, full * (1.0 + 1e-12)) << c.name << ", seed " << seed;
    }
  }
}

TEST(ReadingFaultMonitor, AVerdictTwoGyrosShareOnTheStarTrackerIsNobodys) {
  ReadingFaultMonitor monitor;
  Eigen::Matrix<double, 3, 2> T = Eigen::Matrix<double, 3, 2>::Zero();
  T(0, 0) = T(1, 1) = 1.0;
  const absl::Time t0 = absl::FromUnixSeconds(1551398400);
  for (int k = 1; k <= 12; ++k) {
    std::vector<ReadingFaultMonitor::Sample> samples;
    for (int id : {1, 2, 3}) {
      ReadingFaultMonitor::Sample s;
      s.gyro_id = id;
      s.T = T;
      // A star-tracker error of 5 arcmin from step 11 on rotates gyros 1 and 2's rebuilds.
      const double jump = k >= 11 && id != 3 ? 300.0 * kRadPerArcsec : 0.0;
      s.prior_residual_in = Vector3d(jump, 0.0, 0.0);
      s.noise_in = kNoise * kNoise * T * T.transpose();
      s.drift_bound = kLimit;
      samples.push_back(s);
    }
    for (const auto& r : monitor.AddStep(t0 + absl::Seconds(60 * k), samples)) {
      EXPECT_EQ(r.verdict, ReadingVerdict::kNone) << "step " << k << " gyro " << r.gyro_id;
    }
    for (const auto& s : samples) monitor.SetPosterior(s.gyro_id, Source::kStarTracker, s.prior_residual_in);
  }
}

TEST(ReadingFaultMonitor, StateRoundTripsAndRefusesWhatDoesNotFit) {
  Truth run;
  run.rate = [](double) { return DegH(0.1, 0.0); };
  ReadingFaultMonitor a;
  Eigen::Matrix<double, 3, 2> T = Eigen::Matrix<double, 3, 2>::Zero();
  T(0, 0) = T(1, 1) = 1.0;
  const absl::Time t0 = absl::FromUnixSeconds(1551398400);
  for (int k = 1; k <= 5; ++k) {
    ReadingFaultMonitor::Sample s;
    s.gyro_id = 1;
    s.T = T;
    s.prior_residual_in = Vector3d(k * 1e-6, 0.0, 0.0);
    s.noise_in = kNoise * kNoise * T * T.transpose();
    s.drift_bound = kLimit;
    a.AddStep(t0 + absl::Seconds(60 * k), {s});
    a.SetPosterior(1, Source::kStarTracker, Vector3d::Zero());
  }
  const std::vector<double> state = a.ExportState();
  ReadingFaultMonitor b;
  ASSERT_TRUE(b.RestoreState(state).ok());
  EXPECT_EQ(b.ExportState(), state);
  std::vector<double> truncated(state.begin(), state.end() - 1);
  EXPECT_EQ(b.RestoreState(truncated).code(), absl::StatusCode::kDataLoss);
  std::vector<double> nan = state;
  nan.back() = std::nan("");
  EXPECT_EQ(b.RestoreState(nan).code(), absl::StatusCode::kDataLoss);
  EXPECT_EQ(b.ExportState(), state);  // unchanged by the refusals
}

TEST(ReadingFaultMonitor, TurnAxesRoundTripAndRefuseWhatDoesNotFit) {
  ReadingFaultMonitor a;
  Eigen::Matrix<double, 3, 2> T = Eigen::Matrix<double, 3, 2>::Zero();
  T(0, 0) = T(1, 1) = 1.0;
  const absl::Time t0 = absl::FromUnixSeconds(1551398400);
  for (int k = 1; k <= 5; ++k) {
    ReadingFaultMonitor::Sample s;
    s.gyro_id = 1;
    s.T = T;
    s.prior_residual_in = Vector3d(k * 1e-6, 0.0, 0.0);
    s.noise_in = kNoise * kNoise * T * T.transpose();
    s.drift_bound = kLimit;
    s.turn_in = Vector3d(0.01 * k, -0.02, 0.0);
    s.turn = s.turn_in.norm();
    s.turn_in_known = k != 3;
    a.AddStep(t0 + absl::Seconds(60 * k), {s});
    a.SetPosterior(1, Source::kStarTracker, Vector3d::Zero());
  }
  const std::vector<double> axes = a.ExportTurnAxes();
  ASSERT_EQ(axes.size(), 5u * 4u);
  EXPECT_EQ(axes[2 * 4 + 3], 0.0);  // the third point's axis unknown
  EXPECT_EQ(axes[4 * 4 + 0], 0.05);
  ReadingFaultMonitor b;
  ASSERT_TRUE(b.RestoreState(a.ExportState()).ok());
  // Restored without the axes (a checkpoint before version 9): every point's axis unknown.
  for (size_t k = 0; k < 5; ++k) EXPECT_EQ(b.ExportTurnAxes()[4 * k + 3], 0.0);
  ASSERT_TRUE(b.RestoreTurnAxes(axes).ok());
  EXPECT_EQ(b.ExportTurnAxes(), axes);
  std::vector<double> short_axes(axes.begin(), axes.end() - 4);
  EXPECT_EQ(b.RestoreTurnAxes(short_axes).code(), absl::StatusCode::kDataLoss);
  std::vector<double> bad_flag = axes;
  bad_flag[3] = 0.5;
  EXPECT_EQ(b.RestoreTurnAxes(bad_flag).code(), absl::StatusCode::kDataLoss);
  std::vector<double> nan = axes;
  nan[0] = std::nan("");
  EXPECT_EQ(b.RestoreTurnAxes(nan).code(), absl::StatusCode::kDataLoss);
  EXPECT_EQ(b.ExportTurnAxes(), axes);  // unchanged by the refusals
}

}  // namespace
}  // namespace esg::estimator
