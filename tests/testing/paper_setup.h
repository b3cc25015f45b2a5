// A spacecraft set up like the paper's flight test (section 3), for estimator tests: four gyros
// (gyro 4 the cold spare), k0 a few tenths of deg/h with a 0.3 deg/h prior, C1/C2 priors 0.1
// deg/h, star tracker 5/5/30 arcsec, readout 3 arcsec, 60 s telemetry, 8 Hz integration.
#ifndef ESG_TESTS_TESTING_PAPER_SETUP_H_
#define ESG_TESTS_TESTING_PAPER_SETUP_H_

#include <cstdint>

#include "estimator/attitude_profile.h"
#include "estimator/rotation.h"
#include "estimator/simulator.h"
#include "estimator/spacecraft_config.h"
#include "estimator/units.h"

namespace esg::testing {

inline estimator::SpacecraftConfig PaperConfig(bool estimate_c = true,
                                               double misalignment_sigma_arcsec = 60.0) {
  using namespace esg::estimator;
  SpacecraftConfig c;
  c.spacecraft_id = "TEST-1";
  const double k0_deg_h[4] = {0.25, -0.18, 0.31, 0.2};
  const Eigen::Vector3d mount[4] = {Eigen::Vector3d(0, 0, 0), Eigen::Vector3d(0.3, -0.2, 0.5),
                                    Eigen::Vector3d(-0.4, 0.6, 0.1), Eigen::Vector3d(1.0, 0.5, -0.7)};
  for (int i = 0; i < 4; ++i) {
    GyroConfig g;
    g.id = i + 1;
    g.C_b_k = ExpMatrix(mount[i]);
    g.model.k0 = DegPerHourToRadPerSec(k0_deg_h[i]);
    g.model_sigma.k0 = DegPerHourToRadPerSec(0.3);
    if (estimate_c) {
      g.model_sigma.C1.setConstant(DegPerHourToRadPerSec(0.1));
      g.model_sigma.C2.setConstant(DegPerHourToRadPerSec(0.1));
    }
    g.misalignment_sigma = ArcsecToRad(misalignment_sigma_arcsec);
    c.gyros.push_back(g);
  }
  c.working_pair = {1, 2};
  c.reserve_pair = {1, 3};
  c.star_tracker.noise = Eigen::Vector3d(ArcsecToRad(5), ArcsecToRad(5), ArcsecToRad(30));
  c.readout_noise = ArcsecToRad(3);
  c.random_walk = DegPerHourSqrtHourToSi(0.001);
  return c;
}

// The paper's calibration flight (section 3) simulated on PaperConfig(): the a-priori k0 of each
// gyro wrong by 0.1 deg/h (alternating sign), rotor displacements of paper size in gyros 1-3, gyro
// 2 misaligned by (20, -30, 15) arcsec, `hours` of the named attitude profile.
inline estimator::SimulationSpec PaperFlight(uint64_t seed, double hours,
                                             const char* profile = "calibration") {
  using namespace esg::estimator;
  SimulationSpec spec;
  spec.config = PaperConfig();
  spec.duration = HoursToSeconds(hours);
  spec.seed = seed;
  spec.profile = *MakeNamedProfile(profile, spec.duration, seed);
  for (int i = 0; i < 4; ++i) {
    DriftCoefficients d = spec.config.gyros[i].model;
    d.k0 += DegPerHourToRadPerSec(0.1 * (i % 2 ? 1 : -1));
    spec.gyros[i].drift = d;
  }
  spec.gyros[0].rotor_displacement_k = Eigen::Vector3d(1.0e-6, -1.5e-6, 0.8e-6);
  spec.gyros[1].rotor_displacement_k = Eigen::Vector3d(-0.7e-6, 0.5e-6, 1.2e-6);
  spec.gyros[2].rotor_displacement_k = Eigen::Vector3d(0.5e-6, 1.0e-6, -1.0e-6);
  spec.gyros[1].misalignment_b = Eigen::Vector3d(ArcsecToRad(20), ArcsecToRad(-30), ArcsecToRad(15));
  return spec;
}

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_PAPER_SETUP_H_
