#include "estimator/discovery/deviation.h"

#include <algorithm>
#include <cmath>
#include <map>

#include "Eigen/Geometry"
#include "absl/strings/str_format.h"
#include "estimator/discovery/report.h"
#include "estimator/drift_model.h"
#include "estimator/rotation.h"
#include "estimator/session.h"
#include "estimator/spin_axis.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Matrix2d;
using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector2d;
using Eigen::Vector3d;

namespace {

// Largest turn of the attitude within one integration substep: the drift in inertial axes turns
// with the case, and the midpoint rule's relative error is (turn)^2 / 24 (3e-6 at 0.5 deg).
constexpr double kMaxSubstepTurn = 0.5 * kRadPerDeg;
constexpr int kMinSamples = 10;

}  // namespace

double RegressorRms(const DeviationSeries& series, const ScalarFunction& s) {
  double sum = 0.0, time = 0.0;
  for (const TrajectoryStep& st : series.steps) {
    const double v = s(st.inputs);
    sum += v * v * st.dt;
    time += st.dt;
  }
  return time > 0.0 ? std::sqrt(sum / time) : 0.0;
}

std::vector<Vector2d> Signature(const DeviationSeries& series, const DriftFunction& drift_k) {
  std::vector<Vector2d> out(series.sample_end.size(), Vector2d::Zero());
  Vector3d sum = Vector3d::Zero();
  size_t step = 0;
  for (size_t k = 0; k < series.sample_end.size(); ++k) {
    for (; step < static_cast<size_t>(series.sample_end[k]); ++step) {
      const TrajectoryStep& s = series.steps[step];
      sum += (s.C_in_k * drift_k(s.inputs)).cross(s.h_in) * s.dt;
    }
    out[k] = Vector2d(series.u1.dot(sum), series.u2.dot(sum));
  }
  return out;
}

std::vector<Vector2d> ReadoutSignature(const DeviationSeries& series, const Matrix3d& E) {
  std::vector<Vector2d> out(series.h_k.size(), Vector2d::Zero());
  Vector3d first = Vector3d::Zero();
  for (size_t k = 0; k < series.h_k.size(); ++k) {
    const Vector3d& h = series.h_k[k];
    const Vector3d dh_k = (Matrix3d::Identity() - h * h.transpose()) * E * h;
    const Vector3d dh_in = series.C_k_in[k].transpose() * dh_k;
    if (k == 0) first = dh_in;
    out[k] = Vector2d(series.u1.dot(dh_in - first), series.u2.dot(dh_in - first));
  }
  return out;
}

DriftFunction ModelDrift(const DriftCoefficients& coefficients,
                         const std::vector<BasisTerm>& basis_terms) {
  return [coefficients, basis_terms](const BasisInputs& in) -> Vector3d {
    return DriftRate_k(coefficients, in.h_k) + BasisDriftSum_k(basis_terms, in);  // eq. (1), (10)
  };
}

CarriedAttitude AttitudeAlongRecording(const std::vector<TelemetryFrame>& frames,
                                       const BodyRates& rates, const ModelRun& run) {
  const int n = static_cast<int>(frames.size());
  CarriedAttitude out;
  // Samples: the star tracker the model's filter applied (in sample, accepted).
  out.usable.assign(n, false);
  for (const StepRecord& s : run.steps) {
    if (s.star_tracker_present && s.accepted && !s.withheld && s.frame >= 0 && s.frame < n) {
      out.usable[s.frame] = true;
    }
  }
  // Attitude at every frame: the star tracker where usable, else carried from the previous frame
  // by the gyros' measured rotation over the step.
  out.q_in_b.assign(n, Quaterniond::Identity());
  out.known.assign(n, false);
  for (int i = 0; i < n; ++i) {
    if (out.usable[i]) {
      out.q_in_b[i] = frames[i].star_tracker->q_in_b.normalized();
      out.known[i] = true;
    } else if (i > 0 && out.known[i - 1]) {
      const bool step_valid = static_cast<size_t>(i - 1) < rates.gyro_step_valid.size() &&
                              rates.gyro_step_valid[i - 1];
      out.q_in_b[i] = step_valid
                          ? (out.q_in_b[i - 1] * ExpQuaternion(rates.gyro_step[i - 1])).normalized()
                          : out.q_in_b[i - 1];
      out.known[i] = true;
    }
  }
  return out;
}

namespace {

// A gyro's model as the run left it: the drift coefficients and the mounting (C_b_k with the
// estimated misalignment, session.h: C_b_k = Exp(phi) C_b_k) of its final estimate, else the
// configured ones; its basis terms with the channel terms (basis_term.h kChannel) at the run's
// estimates (the filter calibrates them).
struct GyroModel {
  DriftCoefficients coefficients;
  std::vector<BasisTerm> basis_terms;
  Matrix3d C_b_k;
  bool any_channel = false;
};
GyroModel GyroModelOf(const GyroConfig& gc, const std::vector<GyroEstimate>& estimates, int id) {
  GyroModel m;
  m.coefficients = gc.model;
  m.basis_terms = gc.basis_terms;
  m.C_b_k = gc.C_b_k;
  for (const GyroEstimate& e : estimates) {
    if (e.id != id) continue;
    m.coefficients = e.coefficients;
    m.C_b_k = ExpMatrix(e.misalignment_b) * gc.C_b_k;  // session.h: C_b_k = Exp(phi) C_b_k
  }
  for (size_t k = 0; k < m.basis_terms.size(); ++k) {
    if (m.basis_terms[k].kind != BasisKind::kChannel) continue;
    m.any_channel = true;
    for (const GyroEstimate& e : estimates) {
      if (e.id == id && e.basis_terms.size() == m.basis_terms.size()) {
        m.basis_terms[k].value = e.basis_terms[k].value;
      }
    }
  }
  return m;
}

// The samples of d (the frames in `samples`: their times, readings h_k and C_k_in) and the
// substeps from the first sample to the last (d.steps, at most kMaxSubstepTurn of attitude turn
// each; the reading held where one is missing, the suspension voltages interpolated), with the
// channels' states as the filter holds and lags them (channel_signal.h).
void AddTrajectory(const GyroConfig& gc, const GyroModel& m,
                   const std::vector<TelemetryFrame>& frames, const BodyRates& rates,
                   const std::vector<Quaterniond>& q_in_b, const std::vector<int>& samples,
                   ChannelSignals& channels, DeviationSeries& d) {
  const int id = d.gyro;
  const Matrix3d& C_b_k = m.C_b_k;
  const absl::Time t0 = frames.front().time;
  auto reading = [&](int i) -> const std::optional<GyroReading>& { return frames[i].gyros[id - 1]; };
  // A reading as the model's filter uses it: corrected for the configured readout distortion.
  auto h_of = [&](int i) { return CorrectReadout(gc, reading(i)->h_k); };
  Vector3d h_last = h_of(samples.front());
  std::optional<Vector3d> u_last_v;
  auto voltages_v = [&](int i) -> std::optional<Vector3d> {
    if (reading(i).has_value() && reading(i)->u_k_mv.has_value()) {
      return *reading(i)->u_k_mv * kVoltsPerMv;
    }
    return std::nullopt;
  };
  u_last_v = voltages_v(samples.front());
  size_t next_sample = 0;
  if (!channels.empty()) {
    for (int i = 0; i < samples.front(); ++i) {
      channels.Advance(frames[i]);
      channels.Ahead(frames[i + 1]);
    }
  }
  for (int i = samples.front(); i <= samples.back(); ++i) {
    const ChannelSignals* held = nullptr;
    if (!channels.empty()) {
      channels.Advance(frames[i]);
      // The next frame's values end the lines the steps up to it read, as the filter's
      // propagation to that frame does (channel_signal.h Ahead).
      if (i < samples.back()) channels.Ahead(frames[i + 1]);
      d.channel_states.push_back(std::make_shared<const ChannelSignals>(channels));
      held = d.channel_states.back().get();
    }
    const Vector3d h_i = reading(i).has_value() ? h_of(i) : h_last;
    if (auto u = voltages_v(i)) u_last_v = u;
    if (next_sample < samples.size() && samples[next_sample] == i) {
      d.sample_end.push_back(static_cast<int>(d.steps.size()));
      d.frames.push_back(i);
      d.hours.push_back(HoursSince(frames[i].time, t0));
      d.h_k.push_back(h_i);
      d.C_k_in.push_back((q_in_b[i].toRotationMatrix() * C_b_k).transpose());
      ++next_sample;
    }
    h_last = h_i;
    if (i == samples.back()) break;
    const int j = i + 1;
    const Vector3d h_j = reading(j).has_value() ? h_of(j) : h_i;
    const double span = absl::ToDoubleSeconds(frames[j].time - frames[i].time);
    const Quaterniond& qa = q_in_b[i];
    Quaterniond qb = q_in_b[j];
    if (qa.dot(qb) < 0.0) qb.coeffs() *= -1.0;
    const Vector3d turn_b = LogQuaternion(qa.conjugate() * qb);
    const int substeps = std::max(1, static_cast<int>(std::ceil(turn_b.norm() / kMaxSubstepTurn)));
    // The body rate of the regressors (basis_term.h kBodyRate): from two other gyros' spin axes
    // where they give it, whose noise the deviation does not carry (regimes.h
    // BodyRates::gyro_step_without); else the attitude's turn.
    const std::optional<Vector3d>& other =
        static_cast<size_t>(i) < rates.gyro_step_without.size()
            ? rates.gyro_step_without[i][id - 1]
            : std::nullopt;
    const Vector3d step_b = other.has_value() ? *other : turn_b;
    const Vector3d w_b = span > 0.0 ? Vector3d(step_b / span) : Vector3d::Zero();
    const std::optional<Vector3d> u_i = u_last_v, u_j = voltages_v(j);
    for (int s = 0; s < substeps; ++s) {
      const double f = (s + 0.5) / substeps;
      TrajectoryStep step;
      step.dt = span / substeps;
      step.inputs.time = frames[i].time + absl::Seconds(f * span);
      step.inputs.h_k = SlerpUnit(h_i, h_j, f);
      TabulateSpinAxisPowers(step.inputs);  // evaluated under every candidate
      step.inputs.w_k = C_b_k.transpose() * w_b;
      step.inputs.channels = held;
      if (u_i.has_value() && u_j.has_value()) {
        step.inputs.u_k_v = (1.0 - f) * *u_i + f * *u_j;
      } else {
        step.inputs.u_k_v = u_i.has_value() ? u_i : u_j;
      }
      step.C_in_k = qa.slerp(f, qb).toRotationMatrix() * C_b_k;
      step.h_in = step.C_in_k * step.inputs.h_k;
      d.steps.push_back(step);
    }
  }
}

// The measured inertial spin axis at each sample, the fixed projection basis (u1, u2), the
// deviation from the model's drift `model` (y) and its noise (R: the star tracker's rotation and
// the readout's).
void ProjectDeviations(const SpacecraftConfig& config, const Matrix3d& C_b_k,
                       const DriftFunction& model, const std::vector<Quaterniond>& q_in_b,
                       const std::vector<int>& samples, DeviationSeries& d) {
  const Matrix3d S_st_b = config.star_tracker.noise.cwiseAbs2().asDiagonal();
  const double readout_var = config.readout_noise * config.readout_noise;
  std::vector<Vector3d> h_in(samples.size());
  Vector3d mean = Vector3d::Zero();
  for (size_t k = 0; k < samples.size(); ++k) {
    h_in[k] = (d.C_k_in[k].transpose() * d.h_k[k]).normalized();
    mean += h_in[k];
  }
  mean.normalize();
  d.u1 = AnyPerpendicular(mean).normalized();
  d.u2 = mean.cross(d.u1);
  const std::vector<Vector2d> model_signature = Signature(d, model);
  Eigen::Matrix<double, 3, 2> U;
  U << d.u1, d.u2;
  d.y.resize(samples.size());
  d.R.resize(samples.size());
  for (size_t k = 0; k < samples.size(); ++k) {
    const Vector3d dy = h_in[k] - h_in[0];
    d.y[k] = Vector2d(d.u1.dot(dy), d.u2.dot(dy)) - model_signature[k];
    // Noise of h_in: the star tracker's rotation (body axes), h_in = C_in_b (I + [dtheta x])
    // h_b, and the readout's, perpendicular to h.
    const Matrix3d C_in_b = q_in_b[samples[k]].toRotationMatrix();
    const Vector3d h_b = C_b_k * d.h_k[k];
    const Matrix3d J = C_in_b * Skew(h_b);
    const Matrix3d cov = J * S_st_b * J.transpose() +
                         readout_var * (Matrix3d::Identity() - h_in[k] * h_in[k].transpose());
    d.R[k] = U.transpose() * cov * U;
  }
}

}  // namespace

// Each gyro as a sequence: its model as the run left it, the frames with a star-tracker sample
// the model applied and a reading, the trajectory between them, and the deviations projected.
absl::StatusOr<std::vector<DeviationSeries>> MeasureDeviations(
    const SpacecraftConfig& config, const std::vector<GyroEstimate>& estimates,
    const std::vector<TelemetryFrame>& frames, const BodyRates& rates, const ModelRun& run,
    const std::vector<int>& gyros) {
  const int n = static_cast<int>(frames.size());
  const CarriedAttitude attitude = AttitudeAlongRecording(frames, rates, run);
  const std::vector<bool>& usable = attitude.usable;
  const std::vector<Quaterniond>& q_in_b = attitude.q_in_b;

  std::vector<DeviationSeries> out;
  for (int id : gyros) {
    const GyroConfig* gc = config.FindGyro(id);
    if (gc == nullptr) {
      return absl::InvalidArgumentError(absl::StrFormat("gyro %d is not configured", id));
    }
    const GyroModel m = GyroModelOf(*gc, estimates, id);
    ChannelSignals channels(config.channels,
                            m.any_channel ? m.basis_terms : std::vector<BasisTerm>());
    std::vector<int> samples;
    for (int i = 0; i < n; ++i) {
      if (usable[i] && frames[i].gyros[id - 1].has_value()) samples.push_back(i);
    }
    if (static_cast<int>(samples.size()) < kMinSamples) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "gyro %d: %d star-tracker samples the model applied, at least %d needed", id,
          samples.size(), kMinSamples));
    }
    DeviationSeries d;
    d.gyro = id;
    AddTrajectory(*gc, m, frames, rates, q_in_b, samples, channels, d);
    ProjectDeviations(config, m.C_b_k, ModelDrift(m.coefficients, m.basis_terms), q_in_b, samples,
                      d);
    d.duration_s = HoursToSeconds(d.hours.back() - d.hours.front());
    out.push_back(std::move(d));
  }
  return out;
}

}  // namespace esg::estimator::discovery
