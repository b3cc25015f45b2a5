// The regressors of channel basis terms (estimator/channel_signal.h): the held value, the exact
// first-order lag of the held series and its derivative, the age rule, and the state a checkpoint
// carries.
#include "estimator/channel_signal.h"

#include <cmath>

#include "estimator/basis_term.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;

const absl::Time kT0 = absl::FromUnixSeconds(1551398400);

ChannelConfig Declared(absl::Duration max_age) {
  ChannelConfig c;
  c.name = "T_gyro2";
  c.unit = "K";
  c.valid_min = 250;
  c.valid_max = 350;
  c.max_age = max_age;
  return c;
}

BasisTerm Term(ChannelForm form, double tau_s = 0.0, double reference = 0.0) {
  BasisTerm t;
  t.kind = BasisKind::kChannel;
  t.channel = "T_gyro2";
  t.form = form;
  t.time_constant = tau_s;
  t.reference = reference;
  return t;
}

TelemetryFrame Frame(double seconds, std::optional<double> temperature) {
  TelemetryFrame f;
  f.time = kT0 + absl::Seconds(seconds);
  if (temperature) f.channels.Set("T_gyro2", *temperature);
  return f;
}

TEST(ChannelSignals, ValueIsHeldFromItsFrameUntilTheNextAndLessTheReference) {
  const BasisTerm value = Term(ChannelForm::kValue, 0.0, 290.0);
  ChannelSignals s({Declared(absl::Minutes(10))}, {value});
  EXPECT_EQ(s.Scalar(value, kT0), 0.0);  // no value yet
  s.Advance(Frame(0, 295.0));
  EXPECT_EQ(s.Scalar(value, kT0 + absl::Seconds(30)), 5.0);
  s.Advance(Frame(60, std::nullopt));  // held: the frame lacks it, its age 60 s
  EXPECT_EQ(s.Scalar(value, kT0 + absl::Seconds(90)), 5.0);
  // Older than its 10 min maxAgeS: no value, s = 0.
  EXPECT_EQ(s.Scalar(value, kT0 + absl::Seconds(601)), 0.0);
}

// A step of the channel from 0 to 1 at t = 0 after an equilibrium at 0: the lag is the first-order
// response 1 - exp(-t / tau) at every instant, between and across frames.
TEST(ChannelSignals, LagOfAStepIsTheFirstOrderResponseAndItsDerivativeTheLagsSlope) {
  const double tau = 1800.0;
  const BasisTerm lag = Term(ChannelForm::kLag, tau);
  const BasisTerm rate = Term(ChannelForm::kDerivative, tau);
  ChannelSignals s({Declared(absl::Hours(1))}, {lag, rate});
  s.Advance(Frame(-60, 0.0));  // equilibrium at 0
  s.Advance(Frame(0, 1.0));
  for (double t : {30.0, 60.0, 600.0, 3000.0}) {
    if (t > 60.0) s.Advance(Frame(t - 30.0, std::nullopt));
    EXPECT_NEAR(s.Scalar(lag, kT0 + absl::Seconds(t)), 1.0 - std::exp(-t / tau), 1e-12) << t;
    // dy/dt = (x - y) / tau, per hour.
    EXPECT_NEAR(s.Scalar(rate, kT0 + absl::Seconds(t)),
                std::exp(-t / tau) / tau * kSecondsPerHour, 1e-12)
        << t;
  }
}

// With the next frame known (Ahead), the value between two frames is on the line between their
// values; without it (a prediction past the last frame) it is held; a line longer than maxAgeS is
// not drawn.
TEST(ChannelSignals, ValueBetweenFramesIsOnTheLineToTheNextFrameWhenItIsKnown) {
  const BasisTerm value = Term(ChannelForm::kValue, 0.0, 290.0);
  ChannelSignals s({Declared(absl::Minutes(10))}, {value});
  s.Advance(Frame(0, 295.0));
  s.Ahead(Frame(60, 298.0));
  EXPECT_NEAR(s.Scalar(value, kT0 + absl::Seconds(20)), 6.0, 1e-12);
  EXPECT_NEAR(s.Scalar(value, kT0 + absl::Seconds(60)), 8.0, 1e-12);
  s.Advance(Frame(60, 298.0));
  EXPECT_EQ(s.Scalar(value, kT0 + absl::Seconds(90)), 8.0);  // held: nothing ahead
  // The next value 11 min after the last one (maxAgeS 10 min): held, then expired.
  s.Ahead(Frame(60 + 660, 300.0));
  EXPECT_EQ(s.Scalar(value, kT0 + absl::Seconds(120)), 8.0);
  EXPECT_EQ(s.Scalar(value, kT0 + absl::Seconds(60 + 601)), 0.0);
  // A frame without the channel leaves it held.
  s.Advance(Frame(120, std::nullopt));
  s.Ahead(Frame(180, std::nullopt));
  EXPECT_EQ(s.Scalar(value, kT0 + absl::Seconds(150)), 8.0);
}

// A channel rising at r = 3 K/h sampled every 60 s: with each frame known while its interval is
// integrated, the lag is the exact response to the ramp, y = x - r tau once the start has decayed,
// and its derivative r at every instant; held, the lag trails by half a frame more and its
// derivative, at a frame, is below r (the staircase's step not yet followed).
TEST(ChannelSignals, LagOfARampSampledByFramesIsExactOnTheLineAndTrailsWhenHeld) {
  const double tau = 600.0, r_per_s = 3.0 / 3600.0;
  const BasisTerm lag = Term(ChannelForm::kLag, tau);
  const BasisTerm rate = Term(ChannelForm::kDerivative, tau);
  ChannelSignals line({Declared(absl::Minutes(5))}, {lag, rate});
  ChannelSignals held({Declared(absl::Minutes(5))}, {lag, rate});
  auto x = [&](double t) { return 290.0 + r_per_s * t; };
  // Equilibrium with the ramp at t = 0 (y = x - r tau) is reached by running from -30 tau.
  for (double t = -30 * tau; t <= 0.0; t += 60.0) {
    line.Ahead(Frame(t, x(t)));
    line.Advance(Frame(t, x(t)));
    held.Advance(Frame(t, x(t)));
  }
  for (double t = 0.0; t < 3600.0; t += 60.0) {
    line.Ahead(Frame(t + 60.0, x(t + 60.0)));
    for (double u : {15.0, 30.0, 59.0}) {
      const absl::Time at = kT0 + absl::Seconds(t + u);
      EXPECT_NEAR(line.Scalar(lag, at), x(t + u) - r_per_s * tau, 1e-9) << t + u;
      EXPECT_NEAR(line.Scalar(rate, at), 3.0, 1e-9) << t + u;
    }
    line.Advance(Frame(t + 60.0, x(t + 60.0)));
    held.Advance(Frame(t + 60.0, x(t + 60.0)));
  }
  // Held: at a frame, just after its value is taken, the lag trails the line's by about half a
  // frame of the ramp (r x 30 s = 0.025 K), and the derivative at an instant before the next
  // frame is below 3 K/h by more than 1%.
  const absl::Time end = kT0 + absl::Seconds(3600.0);
  EXPECT_NEAR(line.Scalar(lag, end) - held.Scalar(lag, end), r_per_s * 30.0, 0.005);
  EXPECT_LT(held.Scalar(rate, end + absl::Seconds(59)), 0.99 * 3.0);
}

TEST(ChannelSignals, LagStartsAtTheFirstValueAndHoldsWhenTheValueExpires) {
  const double tau = 600.0;
  const BasisTerm lag = Term(ChannelForm::kLag, tau, 10.0);
  ChannelSignals s({Declared(absl::Seconds(120))}, {lag});
  EXPECT_EQ(s.Scalar(lag, kT0), 0.0);
  s.Advance(Frame(0, 20.0));
  EXPECT_EQ(s.Scalar(lag, kT0 + absl::Seconds(50)), 10.0);  // in equilibrium: y = 20
  s.Advance(Frame(60, 30.0));
  // The value 30 held for 120 s from t = 60, then none: the lag stops at t = 180.
  const double at_180 = 30.0 + (20.0 - 30.0) * std::exp(-120.0 / tau);
  EXPECT_NEAR(s.Scalar(lag, kT0 + absl::Seconds(500)), at_180 - 10.0, 1e-12);
  s.Advance(Frame(900, std::nullopt));
  EXPECT_NEAR(s.Scalar(lag, kT0 + absl::Seconds(950)), at_180 - 10.0, 1e-12);
}

TEST(ChannelSignals, StateRestoredGivesTheSameRegressorsAndABadStateIsRefused) {
  const BasisTerm lag = Term(ChannelForm::kLag, 900.0);
  const BasisTerm value = Term(ChannelForm::kValue);
  ChannelSignals a({Declared(absl::Hours(1))}, {lag, value});
  for (int k = 0; k < 10; ++k) a.Advance(Frame(60.0 * k, 290.0 + 0.1 * k * k));
  ChannelSignals b({Declared(absl::Hours(1))}, {value, lag});
  ASSERT_THAT(b.RestoreState(a.ExportState()), IsOk());
  for (ChannelSignals* s : {&a, &b}) s->Advance(Frame(600, 301.0));
  for (double t : {610.0, 650.0}) {
    EXPECT_EQ(a.Scalar(lag, kT0 + absl::Seconds(t)), b.Scalar(lag, kT0 + absl::Seconds(t)));
    EXPECT_EQ(a.Scalar(value, kT0 + absl::Seconds(t)), b.Scalar(value, kT0 + absl::Seconds(t)));
  }
  std::vector<double> state = a.ExportState();
  state.pop_back();
  EXPECT_THAT(b.RestoreState(state), StatusIs(absl::StatusCode::kDataLoss, ::testing::HasSubstr("channel state")));
  state = a.ExportState();
  state[3] = std::nan("");
  EXPECT_THAT(b.RestoreState(state), StatusIs(absl::StatusCode::kDataLoss, ::testing::HasSubstr("channel state")));
  // Without channel terms nothing is tracked.
  EXPECT_TRUE(ChannelSignals({Declared(absl::Hours(1))}, {}).empty());
}

TEST(ChannelSignals, BasisScalarReadsTheSignalsAndGivesZeroWithoutThem) {
  const BasisTerm value = Term(ChannelForm::kValue, 0.0, 290.0);
  ChannelSignals s({Declared(absl::Hours(1))}, {value});
  s.Advance(Frame(0, 292.5));
  BasisInputs in;
  in.time = kT0 + absl::Seconds(10);
  EXPECT_EQ(BasisScalar(value, in), 0.0);
  in.channels = &s;
  EXPECT_EQ(BasisScalar(value, in), 2.5);
  EXPECT_EQ(BasisTermLabel(value), "T_gyro2 -> x");
  EXPECT_EQ(BasisTermLabel(Term(ChannelForm::kLag, 2400.0)), "lag(T_gyro2, 0.667h) -> x");
}

}  // namespace
}  // namespace esg::estimator
