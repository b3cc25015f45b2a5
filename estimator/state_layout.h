// StateLayout: the one owner of the estimation filter's error-state indices, in the manner of
// KF-GINS's state ids, but built at run time because the running gyros and the model's free
// terms vary. The states shared by all gyros come first:
//
//   Latency()    1  error of the star tracker's latency (when estimated) [s]
//
// then each running gyro owns one contiguous block, in the order of the session's gyros
// (working pair first; a gyro switched on later appends its block, so earlier indices hold);
// within a block, in this order:
//
//   SpinAxis(i)  2  dh_g: spin-axis direction error in the gyro's tangent basis (t1, t2) [rad]
//   Drift(i)     2  dw_int_g: residual random-walk drift of eq. (11), same basis [rad/s]
//                   (only with model 11)
//   Theta(i)     n  the free coefficients of the gyro's drift, in two runs:
//                     n1 = ThetaCount(i): errors of the free drift coefficients of eq. (1)/(10)
//                     (k0, C1, C2, mu, nu whose modelSigma > 0), in the order of
//                     FreeCoefficients(i) [rad/s];
//     Basis(i)        n2 = BasisCount(i): errors of the free basis terms (basis_term.h, those of
//                     GyroConfig::basis_terms with sigma > 0), in the order of FreeBasisTerms(i)
//                     [rad/s per unit of the term's s]; Basis(i) = Theta(i) + ThetaCount(i)
//   Phi(i)       3  gyro-to-star-tracker misalignment, small rotation in body axes [rad]
//                   (when misalignmentSigma > 0)
//
// Invariant used by the propagation: the residual drift, the free coefficients and the free basis
// terms, the states that move the spin axis (d(dh)/dt depends on them), follow SpinAxis(i)
// contiguously: [SpinAxisDrivers(i), SpinAxisDrivers(i) + SpinAxisDriverCount(i)).
#ifndef ESG_ESTIMATOR_STATE_LAYOUT_H_
#define ESG_ESTIMATOR_STATE_LAYOUT_H_

#include <vector>

namespace esg::estimator {

class StateLayout {
 public:
  static constexpr int kSpinAxisSize = 2;
  static constexpr int kDriftSize = 2;
  static constexpr int kPhiSize = 3;

  // A layout without gyros (size() == 0, or 1 with the latency). `random_walk`: the model holds
  // eq. (11), so every gyro block carries the residual-drift states. `latency`: the star
  // tracker's latency is a state.
  StateLayout() = default;
  explicit StateLayout(bool random_walk, bool latency = false)
      : random_walk_(random_walk), latency_(latency), size_(latency ? 1 : 0) {}

  // Appends the block of the next running gyro and returns its gyro index. `free_coefficients`
  // are drift_model.h theta indices (calibration_model.h FreeCoefficients), one state each;
  // `free_basis_terms` indices into the gyro's GyroConfig::basis_terms (FreeBasisTerms of
  // calibration_model.h), one state each.
  int AddGyro(std::vector<int> free_coefficients, bool estimate_phi,
              std::vector<int> free_basis_terms = {});

  // Total number of states.
  int size() const { return size_; }
  int gyro_count() const { return static_cast<int>(blocks_.size()); }
  // Whether the residual-drift states of eq. (11) exist; DriftSize() is their count per gyro.
  bool has_drift() const { return random_walk_; }
  int DriftSize() const { return random_walk_ ? kDriftSize : 0; }
  // Whether the star tracker's latency is a state; Latency() is its index.
  bool has_latency() const { return latency_; }
  // Precondition: has_latency().
  int Latency() const;

  // First index and size of gyro i's block (0 <= i < gyro_count()).
  int GyroBegin(int i) const { return blocks_[i].begin; }
  int GyroSize(int i) const;

  // First index of each part of gyro i's block (sizes in the file comment).
  int SpinAxis(int i) const { return blocks_[i].begin; }
  // Precondition: has_drift().
  int Drift(int i) const;
  int Theta(int i) const { return blocks_[i].begin + kSpinAxisSize + DriftSize(); }
  int ThetaCount(int i) const { return static_cast<int>(blocks_[i].free.size()); }
  // drift_model.h theta index of state Theta(i) + j, for j < ThetaCount(i).
  const std::vector<int>& FreeCoefficients(int i) const { return blocks_[i].free; }
  // First state of gyro i's free basis terms, and their count.
  int Basis(int i) const { return Theta(i) + ThetaCount(i); }
  int BasisCount(int i) const { return static_cast<int>(blocks_[i].free_basis.size()); }
  // Index into GyroConfig::basis_terms of state Basis(i) + j, for j < BasisCount(i).
  const std::vector<int>& FreeBasisTerms(int i) const { return blocks_[i].free_basis; }
  bool HasPhi(int i) const { return blocks_[i].estimate_phi; }
  // Precondition: HasPhi(i).
  int Phi(int i) const;

  // The states that drive the spin axis in propagation: residual drift, then free coefficients,
  // then free basis terms.
  int SpinAxisDrivers(int i) const { return blocks_[i].begin + kSpinAxisSize; }
  int SpinAxisDriverCount(int i) const { return DriftSize() + ThetaCount(i) + BasisCount(i); }

 private:
  struct Block {
    int begin = 0;
    std::vector<int> free;
    std::vector<int> free_basis;
    bool estimate_phi = false;
  };
  bool random_walk_ = false;
  bool latency_ = false;
  std::vector<Block> blocks_;
  int size_ = 0;
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_STATE_LAYOUT_H_
