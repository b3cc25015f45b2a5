// The eq. (12) fault decision (estimator/fault_detection.h) from plain values: which subsystem
// is named from the three mismatches, which gyro is excluded and which pair carries the output
// (DecideFault: the rule with a working and a reserve pair, used by the session when fewer or
// more than three gyros have a reading); the isolation with three running gyros (DecideIsolation:
// each hypothesis, ambiguous cases); the exact pair-against-pair mismatch covariance
// (MismatchCovariance) against a Monte-Carlo run of the TRIAD pair attitudes. (The mismatch
// formation, eq. (14) and the directional allowed angle are tested in session_test.cc's
// FaultDetection cases.)
#include "estimator/fault_detection.h"

#include <array>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "Eigen/Cholesky"
#include "estimator/measurements.h"
#include "estimator/rotation.h"
#include "estimator/triad.h"
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
  // the working pair's other gyro (2), keeping the faulty gyro 1 in the output pair. The session
  // no longer applies this rule when three gyros have a reading (DecideIsolation below names
  // gyro 1); it remains the rule with what is available otherwise.
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

// --- Isolation with three running gyros (DecideIsolation) ---
// Gyros 1, 2, 3; pair k lacks gyro k+1: pair 0 = [2,3], pair 1 = [1,3], pair 2 = [1,2].
// pair_pair[m] compares the two pairs holding gyro m+1. Allowed 60 arcsec everywhere.
constexpr std::array<int, 3> kIds = {1, 2, 3};

IsolationTest Isolation3(std::array<double, 3> pair_star_arcsec, std::array<double, 3> pair_pair_arcsec,
                         bool star = true) {
  IsolationTest t;
  t.gyro_ids = kIds;
  t.star_available = star;
  for (int k = 0; k < 3; ++k) {
    t.pair_star_angle[k] = ArcsecToRad(pair_star_arcsec[k]);
    t.pair_pair_angle[k] = ArcsecToRad(pair_pair_arcsec[k]);
    t.pair_star_allowed[k] = ArcsecToRad(60);
    t.pair_pair_allowed[k] = ArcsecToRad(60);
  }
  return t;
}

TEST(DecideIsolation, PairWithoutKeepsTheOrderOfTheIds) {
  EXPECT_EQ(PairWithout(kIds, 0), (std::array<int, 2>{2, 3}));
  EXPECT_EQ(PairWithout(kIds, 1), (std::array<int, 2>{1, 3}));
  EXPECT_EQ(PairWithout(kIds, 2), (std::array<int, 2>{1, 2}));
}

TEST(DecideIsolation, SharedGyroFaultExcludesItAndMovesTheOutputToThePairWithoutIt) {
  // Gyro 1: pairs [1,3], [1,2] disagree with the star tracker and with [2,3]; [2,3] agrees with
  // the star tracker. pair_pair[0] ([1,3] against [1,2]) is free: exceeded or not, gyro 1.
  for (double free : {10.0, 300.0}) {
    const IsolationDecision d = DecideIsolation(Isolation3({10, 300, 300}, {free, 300, 300}), kWorking);
    EXPECT_EQ(d.result, Isolation::kGyro) << free;
    EXPECT_EQ(d.excluded_gyro, 1);
    EXPECT_EQ(d.faulty_index, 0);
    EXPECT_EQ(d.output_pair, (std::array<int, 2>{2, 3}));
    EXPECT_TRUE(d.output_switched);
    EXPECT_FALSE(d.reject_star_tracker);
    EXPECT_EQ(d.candidates, std::vector<int>{1});
  }
}

TEST(DecideIsolation, EachGyroIsNamedByItsSignature) {
  // Gyro 2: pairs [2,3] (0) and [1,2] (2) off; pair [1,3] (1) agrees with the star tracker.
  IsolationDecision d = DecideIsolation(Isolation3({300, 10, 300}, {300, 10, 300}), kWorking);
  EXPECT_EQ(d.result, Isolation::kGyro);
  EXPECT_EQ(d.excluded_gyro, 2);
  EXPECT_EQ(d.output_pair, (std::array<int, 2>{1, 3}));
  EXPECT_TRUE(d.output_switched);
  // Gyro 3: not in the working pair: the output stays on [1,2].
  d = DecideIsolation(Isolation3({300, 300, 10}, {300, 300, 10}), kWorking);
  EXPECT_EQ(d.result, Isolation::kGyro);
  EXPECT_EQ(d.excluded_gyro, 3);
  EXPECT_EQ(d.output_pair, kWorking);
  EXPECT_FALSE(d.output_switched);
}

TEST(DecideIsolation, StarTrackerDisagreesWithThreeAgreeingPairs) {
  IsolationDecision d = DecideIsolation(Isolation3({300, 300, 300}, {10, 10, 10}), kWorking);
  EXPECT_EQ(d.result, Isolation::kStarTracker);
  EXPECT_TRUE(d.reject_star_tracker);
  EXPECT_EQ(d.excluded_gyro, 0);
  EXPECT_EQ(d.output_pair, kWorking);
  EXPECT_EQ(d.candidates, std::vector<int>{0});
  // Two pairs suffice while the pairs agree (the third may have a large sigma along the error).
  d = DecideIsolation(Isolation3({10, 300, 300}, {10, 10, 10}), kWorking);
  EXPECT_EQ(d.result, Isolation::kStarTracker);
  // One pair against the star tracker names nothing.
  EXPECT_EQ(DecideIsolation(Isolation3({300, 10, 10}, {10, 10, 10}), kWorking).result, Isolation::kNone);
}

TEST(DecideIsolation, OneGyroFailingItsOwnStarTrackerDifferenceAloneIsNotAStarTrackerFault) {
  // The pairs agree with each other; the two pairs holding gyro 1 disagree with the star tracker
  // and the pair without it ([2,3]) agrees: the star tracker's two-pair pattern on its own.
  IsolationTest t = Isolation3({10, 300, 300}, {10, 10, 10});
  t.gyro_star_available = true;
  // Gyro 1's own star-tracker difference fails and gyros 2 and 3 pass: a star-tracker error
  // would turn the rebuilds of gyros 2 and 3 too, so gyro 1 is named, not the star tracker.
  t.gyro_star_nis = {32.2, 1.2, 2.1};
  IsolationDecision d = DecideIsolation(t, kWorking);
  EXPECT_EQ(d.result, Isolation::kGyro);
  EXPECT_EQ(d.excluded_gyro, 1);
  EXPECT_TRUE(d.decided_by_gyro_star);
  EXPECT_FALSE(d.reject_star_tracker);
  EXPECT_EQ(d.output_pair, (std::array<int, 2>{2, 3}));
  // Two gyros failing their own differences (an error the third gyro's axis lies along): the
  // star tracker.
  t.gyro_star_nis = {32.2, 40.0, 2.1};
  EXPECT_EQ(DecideIsolation(t, kWorking).result, Isolation::kStarTracker);
  // A gyro between pass and fail does not clear the star tracker either.
  t.gyro_star_nis = {32.2, 12.0, 2.1};
  EXPECT_EQ(DecideIsolation(t, kWorking).result, Isolation::kStarTracker);
  // The named gyro's pair-without disagreeing with the star tracker leaves the star tracker.
  t = Isolation3({300, 300, 300}, {10, 10, 10});
  t.gyro_star_available = true;
  t.gyro_star_nis = {32.2, 1.2, 2.1};
  EXPECT_EQ(DecideIsolation(t, kWorking).result, Isolation::kStarTracker);
}

TEST(DecideIsolation, AGyroNeedsOnePairHoldingItToDisagreeWithTheStarTracker) {
  // Gyro 1 confirmed by pair [1,2] against the star tracker only.
  IsolationDecision d = DecideIsolation(Isolation3({10, 10, 300}, {10, 300, 300}), kWorking);
  EXPECT_EQ(d.result, Isolation::kGyro);
  EXPECT_EQ(d.excluded_gyro, 1);
  // The pair mismatches alone while every pair agrees with the star tracker: not named (one
  // noisy pair [2,3] exceeds both mismatches it takes part in).
  d = DecideIsolation(Isolation3({10, 10, 10}, {10, 300, 300}), kWorking);
  EXPECT_EQ(d.result, Isolation::kNone);
  EXPECT_EQ(d.excluded_gyro, 0);
}

TEST(DecideIsolation, FewerExceededThanTheSmallestSignatureNameNothing) {
  EXPECT_EQ(DecideIsolation(Isolation3({10, 10, 10}, {10, 10, 10}), kWorking).result, Isolation::kNone);
  IsolationDecision d = DecideIsolation(Isolation3({300, 10, 10}, {10, 10, 10}), kWorking);
  EXPECT_EQ(d.result, Isolation::kNone);
  EXPECT_EQ(d.excluded_gyro, 0);
  EXPECT_FALSE(d.reject_star_tracker);
  EXPECT_TRUE(d.pair_star_exceeded[0]);
  // One noisy pair ([2,3]) against the two other pairs: two exceeded, fewer than a gyro's
  // signature of three with the star tracker: nothing named, not ambiguous.
  d = DecideIsolation(Isolation3({10, 10, 10}, {10, 300, 300}), kWorking);
  EXPECT_EQ(d.result, Isolation::kNone);
  // Without the star tracker two is a gyro's signature: pair mismatches 1 and 2 name gyro 1.
  d = DecideIsolation(Isolation3({0, 0, 0}, {10, 300, 300}, /*star=*/false), kWorking);
  EXPECT_EQ(d.result, Isolation::kGyro);
  EXPECT_EQ(d.excluded_gyro, 1);
}

TEST(DecideIsolation, AmbiguousPatternsExcludeNothing) {
  // Everything exceeds: no hypothesis has the pair that agrees with the star tracker.
  IsolationDecision d = DecideIsolation(Isolation3({300, 300, 300}, {300, 300, 300}), kWorking);
  EXPECT_EQ(d.result, Isolation::kAmbiguous);
  EXPECT_EQ(d.excluded_gyro, 0);
  EXPECT_EQ(d.output_pair, kWorking);
  EXPECT_FALSE(d.reject_star_tracker);
  EXPECT_TRUE(d.candidates.empty());
  // Two pairs disagree with the star tracker, and only one of the two pair mismatches that
  // would confirm gyro 1 exceeds.
  d = DecideIsolation(Isolation3({10, 300, 300}, {10, 10, 300}), kWorking);
  EXPECT_EQ(d.result, Isolation::kAmbiguous);
  EXPECT_EQ(d.excluded_gyro, 0);
  // Without the star tracker, all three pair mismatches exceeded fit gyro 1, 2 and 3 alike.
  d = DecideIsolation(Isolation3({0, 0, 0}, {300, 300, 300}, /*star=*/false), kWorking);
  EXPECT_EQ(d.result, Isolation::kAmbiguous);
  EXPECT_EQ(d.candidates, (std::vector<int>{1, 2, 3}));
  EXPECT_EQ(d.excluded_gyro, 0);
}

TEST(DecideIsolation, WithoutTheStarTrackerThePairsAloneIsolateAGyro) {
  // Gyro 2: [2,3] and [1,2] disagree with [1,3]; [2,3] against [1,2] (both hold gyro 2) agrees.
  const IsolationDecision d =
      DecideIsolation(Isolation3({0, 0, 0}, {300, 10, 300}, /*star=*/false), kWorking);
  EXPECT_EQ(d.result, Isolation::kGyro);
  EXPECT_EQ(d.excluded_gyro, 2);
  EXPECT_FALSE(d.pair_star_exceeded[0]);  // star-tracker mismatches not formed never exceed
}

TEST(DecideIsolation, AnAngleEqualToTheAllowedOneExceeds) {
  IsolationTest t = Isolation3({10, 300, 300}, {10, 300, 300});
  t.pair_pair_angle[1] = t.pair_pair_allowed[1];
  EXPECT_EQ(DecideIsolation(t, kWorking).excluded_gyro, 1);
  t.pair_pair_angle[1] = std::nextafter(t.pair_pair_allowed[1], 0.0);
  EXPECT_EQ(DecideIsolation(t, kWorking).result, Isolation::kAmbiguous);
}

TEST(DecideIsolation, EvidenceNamesEveryMismatchAndMarksTheExceeded) {
  const IsolationTest t = Isolation3({10, 300, 300}, {10, 300, 300});
  const IsolationDecision d = DecideIsolation(t, kWorking);
  const std::string e = IsolationEvidence(t, d);
  EXPECT_NE(e.find("[1,3]-[1,2] 10.0/60.0 arcsec;"), std::string::npos) << e;
  EXPECT_NE(e.find("[2,3]-[1,2] 300.0/60.0 arcsec EXCEEDS"), std::string::npos) << e;
  EXPECT_NE(e.find("[2,3]-star_tracker 10.0/60.0 arcsec;"), std::string::npos) << e;
  EXPECT_NE(e.find("[1,2]-star_tracker 300.0/60.0 arcsec EXCEEDS"), std::string::npos) << e;
}

// --- The pair-against-pair mismatch covariance ---
// Three gyros with spin-axis errors (2 each, tangent basis of h_in, covariance P with cross
// terms) and readout noise (2 each, tangent basis of the reading, sigma_r): the TRIAD attitudes of
// pairs [1,2] and [1,3] (reference gyro 1 in both). Their Jacobians by central differences; the
// mismatch covariance of MismatchCovariance against 40000 Monte-Carlo draws of the full
// nonlinear TRIAD mismatch. The sum of the two pair covariances is far from it (gyro 1, the
// reference of both pairs, cancels in the mismatch): a check that uses S1 + S2 fails.
TEST(MismatchCovariance, MatchesMonteCarloOfTwoPairsSharingAGyro) {
  const Eigen::Vector3d h_in[3] = {Eigen::Vector3d(0.2, 0.9, 0.1).normalized(),
                                   Eigen::Vector3d(-0.7, 0.1, 0.6).normalized(),
                                   Eigen::Vector3d(0.5, -0.3, 0.8).normalized()};
  const Eigen::Quaterniond q_in_b = ExpQuaternion(Eigen::Vector3d(0.4, -0.6, 1.1));
  const Eigen::Matrix3d C_b_in = q_in_b.toRotationMatrix().transpose();
  Eigen::Vector3d h_b[3];
  Eigen::Matrix<double, 3, 2> T[3], U[3];
  for (int i = 0; i < 3; ++i) {
    h_b[i] = C_b_in * h_in[i];
    T[i] = TangentBasis(h_in[i]);
    U[i] = TangentBasis(h_b[i]);
  }
  // e = [dh_1, dh_2, dh_3] (6), r = [r_1, r_2, r_3] (6).
  auto attitude = [&](int a, int b, const Eigen::VectorXd& e, const Eigen::VectorXd& r) {
    auto axis = [&](int g) { return (h_in[g] + T[g] * e.segment<2>(2 * g)).normalized().eval(); };
    auto read = [&](int g) { return (h_b[g] + U[g] * r.segment<2>(2 * g)).normalized().eval(); };
    return *PairAttitude(axis(a), axis(b), read(a), read(b));
  };
  const Eigen::VectorXd zero = Eigen::VectorXd::Zero(6);
  const Eigen::Quaterniond q0[2] = {attitude(0, 1, zero, zero), attitude(0, 2, zero, zero)};
  const int pairs[2][2] = {{0, 1}, {0, 2}};
  Eigen::MatrixXd J[2], G[2];
  const double step = 1e-6;
  for (int p = 0; p < 2; ++p) {
    J[p] = Eigen::MatrixXd::Zero(3, 6);
    G[p] = Eigen::MatrixXd::Zero(3, 6);
    for (int j = 0; j < 6; ++j) {
      Eigen::VectorXd d = Eigen::VectorXd::Zero(6);
      d(j) = step;
      auto diff = [&](const Eigen::Quaterniond& plus, const Eigen::Quaterniond& minus) {
        return ((LogQuaternion(plus * q0[p].conjugate()) - LogQuaternion(minus * q0[p].conjugate())) /
                (2 * step))
            .eval();
      };
      J[p].col(j) = diff(attitude(pairs[p][0], pairs[p][1], d, zero),
                         attitude(pairs[p][0], pairs[p][1], -d, zero));
      G[p].col(j) = diff(attitude(pairs[p][0], pairs[p][1], zero, d),
                         attitude(pairs[p][0], pairs[p][1], zero, -d));
    }
  }
  // P: 20 arcsec spin-axis sigma, correlated across gyros (as after star-tracker updates).
  Eigen::MatrixXd A(6, 6);
  std::mt19937_64 rng(7);
  std::normal_distribution<double> n01(0.0, 1.0);
  for (int i = 0; i < 6; ++i) {
    for (int j = 0; j < 6; ++j) A(i, j) = n01(rng);
  }
  const double s = ArcsecToRad(20);
  const Eigen::MatrixXd P = s * s * (0.5 * Eigen::MatrixXd::Identity(6, 6) + A * A.transpose() / 12.0);
  const double sigma_r = ArcsecToRad(3);
  const Eigen::Matrix3d exact = MismatchCovariance(J[0], G[0], J[1], G[1], P, sigma_r * sigma_r);

  const Eigen::MatrixXd L = P.llt().matrixL();
  const int draws = 40000;
  Eigen::Matrix3d sample = Eigen::Matrix3d::Zero();
  for (int k = 0; k < draws; ++k) {
    Eigen::VectorXd w(6), r(6);
    for (int i = 0; i < 6; ++i) w(i) = n01(rng);
    for (int i = 0; i < 6; ++i) r(i) = sigma_r * n01(rng);
    const Eigen::VectorXd e = L * w;
    const Eigen::Vector3d m = LogQuaternion(attitude(0, 1, e, r) * attitude(0, 2, e, r).conjugate());
    sample += m * m.transpose();
  }
  sample /= draws;
  // Sampling error of a covariance entry ~ sqrt(2/N) of its scale: 0.7% at N = 40000.
  const double scale = exact.norm();
  EXPECT_LT((sample - exact).norm(), 0.03 * scale) << "exact\n" << exact << "\nsample\n" << sample;
  const Eigen::Matrix3d S1 = J[0] * P * J[0].transpose() + sigma_r * sigma_r * G[0] * G[0].transpose();
  const Eigen::Matrix3d S2 = J[1] * P * J[1].transpose() + sigma_r * sigma_r * G[1] * G[1].transpose();
  EXPECT_GT(((S1 + S2) - sample).norm(), 0.3 * scale) << "S1 + S2\n" << S1 + S2;
  // Gyro 1, the reference of both pairs, largely cancels: S1 + S2 overstates the mismatch.
  EXPECT_GT((S1 + S2).trace(), 1.3 * sample.trace());
}

}  // namespace
}  // namespace esg::estimator
