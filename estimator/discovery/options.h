// Options of a diagnosis (docs/discovery.md): the user's model, the false-finding level, the
// effects to try, the priors of freed coefficients, the held-out spans, and how the caller runs
// the diagnosis's independent model runs and cancels it. The estimator starts no threads:
// concurrency is the caller's, through `run_parallel`, so a service bounds its own threads.
#ifndef ESG_ESTIMATOR_DISCOVERY_OPTIONS_H_
#define ESG_ESTIMATOR_DISCOVERY_OPTIONS_H_

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "estimator/discovery/regimes.h"
#include "estimator/discovery/report.h"
#include "estimator/orbit.h"

namespace esg::estimator::discovery {

// The caller's executor: runs task(0) ... task(count - 1), each exactly once, on threads of the
// caller's choosing (concurrently or not), and returns once every task has returned. The tasks
// are independent; each writes only its own results.
using ParallelRunner = std::function<void(int count, const std::function<void(int)>& task)>;

// Progress of a diagnosis: the fraction done in [0, 1] and the stage it is in.
using DiagnoseProgressFn = std::function<void(double fraction, const std::string& stage)>;

struct DiagnoseOptions {
  // Drift model of the user (calibration_model.h ParseModel): "10+11" lets every configured
  // term with a positive modelSigma be calibrated and the residual random walk run.
  std::string model = "10+11";
  // Family-wise false-finding level of each forward-selection round: a candidate is taken when
  // its evidence 2 ln B exceeds 2 ln(M / alpha), M the round's candidates (statistics.h
  // EvidenceThreshold).
  double alpha = 0.01;
  int max_effects = 3;  // forward-selection rounds
  // The open-ended stage (docs/discovery.md): when the library leaves the recording
  // unexplained, regress each gyro's deviation on the basis of drift terms and readout
  // distortions, add what it selects to the model and refit.
  bool open_ended = true;
  // Integration rate of the filter during diagnosis [Hz]. The drift changes slowly; the
  // deviance at 0.2 Hz equals the one at 8 Hz to ~0.1 in 2e5 (docs/discovery.md), at 1/40 of the
  // cost. <= 0 keeps the configuration's rate.
  double integration_rate_hz = 0.2;
  // Concurrency. Independent model runs (the user's model's full and held-out runs, a round's
  // candidate fits, held-out comparisons) are spread over at most `threads` tasks handed to
  // `run_parallel`; each task takes the next unstarted run until none is left. Empty
  // `run_parallel` or threads <= 1: the runs are made one after another on the calling thread.
  // The report does not depend on either.
  int threads = 2;
  ParallelRunner run_parallel;
  // Effects to try (empty: all of the library).
  std::vector<Effect> effects;
  // The spacecraft's orbital period [s] when the user knows it (`esg diagnose --orbital-period`):
  // the open-ended basis's orbital-phase harmonics use it. 0: the median period of the
  // recording's orbital-orientation spans (regimes.h); a recording without such spans (inertial
  // holds, the calibration profile's rotations) then has no orbital-phase regressors.
  double orbital_period_s = 0.0;
  // The spacecraft's orbit when flight dynamics delivered one (`esg diagnose --orbit FILE`,
  // estimator/orbit.h): the sun's illumination of the body faces is then zero in the Earth's
  // shadow (eclipse.h; docs/discovery.md, "A drift that follows the sun"), and the orbital-phase
  // harmonics take the orbit's period when orbital_period_s is 0. It must cover the recording
  // (Diagnose refuses it otherwise, naming the gaps). Null: no orbit, the sun always shines.
  std::shared_ptr<const Orbit> orbit;
  // Where the orbit came from ("the OEM file F", "orbit deliveries 3, 4"), or, with no orbit,
  // why none was used (the service's stored deliveries do not cover the span): the report's
  // `orbit` line. Empty: nothing to say.
  std::string orbit_source;
  // Held-out spans: at most this many, each at most max_gap_hours long.
  int max_gaps = 4;
  double max_gap_hours = 4.0;
  // Priors given to freed coefficients (the paper's sizes, docs/physics.md) and the search grids:
  // per effect, to each fixed term it frees (estimator/model_terms.h `effect`).
  double c_sigma_deg_h = 0.1;                    // rotor_displacement
  double k0_sigma_deg_h = 0.3;                   // fourth_harmonic
  double unequal_stiffness_sigma_deg_h = 0.1;  // unequal_stiffness
  double misalignment_sigma_arcsec = 60.0;
  // Prior 1-sigma of a star-tracker latency (its evidence, docs/discovery.md "Evidence"): a
  // time stamp late or early by up to about a second.
  double latency_sigma_s = 1.0;
  RegimeOptions regimes;
  // Cancellation (may be empty): polled before each stage and before each candidate or
  // held-out model run (a candidate fit with a parameter search is one unit and is not
  // interrupted); once it returns true Diagnose returns Cancelled "diagnosis cancelled". Called
  // from the tasks of run_parallel concurrently: it must be thread-safe and cheap (e.g. an atomic
  // flag).
  std::function<bool()> cancelled;
};

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_OPTIONS_H_
