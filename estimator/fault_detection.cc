#include "estimator/fault_detection.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "Eigen/Cholesky"
#include "absl/strings/str_format.h"
#include "estimator/rotation.h"

namespace esg::estimator {

const char* SubsystemName(Subsystem s) {
  switch (s) {
    case Subsystem::kNone:
      return "none";
    case Subsystem::kWorkingPair:
      return "working_pair";
    case Subsystem::kReservePair:
      return "reserve_pair";
    case Subsystem::kStarTracker:
      return "star_tracker";
  }
  return "?";
}

Subsystem FaultySubsystem(const std::array<double, 3>& angle, const std::array<double, 3>& allowed,
                          const std::array<bool, 3>& available) {
  std::array<bool, 3> exceeded = {false, false, false};
  for (int m = 0; m < 3; ++m) exceeded[m] = available[m] && angle[m] >= allowed[m];
  // Subsystem s is faulty when both mismatches that involve it exceed: 1 -> (12, 13),
  // 2 -> (12, 23), 3 -> (13, 23).
  if (exceeded[kMismatch12] && exceeded[kMismatch13]) return Subsystem::kWorkingPair;
  if (exceeded[kMismatch12] && exceeded[kMismatch23]) return Subsystem::kReservePair;
  if (exceeded[kMismatch13] && exceeded[kMismatch23]) return Subsystem::kStarTracker;
  return Subsystem::kNone;
}

MismatchTest TestMismatch(const Eigen::Quaterniond* q1, const Eigen::Quaterniond* q2,
                          const Eigen::Quaterniond* q3, const std::array<double, 3>& allowed) {
  // eq. (12): dL_12 = L1 o conj(L2), dL_13 = L1 o conj(L3), dL_23 = L2 o conj(L3).
  MismatchTest t;
  t.allowed = allowed;
  const Eigen::Quaterniond* q[3] = {q1, q2, q3};
  const int pairs[3][2] = {{0, 1}, {0, 2}, {1, 2}};
  for (int m = 0; m < 3; ++m) {
    const auto* a = q[pairs[m][0]];
    const auto* b = q[pairs[m][1]];
    if (a == nullptr || b == nullptr) continue;
    t.available[m] = true;
    t.angle[m] = RotationAngle(*a, *b);
  }
  t.faulty = FaultySubsystem(t.angle, t.allowed, t.available);
  return t;
}

double DirectionalAllowedAngle(const Eigen::Vector3d& dtheta, const Eigen::Matrix3d& Sigma, double k_d,
                               double floor) {
  const double angle = dtheta.norm();
  Eigen::LLT<Eigen::Matrix3d> llt(0.5 * (Sigma + Sigma.transpose()));
  if (angle == 0.0 || llt.info() != Eigen::Success) {
    // No direction, or no usable covariance: the largest axis sigma.
    return std::max(floor, k_d * std::sqrt(std::max(Sigma.diagonal().maxCoeff(), 0.0)));
  }
  const Eigen::Vector3d u = dtheta / angle;
  const double info = u.dot(llt.solve(u));  // u^T Sigma^-1 u = 1 / sigma_u^2
  return std::max(floor, k_d / std::sqrt(info));
}

double AllowedMismatchAngle(const Eigen::Quaterniond& q_in_b_a, const Eigen::Quaterniond& q_in_b_b,
                            const Eigen::Matrix3d& Sigma, double k_d, double configured) {
  if (configured > 0.0) return configured;
  return DirectionalAllowedAngle(LogQuaternion(q_in_b_a * q_in_b_b.conjugate()), Sigma, k_d,
                                 kMinAllowedMismatch);
}

FaultDecision DecideFault(const MismatchTest& test, const std::array<int, 2>& working_pair,
                          const std::array<int, 2>& reserve_pair) {
  FaultDecision d;
  d.faulty = FaultySubsystem(test.angle, test.allowed, test.available);
  d.output_pair = working_pair;
  auto contains = [](const std::array<int, 2>& pair, int id) {
    return pair[0] == id || pair[1] == id;
  };
  switch (d.faulty) {
    case Subsystem::kNone:
      break;
    case Subsystem::kWorkingPair:
      // docs/decisions.md D10: the gyro of the working pair that is not in the reserve pair.
      d.evidence = kMismatch12;
      d.excluded_gyro = contains(reserve_pair, working_pair[1]) ? working_pair[0] : working_pair[1];
      d.output_pair = reserve_pair;
      d.output_switched = true;
      break;
    case Subsystem::kReservePair:
      d.evidence = kMismatch12;
      d.excluded_gyro = contains(working_pair, reserve_pair[1]) ? reserve_pair[0] : reserve_pair[1];
      break;
    case Subsystem::kStarTracker:
      d.evidence = kMismatch13;
      d.reject_star_tracker = true;
      break;
  }
  return d;
}

const char* IsolationName(Isolation i) {
  switch (i) {
    case Isolation::kNone:
      return "none";
    case Isolation::kGyro:
      return "gyro";
    case Isolation::kStarTracker:
      return "star_tracker";
    case Isolation::kAmbiguous:
      return "ambiguous";
  }
  return "?";
}

std::array<int, 2> PairWithout(const std::array<int, 3>& gyro_ids, int k) {
  std::array<int, 2> p = {0, 0};
  int j = 0;
  for (int i = 0; i < 3; ++i) {
    if (i != k) p[j++] = gyro_ids[i];
  }
  return p;
}

IsolationDecision DecideIsolation(const IsolationTest& test, const std::array<int, 2>& working_pair) {
  IsolationDecision d;
  d.output_pair = working_pair;
  int exceeded = 0;
  for (int k = 0; k < 3; ++k) {
    d.pair_star_exceeded[k] = test.star_available && test.pair_star_angle[k] >= test.pair_star_allowed[k];
    d.pair_pair_exceeded[k] = test.pair_pair_angle[k] >= test.pair_pair_allowed[k];
    exceeded += d.pair_star_exceeded[k] + d.pair_pair_exceeded[k];
  }
  // The gyro whose own star-tracker difference alone fails (D22), -1 if none.
  int star_named = -1;
  if (test.gyro_star_available) {
    int failed = 0, passed = 0;
    for (int k = 0; k < 3; ++k) {
      d.gyro_star_failed[k] = test.gyro_star_nis[k] > test.gyro_star_fail;
      failed += d.gyro_star_failed[k];
      passed += test.gyro_star_nis[k] < test.gyro_star_pass;
      if (d.gyro_star_failed[k]) star_named = k;
    }
    if (failed != 1 || passed != 2) star_named = -1;
  }
  if (exceeded == 0) return d;
  if (star_named >= 0 && test.star_available && !d.pair_star_exceeded[star_named]) {
    // Fewer mismatches than a gyro's signature exceeded, but the named gyro's own star-tracker
    // difference fails alone and the pair without it agrees with the star tracker (D22).
    // pair_pair[m], m != the named gyro, compares the pair without it with a pair that holds it;
    // pair_star[m], m != the named gyro, a pair that holds it with the star tracker. Both of
    // those against the star tracker while the pairs agree with each other is the star
    // tracker's two-pair pattern, but a star-tracker error cannot fail one gyro's own difference
    // while two others on non-parallel axes pass and the pair of those two agrees with it: the
    // gyro is named (a slow error of its readings, such as a drift it gained, that the pair
    // mismatches, whose thresholds carry every gyro's model uncertainty, do not yet see).
    bool involves_named = false;
    int star_holding_named = 0;
    for (int m = 0; m < 3; ++m) {
      if (m == star_named) continue;
      involves_named = involves_named || d.pair_pair_exceeded[m];
      star_holding_named += d.pair_star_exceeded[m];
    }
    if ((involves_named || star_holding_named == 2) && exceeded < 3) {
      d.result = Isolation::kGyro;
      d.decided_by_gyro_star = true;
      d.faulty_index = star_named;
      d.excluded_gyro = test.gyro_ids[star_named];
      if (working_pair[0] == d.excluded_gyro || working_pair[1] == d.excluded_gyro) {
        d.output_pair = PairWithout(test.gyro_ids, star_named);
        d.output_switched = true;
      }
      return d;
    }
  }
  std::vector<int> matches;  // gyro index, 3 = star tracker
  for (int g = 0; g < 3; ++g) {
    bool holds = true;
    int star_exceeded = 0;
    for (int k = 0; k < 3; ++k) {
      if (k == g) continue;
      holds = holds && d.pair_pair_exceeded[k];
      star_exceeded += d.pair_star_exceeded[k];
    }
    if (test.star_available) holds = holds && !d.pair_star_exceeded[g] && star_exceeded >= 1;
    if (holds) matches.push_back(g);
  }
  if (test.star_available) {
    int star_exceeded = 0;
    bool pairs_agree = true;
    for (int k = 0; k < 3; ++k) {
      star_exceeded += d.pair_star_exceeded[k];
      pairs_agree = pairs_agree && !d.pair_pair_exceeded[k];
    }
    if (pairs_agree && star_exceeded >= 2) matches.push_back(3);
  }
  for (int m : matches) d.candidates.push_back(m == 3 ? 0 : test.gyro_ids[m]);
  const bool star_tracker_only = matches.size() == 1 && matches[0] == 3;
  const bool signature = exceeded >= (test.star_available ? 3 : 2);
  if (star_named >= 0 && !star_tracker_only && (signature || matches.size() == 1)) {
    d.decided_by_gyro_star = !(matches.size() == 1 && matches[0] == star_named);
    matches = {star_named};
  }
  if (matches.size() != 1) {
    // Fewer exceeded mismatches than a gyro's smallest signature (three with the star tracker,
    // two without) are not reported: one noisy pair attitude exceeds the two mismatches it takes
    // part in.
    if (exceeded >= (test.star_available ? 3 : 2)) d.result = Isolation::kAmbiguous;
    return d;
  }
  if (matches[0] == 3) {
    d.result = Isolation::kStarTracker;
    d.reject_star_tracker = true;
    return d;
  }
  const int g = matches[0];
  d.result = Isolation::kGyro;
  d.faulty_index = g;
  d.excluded_gyro = test.gyro_ids[g];
  if (working_pair[0] == d.excluded_gyro || working_pair[1] == d.excluded_gyro) {
    d.output_pair = PairWithout(test.gyro_ids, g);
    d.output_switched = true;
  }
  return d;
}

std::string IsolationEvidence(const IsolationTest& test, const IsolationDecision& decision) {
  std::string out;
  auto pair_name = [&](int k) {
    const std::array<int, 2> p = PairWithout(test.gyro_ids, k);
    return absl::StrFormat("[%d,%d]", p[0], p[1]);
  };
  auto item = [&](const std::string& name, double angle, double allowed, bool exceeded) {
    if (!out.empty()) out += "; ";
    out += absl::StrFormat("%s %.1f/%.1f arcsec%s", name, RadToArcsec(angle), RadToArcsec(allowed),
                           exceeded ? " EXCEEDS" : "");
  };
  for (int m = 0; m < 3; ++m) {
    // pair_pair[m] compares the two pairs that hold gyro m, i.e. the pairs without the others.
    const int k = (m + 1) % 3, l = (m + 2) % 3;
    item(pair_name(std::min(k, l)) + "-" + pair_name(std::max(k, l)), test.pair_pair_angle[m],
         test.pair_pair_allowed[m], decision.pair_pair_exceeded[m]);
  }
  if (test.star_available) {
    for (int k = 0; k < 3; ++k) {
      item(pair_name(k) + "-star_tracker", test.pair_star_angle[k], test.pair_star_allowed[k],
           decision.pair_star_exceeded[k]);
    }
  }
  if (test.gyro_star_available) {
    for (int k = 0; k < 3; ++k) {
      out += absl::StrFormat("; gyro %d star-tracker difference chi-square %.1f (fails above %.1f)%s",
                             test.gyro_ids[k], test.gyro_star_nis[k], test.gyro_star_fail,
                             decision.gyro_star_failed[k] ? " FAILS" : "");
    }
  }
  return out;
}

Eigen::Matrix3d MismatchCovariance(const Eigen::MatrixXd& J_x, const Eigen::MatrixXd& G_x,
                                   const Eigen::MatrixXd& J_y, const Eigen::MatrixXd& G_y,
                                   const Eigen::MatrixXd& P, double readout_var) {
  const Eigen::MatrixXd dJ = J_x - J_y;
  const Eigen::MatrixXd dG = G_x - G_y;
  const Eigen::Matrix3d S = dJ * P * dJ.transpose() + readout_var * dG * dG.transpose();
  return 0.5 * (S + S.transpose());
}

InnovationTest TestInnovation(const Eigen::VectorXd& z, const Eigen::MatrixXd& S, double k_d) {
  InnovationTest t;
  const int n = static_cast<int>(z.size());
  if (n == 0) return t;
  Eigen::LLT<Eigen::MatrixXd> llt(S);
  if (llt.info() != Eigen::Success) {
    // Fall back to the printed diagonal form.
    for (int i = 0; i < n; ++i) {
      const double sigma = std::sqrt(std::max(S(i, i), 0.0));
      const double ratio = sigma > 0 ? std::abs(z(i)) / sigma : INFINITY;
      if (ratio > t.worst_ratio) {
        t.worst_ratio = ratio;
        t.worst_index = i;
        t.worst_value = std::abs(z(i));
        t.worst_threshold = k_d * sigma;
      }
    }
    t.passed = t.worst_ratio <= k_d;
    return t;
  }
  const Eigen::MatrixXd L = llt.matrixL();
  Eigen::VectorXd w(n);
  for (int i = 0; i < n; ++i) {
    // Conditional innovation e_i = z_i - sum_{j<i} L_ij w_j with conditional sigma L_ii.
    double e = z(i);
    for (int j = 0; j < i; ++j) e -= L(i, j) * w(j);
    w(i) = e / L(i, i);
    t.nis += w(i) * w(i);
    t.log_det_s += 2.0 * std::log(L(i, i));
    const double ratio = std::abs(w(i));
    if (ratio > t.worst_ratio) {
      t.worst_ratio = ratio;
      t.worst_index = i;
      t.worst_value = std::abs(e);
      t.worst_threshold = k_d * L(i, i);
    }
  }
  t.passed = t.worst_ratio <= k_d;
  return t;
}

}  // namespace esg::estimator
