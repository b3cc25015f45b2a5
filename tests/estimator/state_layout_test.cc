// The filter's state layout (estimator/state_layout.h): per-gyro blocks of spin axis, residual
// drift of eq. (11), free coefficients of eq. (10) and misalignment, and the session's covariance
// laid out by it.
#include "estimator/state_layout.h"

#include <vector>

#include "estimator/calibration_model.h"
#include "estimator/session.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/paper_setup.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using ::esg::testing::IsOk;

TEST(StateLayout, BlocksFollowEachOtherInTheDocumentedOrder) {
  StateLayout layout(/*random_walk=*/true);
  EXPECT_EQ(layout.AddGyro({kThetaK0, kThetaC1, kThetaC1 + 1}, /*estimate_phi=*/true), 0);
  EXPECT_EQ(layout.AddGyro({kThetaK0}, /*estimate_phi=*/false), 1);
  EXPECT_EQ(layout.AddGyro({}, /*estimate_phi=*/true), 2);
  ASSERT_EQ(layout.gyro_count(), 3);
  // Gyro 0: dh 0-1, dw_int 2-3, theta 4-6, phi 7-9.
  EXPECT_EQ(layout.SpinAxis(0), 0);
  EXPECT_EQ(layout.Drift(0), 2);
  EXPECT_EQ(layout.Theta(0), 4);
  EXPECT_EQ(layout.ThetaCount(0), 3);
  EXPECT_EQ(layout.Phi(0), 7);
  EXPECT_EQ(layout.GyroSize(0), 10);
  // Gyro 1: dh 10-11, dw_int 12-13, theta 14, no phi.
  EXPECT_EQ(layout.SpinAxis(1), 10);
  EXPECT_EQ(layout.Drift(1), 12);
  EXPECT_EQ(layout.Theta(1), 14);
  EXPECT_FALSE(layout.HasPhi(1));
  EXPECT_EQ(layout.GyroSize(1), 5);
  // Gyro 2: dh 15-16, dw_int 17-18, no theta, phi 19-21.
  EXPECT_EQ(layout.SpinAxis(2), 15);
  EXPECT_EQ(layout.ThetaCount(2), 0);
  EXPECT_EQ(layout.Phi(2), 19);
  EXPECT_EQ(layout.size(), 22);
  EXPECT_EQ(layout.FreeCoefficients(0), (std::vector<int>{kThetaK0, kThetaC1, kThetaC1 + 1}));
}

// Free basis terms follow the free eq. (1) coefficients inside the gyro's block, before the
// misalignment, and count among the spin-axis drivers.
TEST(StateLayout, FreeBasisTermsFollowTheFreeCoefficientsAndDriveTheSpinAxis) {
  StateLayout layout(/*random_walk=*/true);
  layout.AddGyro({kThetaK0, kThetaC1}, /*estimate_phi=*/true, /*free_basis_terms=*/{0, 2, 3});
  layout.AddGyro({kThetaK0}, /*estimate_phi=*/false, /*free_basis_terms=*/{1});
  // Gyro 0: dh 0-1, dw_int 2-3, theta 4-5, basis 6-8, phi 9-11.
  EXPECT_EQ(layout.Theta(0), 4);
  EXPECT_EQ(layout.ThetaCount(0), 2);
  EXPECT_EQ(layout.Basis(0), 6);
  EXPECT_EQ(layout.BasisCount(0), 3);
  EXPECT_EQ(layout.FreeBasisTerms(0), (std::vector<int>{0, 2, 3}));
  EXPECT_EQ(layout.Phi(0), 9);
  EXPECT_EQ(layout.GyroSize(0), 12);
  EXPECT_EQ(layout.SpinAxisDrivers(0), 2);
  EXPECT_EQ(layout.SpinAxisDriverCount(0), 2 + 2 + 3);
  // Gyro 1: dh 12-13, dw_int 14-15, theta 16, basis 17, no phi.
  EXPECT_EQ(layout.Basis(1), 17);
  EXPECT_EQ(layout.BasisCount(1), 1);
  EXPECT_EQ(layout.GyroSize(1), 6);
  EXPECT_EQ(layout.size(), 18);
  EXPECT_EQ(layout.SpinAxisDrivers(1) + layout.SpinAxisDriverCount(1), 18);
}

TEST(StateLayout, WithoutRandomWalkTheCoefficientsFollowTheSpinAxis) {
  StateLayout layout(/*random_walk=*/false);
  layout.AddGyro({kThetaK0, kThetaMu}, /*estimate_phi=*/true);
  layout.AddGyro({kThetaK0}, /*estimate_phi=*/true);
  EXPECT_FALSE(layout.has_drift());
  EXPECT_EQ(layout.DriftSize(), 0);
  EXPECT_EQ(layout.Theta(0), 2);
  EXPECT_EQ(layout.Phi(0), 4);
  EXPECT_EQ(layout.SpinAxis(1), 7);
  EXPECT_EQ(layout.Theta(1), 9);
  EXPECT_EQ(layout.Phi(1), 10);
  EXPECT_EQ(layout.size(), 13);
}

TEST(StateLayout, TheLatencyComesFirstAndAGyroSwitchedOnLaterKeepsEarlierIndices) {
  StateLayout layout(/*random_walk=*/false, /*latency=*/true);
  EXPECT_EQ(layout.size(), 1);
  ASSERT_TRUE(layout.has_latency());
  EXPECT_EQ(layout.Latency(), 0);
  layout.AddGyro({kThetaK0}, /*estimate_phi=*/true);
  EXPECT_EQ(layout.SpinAxis(0), 1);
  EXPECT_EQ(layout.Theta(0), 3);
  EXPECT_EQ(layout.Phi(0), 4);
  layout.AddGyro({}, /*estimate_phi=*/false);
  EXPECT_EQ(layout.SpinAxis(1), 7);
  EXPECT_EQ(layout.size(), 9);
  EXPECT_FALSE(StateLayout(/*random_walk=*/true).has_latency());
}

TEST(StateLayout, PartsCoverEveryStateOnceAndDriversFollowTheSpinAxis) {
  for (int variant = 0; variant < 4; ++variant) {
    const bool random_walk = variant % 2 == 1, latency = variant >= 2;
    StateLayout layout(random_walk, latency);
    layout.AddGyro({0, 1, 2, 3, 4, 5, 6}, true);
    layout.AddGyro({}, false);
    layout.AddGyro({0}, true);
    std::vector<int> owner(layout.size(), 0);
    if (layout.has_latency()) ++owner.at(layout.Latency());
    for (int i = 0; i < layout.gyro_count(); ++i) {
      auto mark = [&](int begin, int count) {
        for (int k = begin; k < begin + count; ++k) ++owner.at(k);
      };
      mark(layout.SpinAxis(i), StateLayout::kSpinAxisSize);
      if (layout.has_drift()) mark(layout.Drift(i), StateLayout::kDriftSize);
      mark(layout.Theta(i), layout.ThetaCount(i));
      if (layout.HasPhi(i)) mark(layout.Phi(i), StateLayout::kPhiSize);
      EXPECT_EQ(layout.GyroBegin(i), layout.SpinAxis(i));
      // The propagation's transition block (d(dh)/dt over dw_int and dtheta) relies on this.
      EXPECT_EQ(layout.SpinAxisDrivers(i), layout.SpinAxis(i) + StateLayout::kSpinAxisSize);
      EXPECT_EQ(layout.SpinAxisDriverCount(i), layout.DriftSize() + layout.ThetaCount(i));
      EXPECT_EQ(layout.Theta(i), layout.SpinAxisDrivers(i) + layout.DriftSize());
    }
    for (int k = 0; k < layout.size(); ++k) EXPECT_EQ(owner[k], 1) << "state " << k;
  }
}

// The session lays its prior covariance out by the layout: the paper's setup (three running
// gyros, model 10+11 frees k0, C1, C2 = 7 coefficients, misalignment estimated) has 14 states
// per gyro, and each prior variance sits where the layout says.
TEST(StateLayout, SessionPriorCovarianceSitsAtTheLayoutIndices) {
  const SpacecraftConfig config = testing::PaperConfig();
  SimulationSpec spec;
  spec.config = config;
  spec.duration = 120.0;
  spec.seed = 5;
  spec.profile = *MakeNamedProfile("calibration", spec.duration, spec.seed);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  SessionOptions options;
  options.model = *ParseModel("10+11");
  EstimationSession session = *EstimationSession::Create(config, options);
  ASSERT_THAT(session.AddFrame(sim->recording.frames[0]), IsOk());
  ASSERT_TRUE(session.initialized());
  ASSERT_EQ(session.state_size(), 3 * 14);

  StateLayout layout(true);
  const std::vector<GyroEstimate> gyros = session.Gyros();
  ASSERT_EQ(gyros.size(), 3u);
  for (const GyroEstimate& g : gyros) {
    const GyroConfig& gc = *config.FindGyro(g.id);
    layout.AddGyro(FreeCoefficients(options.model, gc), gc.misalignment_sigma > 0.0);
  }
  ASSERT_EQ(layout.size(), session.state_size());
  const Eigen::MatrixXd& P = session.covariance();
  const double sigma_rw0 = DegPerHourToRadPerSec(0.01);  // session.h: on top of model 10
  for (int i = 0; i < layout.gyro_count(); ++i) {
    const GyroConfig& gc = *config.FindGyro(gyros[i].id);
    for (int k = 0; k < 2; ++k) {
      EXPECT_DOUBLE_EQ(P(layout.Drift(i) + k, layout.Drift(i) + k), sigma_rw0 * sigma_rw0);
      EXPECT_DOUBLE_EQ(gyros[i].residual_drift_sigma(k), sigma_rw0);
    }
    const DriftVector prior = gc.model_sigma.AsVector();
    for (int j = 0; j < layout.ThetaCount(i); ++j) {
      const int c = layout.FreeCoefficients(i)[j];
      EXPECT_DOUBLE_EQ(P(layout.Theta(i) + j, layout.Theta(i) + j), prior(c) * prior(c));
      EXPECT_DOUBLE_EQ(gyros[i].sigma.AsVector()(c), prior(c));
    }
    for (int k = 0; k < 3; ++k) {
      EXPECT_DOUBLE_EQ(P(layout.Phi(i) + k, layout.Phi(i) + k),
                       gc.misalignment_sigma * gc.misalignment_sigma);
    }
    // Spin-axis errors are correlated with the misalignment (they were rebuilt through it).
    EXPECT_NE(P(layout.SpinAxis(i), layout.Phi(i)) + P(layout.SpinAxis(i), layout.Phi(i) + 1) +
                  P(layout.SpinAxis(i), layout.Phi(i) + 2),
              0.0);
  }
}

}  // namespace
}  // namespace esg::estimator
