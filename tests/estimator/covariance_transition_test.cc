// The covariance transition of the propagation (estimator/session_propagation.cc: Phi = I + E over
// a frame interval, the spin-axis errors driven by the residual drift of eq. (11), the free
// drift coefficients of eq. (1)/(10) and the free basis terms of basis_term.h) checked against central differences of the nominal
// propagation, through the public API only: the checkpoint (layout at the top of
// estimator/session_checkpoint.cc) is edited and restored, one frame that is not a measurement
// step is applied, and
//   analytic:  P = tiny I except P(j, j) = eps  =>  P'(:, j) = Phi(:, j) eps + Q(:, j)
//   numerical: theta_j (or residual_drift_j, or a basis term's value) +- delta in the checkpoint =>
//              Phi(spin axis of gyro g, j) = T_g^T (h_in_g(+delta) - h_in_g(-delta)) / (2 delta),
//              T_g = (t1, h_in x t1) at the end of the interval, error = true - estimate
//              (conventions.h, session.h): a true theta larger by delta moves the true axis by
//              the numerical difference, so no sign flip.
// Measured (seed 7, 10 s interval): worst relative mismatch 1.7e-6 against the tolerance 1e-4.
// Against mutants of session_propagation.cc built outside the tree: the coefficient columns of E
// with the sign flipped, or J transposed in the residual-drift columns, give a relative mismatch
// of 2; the (spin axis, residual drift) process-noise term dropped fails
// ProcessNoiseIsOnlyTheIntegratedRandomWalk by 3.3e-19 rad^2/s against a tolerance of 1e-35.
#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "estimator/basis_term.h"
#include "estimator/calibration_model.h"
#include "estimator/drift_model.h"
#include "estimator/session.h"
#include "estimator/simulator.h"
#include "estimator/state_layout.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/checkpoint_versions.h"
#include "tests/testing/paper_setup.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using ::esg::testing::IsOk;

// Per-gyro checkpoint record of version 7 (session_checkpoint.cc): id, h_in (3), t1 (3),
// residual_drift (2), theta (13), phi_b (3), faulty, has_reading, h_k_last (3); version 8 has the
// theta count before theta (testing::GyroRecordLength). The tests below cut the checkpoint to
// version 6, so their offsets are version 7's.
constexpr int kHIn = 1, kT1 = 4, kResidualDrift = 7, kTheta = 9;

// Offsets into a version-3 checkpoint's values.
struct CheckpointIndex {
  std::vector<int> gyro;  // start of each running gyro's record, in the session's order
  int n_index = 0;        // the state size n; P follows row by row
  int n = 0;
  int P(int r, int c) const { return n_index + 1 + r * n + c; }
};

CheckpointIndex Index(const SessionCheckpoint& c) {
  CheckpointIndex x;
  // initialized, use_star_tracker, four times of three values, working and reserve pair, state,
  // steps_without_star_tracker, consecutive_rejections, converged: 22 values; then m and m values.
  int pos = 22;
  const int m = static_cast<int>(c.values[pos]);
  pos += 1 + m;
  const int gyros = static_cast<int>(c.values[pos++]);
  const int record = static_cast<int>(testing::GyroRecordLength(c));
  for (int i = 0; i < gyros; ++i, pos += record) x.gyro.push_back(pos);
  x.n_index = pos;
  x.n = static_cast<int>(c.values[pos]);
  return x;
}

// The checkpoint cut to version 6 (session_checkpoint.cc: each version appends to the one
// before), which the session restores with its version-7 parts (exclusions, the reading-fault
// tracks) starting afresh: the tests below read the version-6 tail from the end.
SessionCheckpoint ToVersion6(SessionCheckpoint c, int gyros, int n, const SpacecraftConfig& config,
                             const std::vector<int>& ids) {
  c = testing::AsVersion7(std::move(c));
  const CheckpointIndex x = Index(c);
  size_t pos = static_cast<size_t>(x.n_index) + 1 + 2 * static_cast<size_t>(n) * n;  // version 1
  auto section = [&] { pos += 1 + static_cast<size_t>(c.values[pos]); };
  pos += 3;   // version 2: anchoring flags
  section();  // consistency monitor
  section();  // version 3: widening
  pos += 4;   // suspect gyro and time
  pos += 5;   // version 4: latency, rate (3), interval
  section();  // change detector
  pos += 10;  // version 5: mount correction
  section();  // mount monitor
  for (int g = 0; g < gyros; ++g) {  // version 6: basis values, held voltages
    pos += 1 + config.FindGyro(ids[g])->basis_terms.size() + 4;
  }
  c.version = 6;
  c.values.resize(pos);
  return c;
}

Eigen::Vector3d Vec3(const SessionCheckpoint& c, int at) {
  return Eigen::Vector3d(c.values[at], c.values[at + 1], c.values[at + 2]);
}

// The state layout the session builds (session.cc LayoutFor) for the running gyros `ids`.
StateLayout LayoutOf(const SpacecraftConfig& config, const ModelSpec& model,
                     const std::vector<int>& ids) {
  StateLayout layout(model.random_walk);
  for (int id : ids) {
    const GyroConfig& gc = *config.FindGyro(id);
    layout.AddGyro(FreeCoefficients(model, gc), gc.misalignment_sigma > 0.0, FreeBasisTerms(gc));
  }
  return layout;
}

class CovarianceTransition : public ::testing::Test {
 protected:
  void SetUp() override {
    // The paper's flight (session_test.cc PaperFlight, shortened) with 10 s telemetry frames and
    // the 60 s measurement step: five of every six frames only propagate.
    SimulationSpec spec;
    spec.config = testing::PaperConfig();
    // Free basis terms (basis_term.h) in gyros 1 and 3: h1 -> z, and a case-fixed drift -> x.
    BasisTerm h1;
    h1.kind = BasisKind::kSpinAxisHarmonic;
    h1.axis = 3;
    h1.exponents = {1, 0, 0};
    h1.sigma = DegPerHourToRadPerSec(0.1);
    BasisTerm fixed = h1;
    fixed.axis = 1;
    fixed.exponents = {0, 0, 0};
    spec.config.gyros[0].basis_terms = {h1};
    spec.config.gyros[2].basis_terms = {fixed};
    spec.duration = HoursToSeconds(2.0);
    spec.telemetry_step = 10.0;
    spec.seed = 7;
    spec.profile = *MakeNamedProfile("calibration", spec.duration, spec.seed);
    for (int i = 0; i < 4; ++i) {
      DriftCoefficients d = spec.config.gyros[i].model;
      d.k0 += DegPerHourToRadPerSec(0.1 * (i % 2 ? 1 : -1));
      spec.gyros[i].drift = d;
    }
    spec.gyros[0].rotor_displacement_k = Eigen::Vector3d(1.0e-6, -1.5e-6, 0.8e-6);
    spec.gyros[1].rotor_displacement_k = Eigen::Vector3d(-0.7e-6, 0.5e-6, 1.2e-6);
    config_ = spec.config;
    ASSERT_EQ(config_.filter.measurement_step, 60.0);
    options_.model = *ParseModel("10+11");
    auto sim = Simulate(spec);
    ASSERT_THAT(sim, IsOk());
    frames_ = sim->recording.frames;
    auto session = EstimationSession::Create(config_, options_);
    ASSERT_THAT(session, IsOk());
    // Run 1 h 30 min, stopping right after a measurement step, so the next frame (10 s later)
    // only propagates.
    size_t i = 0;
    for (; i < frames_.size(); ++i) {
      auto report = session->AddFrame(frames_[i]);
      ASSERT_THAT(report, IsOk());
      if (i >= 540 && report->measurement_step) break;
    }
    ASSERT_LT(i + 1, frames_.size());
    next_ = frames_[i + 1];
    for (const GyroEstimate& g : session->Gyros()) ids_.push_back(g.id);
    const SessionCheckpoint full = session->ExportCheckpoint();
    checkpoint_ = ToVersion6(full, static_cast<int>(ids_.size()), Index(full).n, config_, ids_);
    index_ = Index(checkpoint_);
    layout_ = LayoutOf(config_, options_.model, ids_);
    ASSERT_EQ(layout_.size(), index_.n);
    ASSERT_EQ(ids_.size(), 3u);
  }

  // Restores `c`, applies next_ (asserted not a measurement step) and returns the checkpoint
  // after it.
  SessionCheckpoint Step(const SessionCheckpoint& c) {
    auto s = EstimationSession::FromCheckpoint(config_, options_, c);
    EXPECT_THAT(s, IsOk());
    if (!s.ok()) return c;
    auto report = s->AddFrame(next_);
    EXPECT_THAT(report, IsOk());
    if (!report.ok()) return c;
    EXPECT_FALSE(report->measurement_step);
    // In version 7's layout, whose first part (through P) the offsets of index_ describe.
    return testing::AsVersion7(s->ExportCheckpoint());
  }

  // The checkpoint with P = tiny I, except P(j, j) = eps.
  SessionCheckpoint WithCovariance(int j, double eps, double tiny) const {
    SessionCheckpoint c = checkpoint_;
    for (int r = 0; r < index_.n; ++r) {
      for (int k = 0; k < index_.n; ++k) c.values[index_.P(r, k)] = r == k ? tiny : 0.0;
    }
    if (j >= 0) c.values[index_.P(j, j)] = eps;
    return c;
  }

  double Span() const { return absl::ToDoubleSeconds(next_.time - LastTime()); }
  absl::Time LastTime() const {
    // last_time: values 2..4 = (1, unix seconds, nanoseconds).
    return absl::FromUnixNanos(static_cast<int64_t>(checkpoint_.values[3]) * 1000000000 +
                               static_cast<int64_t>(checkpoint_.values[4]));
  }

  // Index into a checkpoint's values of the value of basis term `term` of the session's gyro
  // `gyro`: the version-6 tail (session_checkpoint.cc) holds per gyro b, b values, has_u, u (3).
  int BasisValueIndex(const SessionCheckpoint& c, int gyro, int term) const {
    int tail = 0;
    for (int id : ids_) tail += 5 + static_cast<int>(config_.FindGyro(id)->basis_terms.size());
    int pos = static_cast<int>(c.values.size()) - tail;
    for (int g = 0; g < gyro; ++g) {
      pos += 5 + static_cast<int>(config_.FindGyro(ids_[g])->basis_terms.size());
    }
    return pos + 1 + term;
  }

  // The process noise Q(r, j) the propagation adds over the interval (session_propagation.cc):
  // the integrated random walk of eq. (11) in each gyro's spin-axis / residual-drift block, and
  // nothing in any column of a free coefficient.
  double Q(int r, int j, double span) const {
    const double q2 = config_.random_walk * config_.random_walk;
    for (int g = 0; g < layout_.gyro_count(); ++g) {
      const int h = layout_.SpinAxis(g), d = layout_.Drift(g);
      const auto in = [](int x, int b) { return x >= b && x < b + 2; };
      if (in(r, h) && in(j, h)) return r == j ? q2 * span * span * span / 3.0 : 0.0;
      if (in(r, d) && in(j, d)) return r == j ? q2 * span : 0.0;
      // J = [0 1; -1 0]: Q(h, d) = q2 span^2 / 2 J, Q(d, h) its transpose.
      if (in(r, h) && in(j, d)) {
        const int a = r - h, b = j - d;
        return q2 * span * span / 2.0 * (a == 0 && b == 1 ? 1.0 : a == 1 && b == 0 ? -1.0 : 0.0);
      }
      if (in(r, d) && in(j, h)) {
        const int a = j - h, b = r - d;
        return q2 * span * span / 2.0 * (a == 0 && b == 1 ? 1.0 : a == 1 && b == 0 ? -1.0 : 0.0);
      }
    }
    return 0.0;
  }

  SpacecraftConfig config_;
  SessionOptions options_;
  std::vector<TelemetryFrame> frames_;
  TelemetryFrame next_;
  SessionCheckpoint checkpoint_;
  CheckpointIndex index_;
  std::vector<int> ids_;
  StateLayout layout_;
};

TEST_F(CovarianceTransition, ProcessNoiseIsOnlyTheIntegratedRandomWalk) {
  // (A widened process noise, noise_widening.h, would add to the spin-axis diagonal and fail
  // this test: the run is one the consistency monitor finds consistent.)
  // P = tiny I: P' - P = E tiny E^T + Q; with tiny = 1e-40 the first term is below 1e-36, far
  // under Q's smallest nonzero entry (q^2 span^3 / 3 ~ 2e-18 rad^2), so P' - P is Q exactly up to
  // rounding: nonzero only in the spin-axis / residual-drift blocks, zero in every (spin axis,
  // coefficient) cross term.
  const double tiny = 1e-40;
  const double span = Span();
  ASSERT_EQ(span, 10.0);
  const SessionCheckpoint after = Step(WithCovariance(-1, 0.0, tiny));
  double worst = 0.0;
  for (int r = 0; r < index_.n; ++r) {
    for (int c = 0; c < index_.n; ++c) {
      const double dp = after.values[index_.P(r, c)] - (r == c ? tiny : 0.0);
      const double q = Q(r, c, span);
      worst = std::max(worst, std::abs(dp - q));
      EXPECT_NEAR(dp, q, 1e-12 * std::abs(q) + 1e-35) << "P(" << r << ", " << c << ")";
    }
  }
  RecordProperty("process_noise_worst_abs", std::to_string(worst));
}

TEST_F(CovarianceTransition, ColumnsMatchCentralDifferencesOfThePropagation) {
  const double span = Span();
  ASSERT_EQ(span, 10.0);
  struct Case {
    int gyro;       // index into the session's gyros
    bool drift;     // residual drift (else free coefficient or basis term)
    int component;  // residual drift component, or drift_model.h theta index
    std::string name;
    int basis = -1;  // >= 0: index into the gyro's basis terms (then drift, component unused)
  };
  std::vector<Case> cases;
  for (int g : {0, 2}) {  // the reference gyro and gyro 3 (outside the working pair)
    cases.push_back({g, false, kThetaK0, "k0"});
    cases.push_back({g, false, kThetaC1 + 1, "C1y"});
    cases.push_back({g, false, kThetaC2 + 2, "C2z"});
    cases.push_back({g, true, 0, "dw_int_1"});
    cases.push_back({g, true, 1, "dw_int_2"});
    cases.push_back({g, false, 0, g == 0 ? "h1->z" : "1->x", /*basis=*/0});
  }
  const SessionCheckpoint nominal_after = Step(checkpoint_);
  double worst_relative = 0.0;
  for (const Case& k : cases) {
    SCOPED_TRACE(absl::StrCat("gyro ", ids_[k.gyro], " ", k.name));
    int state = -1;
    int value = index_.gyro[k.gyro];
    if (k.basis >= 0) {
      const std::vector<int>& free = layout_.FreeBasisTerms(k.gyro);
      for (size_t f = 0; f < free.size(); ++f) {
        if (free[f] == k.basis) state = layout_.Basis(k.gyro) + static_cast<int>(f);
      }
      value = BasisValueIndex(checkpoint_, k.gyro, k.basis);
      ASSERT_EQ(checkpoint_.values[value - 1 - k.basis], 1.0);  // b: one term each
    } else if (k.drift) {
      state = layout_.Drift(k.gyro) + k.component;
      value += kResidualDrift + k.component;
    } else {
      const std::vector<int>& free = layout_.FreeCoefficients(k.gyro);
      for (size_t f = 0; f < free.size(); ++f) {
        if (free[f] == k.component) state = layout_.Theta(k.gyro) + static_cast<int>(f);
      }
      value += kTheta + k.component;
    }
    ASSERT_GE(state, 0);

    // (a) Analytic column. eps of a typical prior variance, (0.01 deg/h)^2; tiny as above.
    const double eps = std::pow(DegPerHourToRadPerSec(0.01), 2);
    const double tiny = 1e-40;
    const SessionCheckpoint analytic_after = Step(WithCovariance(state, eps, tiny));
    Eigen::VectorXd phi(index_.n);
    for (int r = 0; r < index_.n; ++r) {
      phi(r) = (analytic_after.values[index_.P(r, state)] - Q(r, state, span)) / eps;
    }
    // Outside the spin-axis rows Phi is the identity: column j is e_j.
    for (int r = 0; r < index_.n; ++r) {
      bool spin_axis_row = false;
      for (int g = 0; g < layout_.gyro_count(); ++g) {
        spin_axis_row |= r >= layout_.SpinAxis(g) && r < layout_.SpinAxis(g) + 2;
      }
      if (!spin_axis_row) EXPECT_NEAR(phi(r), r == state ? 1.0 : 0.0, 1e-12) << "row " << r;
    }
    // The second-order term E P E^T of the transition: the spin-axis block of the driven gyro
    // gains Phi(s, j) Phi(s', j) eps on top of tiny and Q.
    const int h = layout_.SpinAxis(k.gyro);
    for (int a = 0; a < 2; ++a) {
      for (int b = 0; b < 2; ++b) {
        const double gained = analytic_after.values[index_.P(h + a, h + b)] -
                              (a == b ? tiny : 0.0) - Q(h + a, h + b, span);
        const double expected = phi(h + a) * phi(h + b) * eps;
        EXPECT_NEAR(gained, expected, 1e-9 * phi.segment<2>(h).squaredNorm() * eps)
            << "P(" << h + a << ", " << h + b << ")";
      }
    }

    // (b) Numerical column. delta moves the axis by delta * span ~ 5e-7 rad over the 10 s: far
    // above rounding of the unit vectors (1e-16 / 5e-7 ~ 2e-10 relative), far below where the
    // third-order remainder of the central difference matters ((delta span)^2 ~ 3e-13 relative).
    const double delta = DegPerHourToRadPerSec(10.0);
    SessionCheckpoint plus = checkpoint_, minus = checkpoint_;
    plus.values[value] += delta;
    minus.values[value] -= delta;
    const SessionCheckpoint after_plus = Step(plus), after_minus = Step(minus);
    // Spin-axis rows of every gyro (the cross-gyro rows are zero in Phi: the linearisation
    // leaves out that a gyro's axis error turns the pair attitude that carries the other gyros'
    // case-frame drift to inertial axes).
    double column_norm = 0.0, mismatch = 0.0;
    for (int g = 0; g < layout_.gyro_count(); ++g) {
      const int rec = index_.gyro[g];
      const Eigen::Vector3d h = Vec3(nominal_after, rec + kHIn);
      const Eigen::Vector3d t1 = Vec3(nominal_after, rec + kT1);
      const Eigen::Vector3d t2 = h.cross(t1);
      const Eigen::Vector3d dh =
          (Vec3(after_plus, rec + kHIn) - Vec3(after_minus, rec + kHIn)) / (2.0 * delta);
      const Eigen::Vector2d numerical(t1.dot(dh), t2.dot(dh));
      const Eigen::Vector2d analytic = phi.segment<2>(layout_.SpinAxis(g));
      column_norm = std::max(column_norm, numerical.norm());
      mismatch = std::max(mismatch, (analytic - numerical).norm());
      std::printf("gyro %d %-9s -> rows of gyro %d: analytic (%+.9f, %+.9f) numerical (%+.9f, %+.9f) s\n",
                  ids_[k.gyro], k.name.c_str(), ids_[g], analytic(0), analytic(1), numerical(0),
                  numerical(1));
    }
    // The column is of order the span (0.35 to 10 s here); a sign error or a missing term is a
    // mismatch of order the column itself.
    ASSERT_GT(column_norm, 0.01 * span);
    // What the linearisation leaves out, relative to the column: the rotation of the tangent
    // basis over the interval and the turn of the pair attitude by the perturbed axis, both of
    // order |dw| span <= 2e-6 rad/s x 10 s = 2e-5. Tolerance 1e-4 of the column.
    const double relative = mismatch / column_norm;
    worst_relative = std::max(worst_relative, relative);
    EXPECT_LT(relative, 1e-4);
  }
  std::printf("worst relative mismatch %.3g\n", worst_relative);
  RecordProperty("worst_relative_mismatch", std::to_string(worst_relative));
}

}  // namespace
}  // namespace esg::estimator
