// The per-gyro block arithmetic of the error state (state_layout.h); nothing else in the
// estimator adds offsets.
#include "estimator/state_layout.h"

#include <cassert>
#include <utility>

namespace esg::estimator {

int StateLayout::AddGyro(std::vector<int> free_coefficients, bool estimate_phi,
                         std::vector<int> free_basis_terms) {
  Block b;
  b.begin = size_;
  b.free = std::move(free_coefficients);
  b.free_basis = std::move(free_basis_terms);
  b.estimate_phi = estimate_phi;
  blocks_.push_back(std::move(b));
  const int i = gyro_count() - 1;
  size_ += GyroSize(i);
  return i;
}

int StateLayout::GyroSize(int i) const {
  return kSpinAxisSize + DriftSize() + ThetaCount(i) + BasisCount(i) + (HasPhi(i) ? kPhiSize : 0);
}

int StateLayout::Drift(int i) const {
  assert(random_walk_);
  return blocks_[i].begin + kSpinAxisSize;
}

int StateLayout::Latency() const {
  assert(latency_);
  return 0;
}

int StateLayout::Phi(int i) const {
  assert(blocks_[i].estimate_phi);
  return Basis(i) + BasisCount(i);
}

}  // namespace esg::estimator
