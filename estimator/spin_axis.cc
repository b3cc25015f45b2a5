#include "estimator/spin_axis.h"

#include <algorithm>
#include <cmath>

#include "estimator/rotation.h"

namespace esg::estimator {

using Eigen::Vector3d;

Vector3d SpinAxisRate_in(const Vector3d& dw_in, const Vector3d& h_in) {
  // docs/physics.md, "Drift model".
  return dw_in.cross(h_in);
}

Vector3d StepSpinAxis(const Vector3d& h_in, const Vector3d& dw_in, double dt) {
  return (ExpMatrix(dw_in * dt) * h_in).normalized();
}

Vector3d SlerpUnit(const Vector3d& a, const Vector3d& b, double s) {
  const double c = std::clamp(a.dot(b), -1.0, 1.0);
  const double angle = std::acos(c);
  if (angle < 1e-9) return ((1.0 - s) * a + s * b).normalized();
  const double sin_angle = std::sin(angle);
  return ((std::sin((1.0 - s) * angle) / sin_angle) * a + (std::sin(s * angle) / sin_angle) * b)
      .normalized();
}

}  // namespace esg::estimator
