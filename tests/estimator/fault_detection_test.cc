// The eq. (12) fault decision (estimator/fault_detection.h) from plain values: which subsystem
// is named from the three mismatches, which gyro is excluded and which pair carries the output.
// (The mismatch formation, eq. (14) and the directional allowed angle are tested in
// session_test.cc's FaultDetection cases.)
#include "estimator/fault_detection.h"

#include <array>
#include <cmath>

#include "estimator/rotation.h"
#include "estimator/units.h"
#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

constexpr std::array<int, 2> kWorking = {1, 2};
constexpr std::array<int, 2> kReserve = {1, 3};

// A mismatch test with all three mismatches formed, allowed 60 arcsec each.
MismatchTest Mismatches(double a12_arcsec, double a13_arcsec, double a23_arcsec) {
  MismatchTest t;
  t.angle = {ArcsecToRad(a12_arcsec), ArcsecToRad(a13_arcsec), ArcsecToRad(a23_arcsec)};
  t.allowed = {ArcsecToRad(60), ArcsecToRad(60), ArcsecToRad(60)};
  t.available = {true, true, true};
  return t;
}

TEST(FaultDecision, WorkingPairFaultExcludesItsGyroOutsideTheReserveAndSwitchesTheOutput) {
  // eq. (12): dL_12 and dL_13 exceed. Pairs [1,2] and [1,3] share gyro 1: gyro 2 is excluded.
  const FaultDecision d = DecideFault(Mismatches(300, 300, 10), kWorking, kReserve);
  EXPECT_EQ(d.faulty, Subsystem::kWorkingPair);
  EXPECT_EQ(d.excluded_gyro, 2);
  EXPECT_EQ(d.output_pair, kReserve);
  EXPECT_TRUE(d.output_switched);
  EXPECT_FALSE(d.reject_star_tracker);
  EXPECT_EQ(d.evidence, kMismatch12);
}

TEST(FaultDecision, ExcludedGyroIsTheOneNotSharedWhicheverPositionItHolds) {
  // Working [1,2], reserve [2,3]: the shared gyro is the working pair's second, so gyro 1 goes.
  const FaultDecision w = DecideFault(Mismatches(300, 300, 10), {1, 2}, {2, 3});
  EXPECT_EQ(w.excluded_gyro, 1);
  EXPECT_EQ(w.output_pair, (std::array<int, 2>{2, 3}));
  // Reserve pair faulty (dL_12 and dL_23): its gyro outside the working pair.
  const FaultDecision r = DecideFault(Mismatches(300, 10, 300), kWorking, kReserve);
  EXPECT_EQ(r.faulty, Subsystem::kReservePair);
  EXPECT_EQ(r.excluded_gyro, 3);
  const FaultDecision r2 = DecideFault(Mismatches(300, 10, 300), {1, 2}, {3, 1});
  EXPECT_EQ(r2.excluded_gyro, 3);
}

TEST(FaultDecision, ReservePairFaultKeepsTheOutputOnTheWorkingPair) {
  const FaultDecision d = DecideFault(Mismatches(300, 10, 300), kWorking, kReserve);
  EXPECT_EQ(d.output_pair, kWorking);
  EXPECT_FALSE(d.output_switched);
  EXPECT_FALSE(d.reject_star_tracker);
  EXPECT_EQ(d.evidence, kMismatch12);
}

TEST(FaultDecision, StarTrackerFaultRejectsItsMeasurementsAndExcludesNoGyro) {
  const FaultDecision d = DecideFault(Mismatches(10, 300, 300), kWorking, kReserve);
  EXPECT_EQ(d.faulty, Subsystem::kStarTracker);
  EXPECT_TRUE(d.reject_star_tracker);
  EXPECT_EQ(d.excluded_gyro, 0);
  EXPECT_EQ(d.output_pair, kWorking);
  EXPECT_FALSE(d.output_switched);
  EXPECT_EQ(d.evidence, kMismatch13);
}

TEST(FaultDecision, OneExceededMismatchNamesNothing) {
  for (const MismatchTest& t : {Mismatches(300, 10, 10), Mismatches(10, 300, 10),
                                Mismatches(10, 10, 300), Mismatches(10, 10, 10)}) {
    const FaultDecision d = DecideFault(t, kWorking, kReserve);
    EXPECT_EQ(d.faulty, Subsystem::kNone);
    EXPECT_EQ(d.excluded_gyro, 0);
    EXPECT_EQ(d.output_pair, kWorking);
    EXPECT_FALSE(d.output_switched);
    EXPECT_FALSE(d.reject_star_tracker);
    EXPECT_EQ(d.evidence, -1);
  }
}

TEST(FaultDecision, AMismatchNotFormedNeverCountsAsExceeded) {
  // Without the reserve pair (dL_12 and dL_23 not formed), even huge angles name nothing.
  MismatchTest t = Mismatches(3000, 3000, 3000);
  t.available = {false, true, false};
  EXPECT_EQ(DecideFault(t, kWorking, kReserve).faulty, Subsystem::kNone);
  // A mismatch not formed has allowed angle 0 in the session; angle 0 >= 0 must not count.
  MismatchTest u;
  u.angle = {ArcsecToRad(300), 0.0, 0.0};
  u.allowed = {ArcsecToRad(60), 0.0, 0.0};
  u.available = {true, false, false};
  EXPECT_EQ(DecideFault(u, kWorking, kReserve).faulty, Subsystem::kNone);
}

TEST(FaultDecision, AnAngleEqualToTheAllowedOneExceeds) {
  // eq. (12) is printed with ">=".
  MismatchTest t = Mismatches(60, 60, 10);
  EXPECT_EQ(DecideFault(t, kWorking, kReserve).faulty, Subsystem::kWorkingPair);
  t.angle[kMismatch13] = std::nextafter(t.allowed[kMismatch13], 0.0);
  EXPECT_EQ(DecideFault(t, kWorking, kReserve).faulty, Subsystem::kNone);
}

TEST(FaultDecision, AllThreeExceededNamesTheWorkingPairByTheOrderOfTheChecks) {
  // The printed rule cannot separate three exceeded mismatches; the checks run working pair,
  // reserve pair, star tracker. A fault in the gyro both pairs share lands here and excludes
  // the working pair's other gyro (2), keeping the faulty gyro 1 in the output pair.
  const FaultDecision d = DecideFault(Mismatches(300, 300, 300), kWorking, kReserve);
  EXPECT_EQ(d.faulty, Subsystem::kWorkingPair);
  EXPECT_EQ(d.excluded_gyro, 2);
  EXPECT_EQ(d.output_pair, kReserve);
}

TEST(FaultDecision, TheFaultyFieldOfTheTestIsNotRead) {
  MismatchTest t = Mismatches(10, 10, 10);
  t.faulty = Subsystem::kStarTracker;
  EXPECT_EQ(DecideFault(t, kWorking, kReserve).faulty, Subsystem::kNone);
}

TEST(FaultySubsystem, IsTheRuleTestMismatchApplies) {
  const Eigen::Quaterniond q = ExpQuaternion(Eigen::Vector3d(0.3, -0.2, 0.9));
  const Eigen::Quaterniond off = ExpQuaternion(Eigen::Vector3d(0, ArcminToRad(3), 0)) * q;
  const std::array<double, 3> allowed = {ArcminToRad(1), ArcminToRad(1), ArcminToRad(1)};
  for (const auto& [a, b, c] : {std::array<const Eigen::Quaterniond*, 3>{&off, &q, &q},
                                std::array<const Eigen::Quaterniond*, 3>{&q, &off, &q},
                                std::array<const Eigen::Quaterniond*, 3>{&q, &q, &off},
                                std::array<const Eigen::Quaterniond*, 3>{&q, nullptr, &off}}) {
    const MismatchTest t = TestMismatch(a, b, c, allowed);
    EXPECT_EQ(t.faulty, FaultySubsystem(t.angle, t.allowed, t.available));
  }
}

TEST(AllowedMismatchAngle, ConfiguredThresholdWinsOtherwiseDirectionalWithTheFloor) {
  const Eigen::Quaterniond q = ExpQuaternion(Eigen::Vector3d(0.1, 0.2, 0.3));
  const Eigen::Quaterniond about_z = ExpQuaternion(Eigen::Vector3d(0, 0, ArcsecToRad(100))) * q;
  // Sigma 5/5/30 arcsec about x/y/z, k_d = 5: 150 arcsec about z.
  const Eigen::Matrix3d Sigma =
      Eigen::Vector3d(ArcsecToRad(5), ArcsecToRad(5), ArcsecToRad(30)).cwiseAbs2().asDiagonal();
  EXPECT_NEAR(RadToArcsec(AllowedMismatchAngle(about_z, q, Sigma, 5.0, 0.0)), 150.0, 1e-6);
  EXPECT_EQ(AllowedMismatchAngle(about_z, q, Sigma, 5.0, ArcsecToRad(40)), ArcsecToRad(40));
  // A tiny covariance gives the 2 arcsec floor.
  const Eigen::Matrix3d tiny = 1e-30 * Eigen::Matrix3d::Identity();
  EXPECT_EQ(AllowedMismatchAngle(about_z, q, tiny, 5.0, 0.0), kMinAllowedMismatch);
  EXPECT_NEAR(RadToArcsec(kMinAllowedMismatch), 2.0, 1e-12);
}

}  // namespace
}  // namespace esg::estimator
