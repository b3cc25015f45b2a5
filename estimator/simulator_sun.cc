#include "estimator/simulator_sun.h"

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "estimator/eclipse.h"
#include "estimator/orbit.h"
#include "estimator/simulator.h"
#include "estimator/status_macros.h"
#include "estimator/sun_direction.h"

namespace esg::estimator::simulator_internal {

using Eigen::Vector3d;

absl::StatusOr<SunNodes> SunNodes::Make(absl::Time start, double duration_s,
                                        const std::optional<OrbitalOptions>& earth_shadow) {
  SunNodes nodes;
  nodes.start_ = start;
  nodes.earth_shadow_ = earth_shadow;
  const int64_t n = static_cast<int64_t>(std::ceil(duration_s / kSunNodeSpacingS)) + 2;
  nodes.s_in_.reserve(n);
  for (int64_t i = 0; i < n; ++i) {
    const absl::Time t = start + absl::Seconds(kSunNodeSpacingS * i);
    ASSIGN_OR_RETURN(Vector3d s_in, SunDirection_in(t));
    nodes.s_in_.push_back(s_in);
    if (earth_shadow) {
      ASSIGN_OR_RETURN(Vector3d sun_km, SunPosition_in_km(t));
      nodes.sun_in_km_.push_back(sun_km);
    }
  }
  return nodes;
}

Vector3d SunNodes::At(double t) const {
  const double x = std::clamp(t / kSunNodeSpacingS, 0.0, static_cast<double>(s_in_.size() - 2));
  const size_t i = static_cast<size_t>(x);
  const double f = x - static_cast<double>(i);
  const Vector3d s_in = ((1.0 - f) * s_in_[i] + f * s_in_[i + 1]).normalized();
  if (!earth_shadow_) return s_in;
  const OrbitalOptions& o = *earth_shadow_;
  const OrbitState state =
      CircularOrbitState(o.inclination, o.raan, o.period, o.arg_latitude0, start_, t);
  return SunlitFraction(state.r_in_km, (1.0 - f) * sun_in_km_[i] + f * sun_in_km_[i + 1]) * s_in;
}

double FaceIllumination(const Vector3d& s_b, int face_axis, double face_sign) {
  if (face_axis == kSunlitFaceAxis) return std::min(1.0, s_b.norm());
  return std::max(0.0, face_sign * s_b(face_axis));
}

}  // namespace esg::estimator::simulator_internal
