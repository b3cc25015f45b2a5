// The frame the checkpoint fuzz target gives a restored session (fuzz/fuzz_checkpoint.cc), shared
// with the regression tests of its findings (tests/server/quarantine_test.cc).
#ifndef ESG_FUZZ_NEXT_FRAME_H_
#define ESG_FUZZ_NEXT_FRAME_H_

#include "Eigen/Geometry"
#include "absl/time/time.h"
#include "estimator/session.h"
#include "estimator/spacecraft_config.h"

namespace esg::fuzz {

// A frame 60 s after the session's last one (or at 2019-03-01 before any): every gyro of
// `config` the session runs, with its current spin axis seen from the current attitude, and the
// star tracker at that attitude. A spin axis or attitude that is not finite or not near unit
// length (a fuzzed state) is replaced by z or the identity, so the frame itself is valid.
inline estimator::TelemetryFrame NextFrame(const estimator::EstimationSession& s,
                                           const estimator::SpacecraftConfig& config) {
  estimator::TelemetryFrame f;
  const absl::Time last = s.last_frame_time();
  f.time =
      (last == absl::InfinitePast() ? absl::FromUnixSeconds(1551398400) : last) + absl::Seconds(60);
  const estimator::AttitudeEstimate attitude = s.CurrentAttitude();
  const Eigen::Quaterniond q_in_b =
      attitude.q_in_b.coeffs().allFinite() && attitude.q_in_b.norm() > 0.5
          ? attitude.q_in_b.normalized()
          : Eigen::Quaterniond::Identity();
  for (const estimator::GyroEstimate& g : s.Gyros()) {
    const estimator::GyroConfig* gc = config.FindGyro(g.id);
    if (gc == nullptr || g.id < 1 || g.id > estimator::kMaxGyros) continue;
    Eigen::Vector3d h_k = gc->C_b_k.transpose() * (q_in_b.conjugate() * g.h_in);
    if (!h_k.allFinite() || h_k.norm() < 0.5) h_k = Eigen::Vector3d::UnitZ();
    estimator::GyroReading r;
    r.h_k = h_k.normalized();
    f.gyros[g.id - 1] = r;
  }
  estimator::StarTrackerReading st;
  st.q_in_b = q_in_b;
  st.valid = true;
  f.star_tracker = st;
  return f;
}

}  // namespace esg::fuzz

#endif  // ESG_FUZZ_NEXT_FRAME_H_
