#include <cstdio>
#include "estimator/session.h"
#include "estimator/simulator.h"
#include "tests/testing/paper_setup.h"
using namespace esg::estimator;
int main(int argc, char** argv) {
  const double hours = argc > 1 ? atof(argv[1]) : 24;
  const char* model = argc > 2 ? argv[2] : "10+11";
  const uint64_t seed = argc > 3 ? atoi(argv[3]) : 1;
  SimulationSpec spec;
  spec.config = esg::testing::PaperConfig(true, getenv("MIS") ? atof(getenv("MIS")) : 60.0);
  if (getenv("RO")) spec.config.readout_noise = ArcsecToRad(atof(getenv("RO")));
  if (getenv("QUIET")) { spec.config.star_tracker.noise *= 0.01; spec.config.readout_noise *= 0.01; spec.config.random_walk = 0; }
  spec.duration = hours * 3600;
  spec.seed = seed;
  spec.profile = *MakeNamedProfile("calibration", spec.duration, seed);
  const bool clean = getenv("CLEAN") != nullptr;
  if (!clean) {
  // Truth: k0 off from the prior by ~0.1 deg/h, displacement terms of paper size.
  for (int i = 0; i < 4; ++i) {
    DriftCoefficients d = spec.config.gyros[i].model;
    d.k0 += DegPerHourToRadPerSec(0.1 * (i % 2 ? 1 : -1));
    spec.gyros[i].drift = d;
  }
  spec.gyros[0].rotor_displacement_k = Eigen::Vector3d(1.0e-6, -1.5e-6, 0.8e-6);
  spec.gyros[1].rotor_displacement_k = Eigen::Vector3d(-0.7e-6, 0.5e-6, 1.2e-6);
  spec.gyros[2].rotor_displacement_k = Eigen::Vector3d(0.5e-6, 1.0e-6, -1.0e-6);
  spec.gyros[1].misalignment_b = Eigen::Vector3d(ArcsecToRad(20), ArcsecToRad(-30), ArcsecToRad(15));
  spec.star_tracker.outlier_probability = 0.01;
  spec.star_tracker.outlier_size = ArcminToRad(1);
  }
  auto sim = Simulate(spec);
  if (!sim.ok()) { printf("%s\n", sim.status().ToString().c_str()); return 1; }
  SessionOptions opt; opt.model = *ParseModel(model); opt.use_autonomous_measurements = getenv("NOAVT") == nullptr;
  auto s = EstimationSession::Create(spec.config, opt);
  if (!s.ok()) { printf("%s\n", s.status().ToString().c_str()); return 1; }
  int rejected = 0, outliers = 0, outliers_rejected = 0, clean_rejected = 0, steps = 0;
  double max_err = 0;
  for (size_t i = 0; i < sim->recording.frames.size(); ++i) {
    if (i == 1 && getenv("NOST")) s->SetStarTrackerUse(false);
    auto r = s->AddFrame(sim->recording.frames[i]);
    if (!r.ok()) { printf("frame %zu: %s\n", i, r.status().ToString().c_str()); return 1; }
    bool rej = false;
    for (auto& e : r->events) if (e.kind == Event::Kind::kStarTrackerInnovation || e.kind == Event::Kind::kStarTrackerFault) rej = true;
    if (r->measurement_step) ++steps;
    if (sim->truth[i].star_tracker_outlier) { ++outliers; if (rej) ++outliers_rejected; }
    else if (rej) ++clean_rejected;
    if (rej) ++rejected;
    const double err = RadToArcsec(RotationAngle(r->attitude.q_in_b, sim->truth[i].q_in_b));
    if (i > 10) max_err = std::max(max_err, err);
    if (getenv("VERBOSE") && i < 30) { printf("%zu z=", i); for (int k=0;k<r->star_tracker_innovation.size();++k) printf(" %.1f/%.1f", RadToArcsec(r->star_tracker_innovation(k)), RadToArcsec(r->star_tracker_innovation_sigma(k))); for (int k=0;k<r->autonomous_innovation.size();++k) printf(" avt %.2e/%.2e", r->autonomous_innovation(k), r->autonomous_innovation_sigma(k)); for (auto& e: r->events) printf(" [%s %s %.1f>%.1f]", EventKindName(e.kind), e.subsystem.c_str(), e.value, e.threshold); printf(" err=%.1f", err); for (auto& g : s->Gyros()) { Eigen::Vector3d ht = sim->truth[i].gyros[g.id-1]->h_in; printf(" | g%d dh=%.1f\" sig %.1f %.1f", g.id, RadToArcsec((ht-g.h_in).norm()), RadToArcsec(g.spin_axis_sigma(0)), RadToArcsec(g.spin_axis_sigma(1))); } printf("\n"); }
    if (i % 120 == 0) {
      auto g = s->Gyros();
      printf("t=%5.1fh state=%s att err %.1f\" sigma(%.1f %.1f %.1f) k0err1=%.4f (%.4f) ", i/60.0, SessionStateName(r->state), err,
        RadToArcsec(r->attitude.sigma_b.x()),RadToArcsec(r->attitude.sigma_b.y()),RadToArcsec(r->attitude.sigma_b.z()),
        RadPerSecToDegPerHour(g[0].coefficients.k0 - sim->true_coefficients[0]->k0), RadPerSecToDegPerHour(g[0].sigma.k0));
      printf("C1err1=%.4f (%.4f)\n", RadPerSecToDegPerHour((g[0].coefficients.C1 - sim->true_coefficients[0]->C1).norm()), RadPerSecToDegPerHour(g[0].sigma.C1.norm()));
    }
  }
  printf("steps %d rejected %d outliers %d rejected-outliers %d clean-rejected %d max att err %.1f\"\n", steps, rejected, outliers, outliers_rejected, clean_rejected, max_err);
  for (auto& g : s->Gyros()) {
    auto& t = *sim->true_coefficients[g.id-1];
    printf("gyro %d k0 %.4f true %.4f sig %.4f | ", g.id, RadPerSecToDegPerHour(g.coefficients.k0), RadPerSecToDegPerHour(t.k0), RadPerSecToDegPerHour(g.sigma.k0));
    for (int j=0;j<3;++j) printf("C1%d %.3f/%.3f/%.3f ", j, RadPerSecToDegPerHour(g.coefficients.C1(j)), RadPerSecToDegPerHour(t.C1(j)), RadPerSecToDegPerHour(g.sigma.C1(j)));
    for (int j=0;j<3;++j) printf("C2%d %.3f/%.3f/%.3f ", j, RadPerSecToDegPerHour(g.coefficients.C2(j)), RadPerSecToDegPerHour(t.C2(j)), RadPerSecToDegPerHour(g.sigma.C2(j)));
    printf("\n   mis %.1f %.1f %.1f sig %.1f %.1f %.1f   relsig:", RadToArcsec(g.misalignment_b.x()), RadToArcsec(g.misalignment_b.y()), RadToArcsec(g.misalignment_b.z()),
      RadToArcsec(g.misalignment_sigma_b.x()), RadToArcsec(g.misalignment_sigma_b.y()), RadToArcsec(g.misalignment_sigma_b.z()));
    for (auto [i, r] : s->RelativeSigma(g.id)) printf(" %s=%.3f", CoefficientName(i), r);
    printf("\n");
  }
}
