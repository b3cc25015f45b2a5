// Attitude regimes found from the data (docs/discovery.md, "Locate"): the
// body rate at every telemetry frame, measured from consecutive star-tracker quaternions or from
// the gyro readings, and the recording cut into spans of one regime: inertial hold, orbital
// orientation, steady rotation, slew. The discovery (diagnose.h) holds out whole spans to test
// the model's prediction across regimes, reports where a mismatch sits, and corrects star-tracker
// latency with the measured rate. Pure computation on the recording; nothing here knows the
// simulator or the profile that produced it.
#ifndef ESG_ESTIMATOR_DISCOVERY_REGIMES_H_
#define ESG_ESTIMATOR_DISCOVERY_REGIMES_H_

#include <array>
#include <optional>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/time/time.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

// Body rate w_b_in_b at each frame [rad/s], body axes.
struct BodyRates {
  // From the gyro readings: the spin axes are inertially fixed over a telemetry step (their drift,
  // < 1 deg/h, moves them < 0.02 arcsec/s), so the body-frame spin axes of two gyros at two
  // consecutive frames give the body's rotation between the frames by TRIAD. Readout noise of
  // 3 arcsec gives ~0.1 arcsec/s at 60 s steps; present through star-tracker outages and free of
  // star-tracker outliers. Central (mean of the two adjacent steps) where both exist.
  std::vector<Eigen::Vector3d> gyro;
  std::vector<bool> gyro_valid;
  // From consecutive valid star-tracker quaternions, q_b1_b2 = conj(q_in_b1) (x) q_in_b2, central
  // as above. Carries star-tracker outliers (arcminutes / step) and boresight noise.
  std::vector<Eigen::Vector3d> star_tracker;
  std::vector<bool> star_tracker_valid;
  // The rate used to correct star-tracker latency: gyro where valid, else star tracker, else 0.
  std::vector<Eigen::Vector3d> best;
  // Rotation vector of q_b(i)_b(i+1) from the gyros, per step i -> i+1 (size frames - 1) [rad].
  std::vector<Eigen::Vector3d> gyro_step;
  std::vector<bool> gyro_step_valid;
  // The same step rotation from two gyros other than gyro k (index k - 1), per step, for the
  // regressors of gyro k's deviation: the deviation carries the star tracker's noise and gyro k's
  // readout noise at each sample, and a body rate differenced from the star tracker carries the
  // same star-tracker noise (its integral over the recording is that noise itself), so a rate
  // regressor fitted it (errors in variables; docs/discovery.md "The open-ended stage"). nullopt
  // without two well separated other gyros in both frames.
  std::vector<std::array<std::optional<Eigen::Vector3d>, kMaxGyros>> gyro_step_without;
};

BodyRates MeasureBodyRates(const SpacecraftConfig& config,
                           const std::vector<TelemetryFrame>& frames);

enum class Regime { kInertialHold, kOrbital, kRotation, kSlew };
const char* RegimeName(Regime r);  // "inertial_hold", "orbital", "rotation", "slew"

struct RegimeOptions {
  double window = 600.0;  // classification window, centred on each frame [s]
  // Below this median rate the spacecraft holds an inertial attitude [rad/s] (0.005 deg/s: ten
  // times the star tracker's rate noise at 60 s steps, a twelfth of the slowest orbital rate).
  double hold_rate = DegToRad(0.005);
  // A steady rotation (rate magnitude within 10%, axis within ~10 deg over the window) whose
  // period lies in this band is orbital orientation (a low Earth orbit turns the body about the
  // orbit normal once per revolution, 85-130 min); other steady rotations are `rotation` [s].
  double orbital_period_min = 75.0 * 60.0;
  double orbital_period_max = 150.0 * 60.0;
  double steady_magnitude = 0.10;  // relative spread of |w| over the window
  double steady_axis = 0.985;      // mean resultant length of the unit rate axes (~10 deg)
  // Runs shorter than this are folded into the neighbouring slew (or, between two runs of one
  // regime, into that regime) [s].
  double min_span = 1200.0;
  // Two runs of one regime separated by a short interruption stay separate spans when their mean
  // rate axes differ by more than this [rad] (the calibration profile's reorientations).
  double max_axis_change = DegToRad(20.0);
};

struct RegimeSpan {
  Regime regime = Regime::kSlew;
  int first_frame = 0;  // inclusive
  int last_frame = 0;   // inclusive
  absl::Time start;
  absl::Time end;
  double mean_rate = 0.0;                            // median |w| over the span [rad/s]
  Eigen::Vector3d axis_b = Eigen::Vector3d::Zero();  // mean rate axis (body), zero for a hold
  double hours() const { return absl::ToDoubleHours(end - start); }
};

// Cuts the recording into regime spans, covering every frame, in time order. The rate per frame is
// the star tracker's where available (docs/discovery.md), the gyros' otherwise; classification uses
// medians over the window, so outliers and outages do not split spans.
std::vector<RegimeSpan> FindRegimes(const std::vector<TelemetryFrame>& frames,
                                    const BodyRates& rates, const RegimeOptions& options = {});

// Index of the span that contains frame i (spans from FindRegimes), -1 if none.
int SpanOfFrame(const std::vector<RegimeSpan>& spans, int frame);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_REGIMES_H_
