#include "estimator/discovery/model_run.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "estimator/statistics.h"
#include "estimator/rotation.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;

Vector3d StarTrackerCorrection::MisalignmentAt(absl::Time time) const {
  if (cycle_period_s == 0.0) return misalignment_b;
  const double phi = 2.0 * kPi * absl::ToDoubleSeconds(time - cycle_epoch) / cycle_period_s;
  return misalignment_b + cycle_cos_b * std::cos(phi) + cycle_sin_b * std::sin(phi);
}

std::vector<TelemetryFrame> CorrectStarTracker(const std::vector<TelemetryFrame>& frames,
                                               const BodyRates& rates,
                                               const StarTrackerCorrection& correction) {
  std::vector<TelemetryFrame> out = frames;
  if (correction.IsZero()) return out;
  for (size_t i = 0; i < out.size(); ++i) {
    auto& st = out[i].star_tracker;
    if (!st.has_value()) continue;
    const Vector3d w_b = i < rates.best.size() ? rates.best[i] : Vector3d::Zero();
    // q_in_b(t) = q_st(t) (x) Exp(-m(t)) (x) Exp(w_b tau)  (model_run.h).
    st->q_in_b = (st->q_in_b.normalized() * ExpQuaternion(-correction.MisalignmentAt(out[i].time)) *
                  ExpQuaternion(w_b * correction.latency))
                     .normalized();
  }
  for (const ReadingShift& shift : correction.reading_shifts) {
    if (shift.dh_k == nullptr || shift.gyro < 1) continue;
    const size_t g = static_cast<size_t>(shift.gyro - 1);
    for (size_t i = 0; i < out.size() && i < shift.dh_k->size(); ++i) {
      if (g >= out[i].gyros.size() || !out[i].gyros[g].has_value()) continue;
      Vector3d& h_k = out[i].gyros[g]->h_k;
      h_k = (h_k - (*shift.dh_k)[i]).normalized();
    }
  }
  return out;
}

absl::StatusOr<ModelRun> RunModel(const SpacecraftConfig& config, const SessionOptions& options,
                                  const std::vector<TelemetryFrame>& frames,
                                  const ModelRunOptions& run_options) {
  // The likelihoods compared here are those of the model as configured: no adaptive widening, and
  // no gyro excluded for a drift that changes and no star tracker re-referenced after a mount
  // shift (the diagnosis names both as physics).
  SessionOptions as_configured = options;
  as_configured.adaptive_noise = false;
  as_configured.detect_drift_change = false;
  as_configured.realign_star_tracker = false;
  auto created = run_options.start != nullptr
                     ? EstimationSession::FromCheckpoint(config, as_configured, *run_options.start)
                     : EstimationSession::Create(config, as_configured);
  if (!created.ok()) return created.status();
  EstimationSession session = std::move(*created);
  ModelRun run;
  run.steps.reserve(frames.size());
  const int n = static_cast<int>(frames.size());
  std::vector<int> withheld_span(n, -1);
  for (size_t k = 0; k < run_options.withheld.size(); ++k) {
    const auto [a, b] = run_options.withheld[k];
    for (int i = std::max(0, a); i <= std::min(n - 1, b); ++i)
      withheld_span[i] = static_cast<int>(k);
  }
  std::map<int, Matrix3d> C_b_k_config;
  for (const GyroConfig& g : config.gyros) C_b_k_config[g.id] = g.C_b_k;

  const int first_frame = run_options.start != nullptr ? std::max(0, run_options.start_frame) : 0;
  const int end_frame =
      run_options.stop_frame >= 0 ? std::min(n, run_options.stop_frame + 1) : n;
  size_t next_checkpoint = 0;
  while (next_checkpoint < run_options.checkpoint_frames.size() &&
         run_options.checkpoint_frames[next_checkpoint] < first_frame) {
    ++next_checkpoint;
  }
  for (int i = first_frame; i < end_frame; ++i) {
    while (next_checkpoint < run_options.checkpoint_frames.size() &&
           run_options.checkpoint_frames[next_checkpoint] == i) {
      run.checkpoints.push_back(session.ExportCheckpoint());
      ++next_checkpoint;
    }
    const TelemetryFrame& frame = frames[i];
    const bool withheld = withheld_span[i] >= 0;
    session.SetStarTrackerUse(!withheld);
    auto report = session.AddFrame(frame);
    if (!report.ok()) return report.status();
    const bool st_valid = frame.star_tracker.has_value() && frame.star_tracker->valid;
    for (const Event& e : report->events) {
      if (e.kind == Event::Kind::kFilterReset) ++run.resets;
      if (e.kind == Event::Kind::kStarTrackerInnovation ||
          e.kind == Event::Kind::kStarTrackerFault) {
        ++run.rejections;
      }
    }
    std::vector<GyroEstimate> gyros;
    if (report->measurement_step) {
      StepRecord s;
      s.frame = i;
      s.star_tracker_present = st_valid;
      s.withheld = withheld;
      s.m = static_cast<int>(report->star_tracker_innovation.size());
      s.nis_formed = s.m > 0;
      s.accepted = report->star_tracker_used;
      s.nis = report->star_tracker_nis;
      s.log_det_s = report->star_tracker_log_det_s;
      if (s.nis_formed) {
        // The differences come per healthy gyro (has a reading, not faulty), in the session's
        // gyro order (session.h), two components each.
        gyros = session.Gyros();
        int k = 0;
        for (const GyroEstimate& g : gyros) {
          if (g.faulty || !frame.gyros[g.id - 1].has_value()) continue;
          if (2 * k + 1 >= s.m) break;
          GyroInnovation gi;
          gi.id = g.id;
          gi.z = report->star_tracker_innovation.segment<2>(2 * k);
          gi.sigma = report->star_tracker_innovation_sigma.segment<2>(2 * k);
          s.innovations.push_back(gi);
          ++k;
        }
      }
      run.steps.push_back(std::move(s));
    }
    if (withheld && st_valid && report->attitude.valid) {
      const int span = withheld_span[i];
      const int first = run_options.withheld[span].first;
      HeldOutSample h;
      h.frame = i;
      h.span = span;
      h.seconds = absl::ToDoubleSeconds(frame.time - frames[std::max(0, first)].time);
      const Quaterniond q_st = frame.star_tracker->q_in_b.normalized();
      h.error_in = LogQuaternion(q_st * report->attitude.q_in_b.conjugate());
      h.sigma_b = report->attitude.sigma_b;
      if (gyros.empty()) gyros = session.Gyros();
      const Matrix3d C_in_b_st = q_st.toRotationMatrix();
      for (const GyroEstimate& g : gyros) {
        const auto& reading = frame.gyros[g.id - 1];
        if (!reading.has_value() || g.faulty) continue;
        const Matrix3d C_b_k = ExpMatrix(g.misalignment_b) * C_b_k_config[g.id];
        const Vector3d h_et_in = (C_in_b_st * C_b_k * reading->h_k.normalized()).normalized();
        HeldOutGyroError e;
        e.id = g.id;
        e.error_in = h_et_in - g.h_in;
        e.sigma = std::sqrt(0.5 * g.spin_axis_sigma.squaredNorm());
        h.gyros.push_back(e);
      }
      run.held_out.push_back(std::move(h));
    }
  }
  run.gyros = session.Gyros();
  for (const GyroEstimate& g : run.gyros) {
    run.coefficient_covariance.push_back(session.CoefficientCovariance(g.id));
  }
  return run;
}

namespace {

double Cap(int m, double outlier_p) {
  // Cached quantiles for the usual sizes.
  static thread_local std::map<std::pair<int, double>, double> cache;
  auto key = std::make_pair(m, outlier_p);
  auto it = cache.find(key);
  if (it != cache.end()) return it->second;
  const double c = ChiSquareQuantile(1.0 - outlier_p, m);
  cache[key] = c;
  return c;
}

}  // namespace

std::vector<double> StepDeviance(const ModelRun& run, double outlier_p) {
  std::vector<double> out(run.steps.size(), 0.0);
  double last_log_det = 0.0;
  int last_m = 0;
  bool have_last = false;
  for (size_t i = 0; i < run.steps.size(); ++i) {
    const StepRecord& s = run.steps[i];
    if (s.withheld || !s.star_tracker_present) continue;
    if (s.nis_formed) {
      out[i] = std::min(s.nis, Cap(s.m, outlier_p)) + s.log_det_s;
      last_log_det = s.log_det_s;
      last_m = s.m;
      have_last = true;
    } else if (have_last) {
      out[i] = Cap(last_m, outlier_p) + last_log_det;
    }
  }
  return out;
}

Deviance ComputeDeviance(const ModelRun& run, double outlier_p) {
  Deviance d;
  double last_log_det = 0.0;
  int last_m = 0;
  bool have_last = false;
  for (const StepRecord& s : run.steps) {
    if (s.withheld || !s.star_tracker_present) continue;
    if (s.nis_formed) {
      const double cap = Cap(s.m, outlier_p);
      const double nis = std::min(s.nis, cap);
      if (s.nis >= cap) ++d.capped;
      d.value += nis + s.log_det_s;
      d.nis_sum += nis;
      d.components += s.m;
      ++d.steps;
      last_log_det = s.log_det_s;
      last_m = s.m;
      have_last = true;
    } else if (have_last) {
      const double cap = Cap(last_m, outlier_p);
      d.value += cap + last_log_det;
      d.nis_sum += cap;
      d.components += last_m;
      ++d.steps;
      ++d.capped;
    }
  }
  return d;
}

}  // namespace esg::estimator::discovery
