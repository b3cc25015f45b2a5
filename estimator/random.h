// Seeded, platform-independent random numbers for the simulator (no hidden
// randomness). std::mt19937_64 is fully specified by the C++ standard, but the standard
// distributions (std::normal_distribution, std::uniform_real_distribution) are implementation
// defined; the draws below are written out here so that one seed gives the same numbers, bit for
// bit, with every standard library. Separate streams per noise source come from DeriveSeed.
#ifndef ESG_ESTIMATOR_RANDOM_H_
#define ESG_ESTIMATOR_RANDOM_H_

#include <cmath>
#include <cstdint>
#include <random>

#include "Eigen/Core"

namespace esg::estimator {

// SplitMix64 finaliser (Steele, Lea, Flood 2014): a bijective 64-bit mix.
constexpr uint64_t SplitMix64(uint64_t x) {
  x += 0x9E3779B97F4A7C15ULL;
  x = (x ^ (x >> 30)) * 0xBF58476D1CE4E5B9ULL;
  x = (x ^ (x >> 27)) * 0x94D049BB133111EBULL;
  return x ^ (x >> 31);
}

// Seed of stream `stream` derived from a master seed; different streams give unrelated sequences,
// so adding draws to one noise source never shifts another.
constexpr uint64_t DeriveSeed(uint64_t seed, uint64_t stream) {
  return SplitMix64(SplitMix64(seed) ^ SplitMix64(0xA5A5A5A5A5A5A5A5ULL + stream));
}

class Rng {
 public:
  explicit Rng(uint64_t seed) : engine_(seed) {}

  // Uniform in [0, 1) with 53 random bits.
  double Uniform() { return static_cast<double>(engine_() >> 11) * 0x1.0p-53; }
  // Uniform in [a, b).
  double Uniform(double a, double b) { return a + (b - a) * Uniform(); }

  // Standard normal by the Marsaglia polar method (pairs; the second value is kept for the
  // next call).
  double Normal() {
    if (has_spare_) {
      has_spare_ = false;
      return spare_;
    }
    double u, v, s;
    do {
      u = 2.0 * Uniform() - 1.0;
      v = 2.0 * Uniform() - 1.0;
      s = u * u + v * v;
    } while (s >= 1.0 || s == 0.0);
    const double factor = std::sqrt(-2.0 * std::log(s) / s);
    spare_ = v * factor;
    has_spare_ = true;
    return u * factor;
  }

  Eigen::Vector3d Normal3() {
    const double x = Normal();
    const double y = Normal();
    const double z = Normal();
    return Eigen::Vector3d(x, y, z);
  }

  // Uniformly distributed unit vector.
  Eigen::Vector3d UnitVector() {
    while (true) {
      const Eigen::Vector3d v = Normal3();
      const double n = v.norm();
      if (n > 1e-12) return v / n;
    }
  }

 private:
  std::mt19937_64 engine_;
  double spare_ = 0.0;
  bool has_spare_ = false;
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_RANDOM_H_
