// The measured spin-axis deviation from a model, per gyro (docs/discovery.md, "The open-ended
// stage"): what the open-ended stage regresses on its basis.
//
// For gyro g, the spin axis measured in inertial axes at each usable star-tracker sample k is
// h_in(t_k) = C_in_b_st(t_k) C_b_k h_k(t_k) (the star tracker as the model corrects it, the
// mounting with the model's misalignment). The model moves it by dh_in/dt = (C_in_k dw_k) x h_in
// (eq. (1), (10) and the basis terms, at the model's final values). The deviation
//
//     y(t_k) = h_in(t_k) - h_in(t_0) - integral_{t_0}^{t_k} (C_in_k dw_model_k(tau)) x h_in dtau
//
// integrates the model along the MEASURED trajectory (h_k, attitude and rates from the data), so
// y is linear in any drift the model lacks: a drift dw_k adds integral (C_in_k dw_k) x h_in dtau
// to it (its signature, Signature below), whatever the size of the accumulated deviation; the
// model's own errors never feed back as they would in an open-loop prediction. y and every
// signature are projected on a fixed basis (u1, u2) perpendicular to the gyro's mean inertial
// spin axis. y carries the measurement noise of h_in(t_k) (star tracker and readout, covariance
// R_k, projected) and the offset -noise(t_0), which the regression's state absorbs.
//
// The attitude between star-tracker samples (outages, samples the model's filter rejected) is
// carried by the gyros' measured rotation (regimes.h BodyRates::gyro_step). Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_DEVIATION_H_
#define ESG_ESTIMATOR_DISCOVERY_DEVIATION_H_

#include <functional>
#include <memory>
#include <optional>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/basis_term.h"
#include "estimator/channel_signal.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/regimes.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"

namespace esg::estimator::discovery {

// One integration substep of a gyro's measured trajectory (midpoint of the substep).
struct TrajectoryStep {
  BasisInputs inputs;                                  // time, h_k, w_k, u_k_v
  double dt = 0.0;                                     // [s]
  Eigen::Matrix3d C_in_k = Eigen::Matrix3d::Identity();
  Eigen::Vector3d h_in = Eigen::Vector3d::UnitZ();     // C_in_k h_k
};

// A gyro's deviation series.
struct DeviationSeries {
  int gyro = 0;
  std::vector<int> frames;    // frame index of each sample k
  std::vector<double> hours;  // since the recording's first frame
  std::vector<Eigen::Vector2d> y;      // [rad], on (u1, u2)
  std::vector<Eigen::Matrix2d> R;      // measurement noise covariance of y_k [rad^2]
  std::vector<Eigen::Matrix3d> C_k_in;  // case <- inertial at each sample
  std::vector<Eigen::Vector3d> h_k;     // the reading at each sample (case axes)
  Eigen::Vector3d u1 = Eigen::Vector3d::UnitX(), u2 = Eigen::Vector3d::UnitY();
  // Substeps between samples: steps[sample_end[k-1] .. sample_end[k]) lead from sample k-1 to k
  // (sample_end[0] = index of the first substep after sample 0).
  std::vector<TrajectoryStep> steps;
  std::vector<int> sample_end;
  double duration_s = 0.0;  // from the first to the last sample
  // With channel terms in the model (basis_term.h kChannel): the held channels and lags over each
  // frame interval, as the filter advances them (channel_signal.h); the steps' inputs point into
  // these. Empty otherwise.
  std::vector<std::shared_ptr<const ChannelSignals>> channel_states;
};

// A drift in case axes [rad/s] at a substep.
using DriftFunction = std::function<Eigen::Vector3d(const BasisInputs&)>;

// The signature of a drift on the series: integral (C_in_k dw_k) x h_in dtau from sample 0 to
// each sample, projected on (u1, u2) [rad per unit of the drift].
std::vector<Eigen::Vector2d> Signature(const DeviationSeries& series, const DriftFunction& drift_k);

// A scalar regressor at a substep (basis_term.h BasisScalar, ...) [its unit], and its RMS over
// the series' substeps, time-weighted (0 for a series without substeps): the scale its prior is
// stated at.
using ScalarFunction = std::function<double(const BasisInputs&)>;
double RegressorRms(const DeviationSeries& series, const ScalarFunction& s);

// The signature of a readout distortion E (a reading h_meas = (I + E) h_k normalised, E symmetric):
// the measured inertial axis moves by C_in_k (I - h h^T) E h_k at each sample, relative to
// sample 0 [rad per unit of E].
std::vector<Eigen::Vector2d> ReadoutSignature(const DeviationSeries& series,
                                              const Eigen::Matrix3d& E);

// The model's drift of gyro `gyro` [rad/s, case axes]: eq. (1), (10) at `coefficients` plus the
// configuration's basis terms.
DriftFunction ModelDrift(const DriftCoefficients& coefficients,
                         const std::vector<BasisTerm>& basis_terms);

// The attitude at every frame of a recording as the deviation uses it: the star tracker (already
// corrected) where `run`, the model's full run, applied it (in sample, accepted: `usable`), else
// carried from the previous frame by the gyros' measured rotation (regimes.h
// BodyRates::gyro_step); `known` is false before the first usable sample.
struct CarriedAttitude {
  std::vector<Eigen::Quaterniond> q_in_b;
  std::vector<bool> known;
  std::vector<bool> usable;
};
CarriedAttitude AttitudeAlongRecording(const std::vector<TelemetryFrame>& frames,
                                       const BodyRates& rates, const ModelRun& run);

// The deviation series of each gyro in `gyros` from the model of `config` whose final estimates
// are `estimates` (coefficients, misalignments), on `frames` (star tracker already corrected by
// the model's StarTrackerCorrection). `run` is that model's full run: star-tracker samples it
// rejected (eq. (12), (14)) are not used. Errors: InvalidArgument when a gyro has fewer than 10
// usable samples.
absl::StatusOr<std::vector<DeviationSeries>> MeasureDeviations(
    const SpacecraftConfig& config, const std::vector<GyroEstimate>& estimates,
    const std::vector<TelemetryFrame>& frames, const BodyRates& rates, const ModelRun& run,
    const std::vector<int>& gyros);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_DEVIATION_H_
