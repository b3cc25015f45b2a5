#include "estimator/eclipse.h"

#include <algorithm>
#include <cmath>

namespace esg::estimator {

double SunlitFraction(const Eigen::Vector3d& r_in_km, const Eigen::Vector3d& sun_in_km) {
  const Eigen::Vector3d to_sun_km = sun_in_km - r_in_km;
  const double r_km = r_in_km.norm();
  const double d_km = to_sun_km.norm();
  // Inside the Earth or at the sun: no geometry to speak of; the caller's orbit was refused
  // before (orbit.h), so this only guards the arithmetic.
  if (!(r_km > kEarthEquatorialRadiusKm) || !(d_km > kSunRadiusKm)) return 0.0;
  const double a = std::asin(kSunRadiusKm / d_km);
  const double b = std::asin(kEarthEquatorialRadiusKm / r_km);
  // The angle between the directions to the Earth's centre (-r) and to the sun's.
  const double cos_c = std::clamp(-r_in_km.dot(to_sun_km) / (r_km * d_km), -1.0, 1.0);
  const double c = std::acos(cos_c);
  if (c >= a + b) return 1.0;
  if (c <= b - a) return 0.0;
  if (c <= a - b) return 1.0 - (b * b) / (a * a);
  const double x = (c * c + a * a - b * b) / (2.0 * c);
  const double y = std::sqrt(std::max(a * a - x * x, 0.0));
  const double overlap = a * a * std::acos(std::clamp(x / a, -1.0, 1.0)) +
                         b * b * std::acos(std::clamp((c - x) / b, -1.0, 1.0)) - c * y;
  return std::clamp(1.0 - overlap / (M_PI * a * a), 0.0, 1.0);
}

}  // namespace esg::estimator
