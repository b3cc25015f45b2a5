// The open-ended stage of the diagnosis (docs/discovery.md, "The open-ended stage"): for what the
// library did not explain, a sparse regression of each gyro's deviation from the model
// (deviation.h) on a documented basis of physically meaningful drift terms (basis_term.h,
// docs/physics.md "Basis of drift terms"):
//
//   spin-axis harmonics   h1^a h2^b h3^c e_m, degree <= 4, c <= 1 (25 monomials: a basis of the
//                         functions of a unit vector to degree 4, which holds eq. (1) and (10))
//   body rate             w_k[i] e_m and w_k[i] w_k[j] e_m (case axes)
//   orbital phase         cos, sin of n x orbital phase, n = 1, 2 (when the recording shows the
//                         orbital period)
//   time                  a ramp t e_m, and t h_m^2 e_m (a C2-like term growing)
//   suspension voltages   dU_k[i] e_m (when telemetered)
//   readout distortion    a symmetric traceless distortion E of the direction-cosine readout (5
//                         per gyro: a common scale factor of the three channels leaves a
//                         normalised reading unchanged and is not observable)
//   the sun               the lagged illumination of each body face (sun_regressors.h), its
//                         time constant profiled over a grid: one family per face
//
// Selection is forward, one group of one gyro per round (a scalar regressor along a direction in
// case axes the data choose: BasisGroup), by the diagnosis's evidence currency: 2 ln B of the
// group (its coefficients integrated over their prior, the dispersion profiled) above
// 2 ln(M / alpha), M the groups tested in the round. Under the null each Bayes factor
// has expectation 1, so by Markov's inequality and the union bound a round adds a regressor the
// data do not need with probability at most alpha (the stated false-discovery control).
// A face's family of sun groups (one per lag of the grid) counts as one group of M: its evidence is
// the Bayes factor averaged over the lags, equally likely a priori on the log-spaced grid (the
// lag integrated over its prior, as the onset of a drift step is), which has expectation 1 under
// the null like every group's, so the bound holds with the larger basis; the lag reported is the
// best of the grid, with the interval where 2 ln B stays within 3.84 of its maximum.
// Groups that the recording cannot tell apart from a selected one (replacing it loses less than
// 2 ln B = 6, "strong" evidence on Kass and Raftery's scale) are reported as alternatives.
// Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_OPEN_ENDED_H_
#define ESG_ESTIMATOR_DISCOVERY_OPEN_ENDED_H_

#include <limits>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/basis_term.h"
#include "estimator/discovery/deviation.h"
#include "estimator/discovery/deviation_filter.h"
#include "estimator/discovery/sun_regressors.h"
#include "estimator/spacecraft_config.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

struct OpenEndedOptions {
  double alpha = 0.01;
  // Prior 1-sigma of a term's drift, at the RMS of its regressor over the recording [rad/s]
  // (the library's prior for C1, C2: 0.1 deg/h).
  double drift_sigma = DegPerHourToRadPerSec(0.1);
  // Prior 1-sigma of each coefficient of a readout distortion on its unit pattern (Frobenius norm
  // 1; ReadoutPattern) [1] (60 arcsec, the misalignment prior).
  double readout_sigma = ArcsecToRad(60.0);
  int max_terms = 6;
  // Orbital period [s] (0: not known, no orbital-phase regressors) and the phase's zero.
  double orbital_period_s = 0.0;
  absl::Time epoch = absl::UnixEpoch();
  // A regressor is an alternative to a selected one when replacing it loses less than this 2 ln B.
  double ambiguity = 6.0;
  // Drift steps the model holds (a coefficient released at a time: gyro id, time). The model's
  // final coefficients hold after the step; before it the deviation carries minus the step, so
  // each adds a nuisance group to the gyro's base model: a case-fixed drift before the time.
  std::vector<std::pair<int, absl::Time>> steps;
  // Drift columns each gyro's model may still take (gyro id, count; the configuration holds at
  // most kMaxBasisTermsPerGyro terms a gyro); a gyro not listed: no bound.
  std::vector<std::pair<int, int>> column_budget;
  // The sun's regressors of each gyro (sun_regressors.h); a gyro not listed has no sun groups.
  std::vector<SunRegressors> sun;
  // The coefficients of eq. (1), (10) each gyro's model leaves free (gyro id, theta index of
  // drift_model.h, the configuration's prior 1-sigma [rad/s]). The deviation is measured from the
  // model at their final values, which took part of whatever drift the model lacks (a drift
  // with a mean shares it with k0); each is therefore refitted beside every group, a nuisance
  // column with its configured prior, so that a group's coefficients and evidence are those of a
  // model that fits both at once.
  struct FreeCoefficient {
    int gyro = 0;
    int theta = 0;
    double sigma = 0.0;
  };
  std::vector<FreeCoefficient> free_coefficients;
};

// The free coefficients of every gyro of `config` (model_sigma > 0), for
// OpenEndedOptions::free_coefficients.
std::vector<OpenEndedOptions::FreeCoefficient> FreeCoefficientsOf(const SpacecraftConfig& config);

// One regressor of the basis for one gyro.
struct BasisColumn {
  bool readout = false;  // a readout distortion entry instead of a drift term
  BasisTerm term;        // drift terms: kind, axis, indices (value 1)
  // readout: the distortion per unit of the coefficient, ReadoutPattern(readout_index)
  int readout_index = 0;
  std::string label;     // BasisTermLabel, or "readout xy", ...; ReadoutPattern
  int group = 0;         // index of its group in the gyro's basis
  // A drift column's regressor s, RMS over the recording's substeps (time-weighted) [SI unit of
  // s]; its prior is OpenEndedOptions::drift_sigma / rms. 0 for a readout entry.
  double rms = 0.0;
  // A nuisance regressor, in every model: e_m before `before` (OpenEndedOptions::steps), or a
  // free coefficient of the model, theta index `theta` (OpenEndedOptions::free_coefficients),
  // its regressor DriftRegressor's column and its prior `prior_sigma`.
  bool nuisance = false;
  absl::Time before = absl::InfinitePast();
  int theta = -1;
  double prior_sigma = 0.0;
  // A sun column: the lagged illumination of face sun_face (sun_regressors.h) at lag index
  // sun_lag, along case axis term.axis; -1 otherwise.
  int sun_face = -1;
  int sun_lag = -1;
  // A drift column that is not the sun's: its regressor s at each substep of the series it was
  // enumerated on, computed once and shared by the term's three axes (the scalar does not depend
  // on the axis), from which its RMS and its signature are taken (sun_regressors.h
  // TabulatedRms, TabulatedSignature: the same bits as evaluating s substep by substep). Released
  // once the signatures are computed; null for a readout entry, a sun column, or after release.
  std::shared_ptr<const std::vector<double>> scalar_table;
};

// The readout distortion's unit patterns, an orthonormal basis (Frobenius inner product) of the
// symmetric traceless 3x3 matrices: 0 diag(1, -1, 0) / sqrt 2 ("readout xx-yy"), 1 diag(1, 1, -2)
// / sqrt 6 ("readout xx+yy-2zz"), 2..4 the off-diagonal pairs xy, yz, zx / sqrt 2.
inline constexpr int kReadoutPatterns = 5;
Eigen::Matrix3d ReadoutPattern(int index);
const char* ReadoutPatternLabel(int index);

// The unit of selection: one scalar regressor along every case axis (a drift of one time or
// spin-axis behaviour along a direction the data choose), cos and sin of one orbital harmonic
// together, the three C2-like growing terms together, the five readout patterns together.
struct BasisGroup {
  std::string label;         // "h1^2*h3", "orbit 1", "ramp", "readout", ...
  std::vector<int> columns;  // indices into the gyro's columns
  bool nuisance = false;     // in every model, never selected
  int sun_face = -1;         // a sun group: its face and lag index (BasisColumn)
  int sun_lag = -1;
};

struct GyroBasis {
  std::vector<BasisColumn> columns;
  std::vector<BasisGroup> groups;
};

// A column's signature on the series it was enumerated on [rad per unit of its coefficient]
// (deviation.h Signature; ReadoutSignature for a readout entry).
std::vector<Eigen::Vector2d> ColumnSignature(const DeviationSeries& series,
                                             const BasisColumn& column);

// The basis for a gyro's series (regressors that vanish on the recording are left out).
GyroBasis EnumerateBasis(const DeviationSeries& series, const OpenEndedOptions& options);

struct FittedColumn {
  BasisColumn column;
  double value = 0.0;  // posterior mean [rad/s per SI unit of s], or [1] for a readout entry
  double sigma = 0.0;  // posterior 1-sigma
  double prior_sigma = 0.0;
};

// A selected group of one gyro.
struct SelectedGroup {
  int gyro = 0;
  std::string label;
  std::vector<FittedColumn> columns;
  // Posterior covariance of the columns' coefficients, in the columns' order.
  Eigen::MatrixXd covariance;
  double evidence = 0.0;   // 2 ln B when it was added
  double threshold = 0.0;  // 2 ln(M / alpha) of its round
  int groups_tested = 0;   // M
  // Groups the recording cannot tell apart from it, with 2 ln B against it (> -ambiguity).
  std::vector<std::pair<std::string, double>> alternatives;
  // A sun group: its face, and the lag profile of the round it was selected in: each lag of the
  // grid [h] with the family's 2 ln B at it (evidence above is their average's).
  int sun_face = -1;
  std::vector<double> lag_hours;
  std::vector<double> lag_evidence;
  // Its drift at full illumination in case axes [rad/s] and covariance averaged over the lags
  // with their posterior weights (proportional to each lag's Bayes factor) in that round: the
  // amplitude with the lag's uncertainty, not at one lag of the grid.
  Eigen::Vector3d lag_averaged_k = Eigen::Vector3d::Zero();
  Eigen::Matrix3d lag_averaged_covariance_k = Eigen::Matrix3d::Zero();
};

// A gyro's residual drift: the fixed-interval smoothed drift of its deviation, carried to case
// axes, before and after the selected terms [rad/s].
struct ResidualDrift {
  int gyro = 0;
  std::vector<double> hours;
  std::vector<Eigen::Vector3d> before_k, after_k;
  std::vector<double> sigma;  // 1-sigma of one component (rms of the two) [rad/s], after
  double smoothing_intensity = 0.0;  // the walk intensity the smoother used [rad/s/sqrt(s)]
};

struct OpenEndedResult {
  std::vector<SelectedGroup> selected;  // in the order selected
  // The best group of the last round, selected or not: what the remaining deviation resembles
  // most (gyro, label, 2 ln B, threshold).
  int best_gyro = 0;
  std::string best_label;
  double best_evidence = 0.0;
  double best_threshold = 0.0;
  int groups_tested = 0;  // M of the first round
  std::vector<ResidualDrift> residual_drift;
  double deviance_before = 0.0, deviance_after = 0.0;  // summed over gyros
};

// `random_walk`: each series' intensity of eq. (11) [rad/s/sqrt(s)], `w0_sigma` the prior 1-sigma
// of its residual drift at the start [rad/s] (same order as `series`; deviation_filter.h).
OpenEndedResult RunOpenEnded(const std::vector<DeviationSeries>& series,
                             const std::vector<double>& random_walk,
                             const std::vector<double>& w0_sigma,
                             const OpenEndedOptions& options);

// A readout group's distortion E (sum of its coefficients times their patterns) and the 1-sigma of
// each entry of E from the group's covariance.
Eigen::Matrix3d ReadoutDistortion(const SelectedGroup& group);
Eigen::Matrix3d ReadoutDistortionSigma(const SelectedGroup& group);

// The readout group alone for one gyro's series (a candidate of each selection round, beside the
// library's effects: selection.h): on top of the series' nuisance groups, its coefficients'
// posterior (SelectedGroup, gyro, label "readout", evidence 2 ln B against the nuisance groups
// alone, threshold 0, groups_tested 1).
struct ReadoutFit {
  SelectedGroup group;
};
ReadoutFit FitReadoutDistortion(const DeviationSeries& series, double random_walk,
                                double w0_sigma, const OpenEndedOptions& options);

// The sun's families alone for one gyro's series (a candidate of each selection round, beside the
// library's effects: readout_candidate.h FitSunCandidate). Each face with regressors in options.sun
// and not in `held_faces` is fitted on top of the series' nuisance groups as the stage fits a
// family (its Bayes factor averaged over the lags, equally likely a priori); the face with the
// largest averaged 2 ln B is returned as a SelectedGroup at its best lag (gyro, label, columns and
// covariance at that lag, evidence the averaged 2 ln B, threshold 0, groups_tested the faces
// fitted, the lag profile, the lag-averaged drift and covariance, and the alternatives: the other
// groups of the basis and the other faces at their best lag that replace it at a loss below
// options.ambiguity). `best_lag_evidence` is 2 ln B at the best lag alone (at least the average),
// `best_other_*` the best group of the rest of the basis. group.sun_face is -1 when no face was
// fitted.
struct SunFamilyFit {
  SelectedGroup group;
  double best_lag_evidence = 0.0;
  // The other groups of the basis on the same deviation: the label and 2 ln B of the one with the
  // most evidence (the group the stage would weigh against the sun in its first round).
  std::string best_other_label;
  double best_other_evidence = -std::numeric_limits<double>::infinity();
};
SunFamilyFit FitSunFamilies(const DeviationSeries& series, double random_walk, double w0_sigma,
                            const OpenEndedOptions& options, const std::vector<int>& held_faces);

// Laplace's Occam term of a group's coefficients, ln det(P0 / P) + a^T P0^-1 a (prior covariance
// P0 from the columns' prior_sigma, posterior P its covariance, a the columns' values).
double ReadoutOccam(const SelectedGroup& group);
// The same term for coefficients a with posterior covariance P and independent priors of 1-sigma
// prior_sigma.
double LaplaceOccam(const Eigen::VectorXd& a, const Eigen::MatrixXd& P,
                    const Eigen::VectorXd& prior_sigma);

// One gyro's series whitened by its reduced filter (deviation_filter.h), with its nuisance
// columns (OpenEndedOptions::steps: in every model) and the signatures `extra` whitened alike:
// what a regression whose coefficients several gyros share stacks, gyro by gyro
// (star_tracker_cycle.h). The gyros' series are independent given the coefficients, so their
// whitened rows stack into one Gaussian linear model.
struct WhitenedSeries {
  Eigen::VectorXd y_w;
  std::vector<Eigen::VectorXd> nuisance_w;
  std::vector<double> nuisance_prior;  // 1-sigma of each nuisance coefficient
  std::vector<Eigen::VectorXd> extra_w;
};
WhitenedSeries WhitenSeries(const DeviationSeries& series, double random_walk, double w0_sigma,
                            const OpenEndedOptions& options,
                            const std::vector<std::vector<Eigen::Vector2d>>& extra);

// WhitenSeries in two steps, for a search that whitens new signatures on one series many times
// (turning_displacement.h, a grid of periods): the series' filter, y and its nuisance columns are
// whitened once at construction; With(extra) gives what WhitenSeries(..., extra) gives, the same
// bits. The series must outlive the whitener.
class SeriesWhitener {
 public:
  SeriesWhitener(const DeviationSeries& series, double random_walk, double w0_sigma,
                 const OpenEndedOptions& options);
  WhitenedSeries With(const std::vector<std::vector<Eigen::Vector2d>>& extra) const;

 private:
  std::shared_ptr<const DeviationFilter> filter_;
  WhitenedSeries base_;  // extra_w empty
};

// What a selected group says in words: case-fixed drift along (x, y, z), varying with the orbital
// phase, growing, proportional to the body rate, ..., with sizes in deg/h, and the alternatives
// that cannot be told apart.
// Not for a sun group (SelectedGroup::sun_face >= 0): sun_terms.h DescribeSunGroup.
std::string DescribeGroup(const SelectedGroup& group, const OpenEndedOptions& options);

// "; on this recording it cannot be told apart from ..." for the group's alternatives, or "".
std::string DescribeAlternatives(const SelectedGroup& group);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_OPEN_ENDED_H_
