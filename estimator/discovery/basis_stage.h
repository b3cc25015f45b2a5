// The open-ended stage inside a diagnosis (docs/discovery.md, "The open-ended stage"): for what
// the library left unexplained, the deviation of each running gyro from the selected model
// (deviation.h) is regressed on the basis (open_ended.h); the groups it selects are added to the
// model as basis terms (GyroConfig::basis_terms, freed with their prior; a readout distortion
// held at its fitted value), the model is refitted by the filter, and the terms are kept only
// when the refitted filter's own evidence, 2 ln B from its marginal likelihood, also passes the
// threshold. Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_BASIS_STAGE_H_
#define ESG_ESTIMATOR_DISCOVERY_BASIS_STAGE_H_

#include <algorithm>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "estimator/discovery/context.h"
#include "estimator/discovery/open_ended.h"
#include "estimator/discovery/report.h"
#include "estimator/discovery/selected_model.h"

namespace esg::estimator::discovery {

struct BasisStageResult {
  OpenEndedOptions options;
  OpenEndedResult stage;
  // One finding per selected group, when the refit confirmed them; then `extended` is the model
  // with the terms, its run and fit (its held-out prediction not run), for the caller to take.
  std::vector<Finding> findings;
  std::optional<SelectedModel> extended;
  // The terms added (gyro id, term) and readout distortions (gyro id, E), to add them to another
  // model (selection.h: the basis against a time behaviour).
  std::vector<std::pair<int, BasisTerm>> added_terms;
  std::vector<std::pair<int, Eigen::Matrix3d>> added_distortions;
  // The drifts that follow the sun, held as corrections of the gyros' readings (sun_terms.h).
  std::vector<ReadingShift> added_shifts;
  // The refitted filter's evidence for all the terms together, 2 ln B (less the Occam term of the
  // sun groups, held at their fitted values), and its threshold.
  double refit_evidence = 0.0;
  double refit_threshold = 0.0;
  bool refitted = false;
  // For an `unexplained` verdict: what the remaining deviation resembles most, in words.
  std::string resembles;
  std::vector<ResidualDriftPoint> residual_drift;
};

// `round`: the forward-selection round the findings are numbered with.
absl::StatusOr<BasisStageResult> RunBasisStage(const SelectedModel& selected,
                                               DiagnosisContext& context,
                                               const std::vector<int>& gyros, int round);

// The gyros whose selected groups in `stage` describe their deviation less well than a drift
// that returns to its mean (wander.h), in the reduced regression's currency (2 ln B against the
// configured walk): the stationary drift's evidence above the sum of the gyro's groups'. A gyro
// in `measured` takes that stationary evidence as measured before; the others are compared on
// their deviation from `selected`, the stationary drift counting only when it passes the
// threshold and beats one step and a raised walk decisively (kDecisiveDeviance). Gyros in `skip`
// are not tested. `note`: "; the basis's terms for gyro g (...) describe ..." per gyro found.
struct OutdoneGyros {
  std::vector<int> gyros;
  std::string note;

  bool Contains(int gyro) const {
    return std::find(gyros.begin(), gyros.end(), gyro) != gyros.end();
  }
  // `all` without the gyros found, in its order.
  std::vector<int> Others(const std::vector<int>& all) const {
    std::vector<int> out;
    for (int id : all) {
      if (!Contains(id)) out.push_back(id);
    }
    return out;
  }
};
absl::StatusOr<OutdoneGyros> GyrosOutdoneByAStationaryDrift(
    const BasisStageResult& stage, const SelectedModel& selected,
    const DiagnosisContext& context, const std::map<int, double>& measured,
    const std::vector<int>& skip, double alpha);

// The open-ended options the diagnosis's options and `model` give: alpha, the drift and readout
// priors, and the drift steps the model holds (nuisance groups).
OpenEndedOptions ModelOpenEndedOptions(const ModelState& model, const DiagnoseOptions& opt);

// The orbital period the recording shows [s]: the median period of its orbital-orientation spans
// (regimes.h), 0 without one.
double RecordingOrbitalPeriod(const std::vector<RegimeSpan>& regimes);

// The orbital period a candidate's fit uses [s]: DiagnoseOptions::orbital_period_s (given, or the
// orbit's), else RecordingOrbitalPeriod of the context's regimes, 0 without either.
double CandidateOrbitalPeriod(const FitContext& ctx);

// A readout group's distortion as the report's parameters: the six entries of the traceless E
// (basis[readout E_xx] .. basis[readout E_zx]) with their 1-sigma, in ppm.
std::vector<Parameter> ReadoutParameters(const SelectedGroup& group);

// `model` with the stage's terms added (as RunBasisStage added them to the selected model).
ModelState WithBasisTerms(const ModelState& model, const BasisStageResult& stage);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_BASIS_STAGE_H_
