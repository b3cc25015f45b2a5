#include "estimator/discovery/coefficient_step.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/discovery/onset_search.h"
#include "estimator/model_terms.h"
#include "estimator/statistics.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

std::vector<BasisTerm> CoefficientStepTerms(int first, const Eigen::VectorXd& step_rad_s,
                                            absl::Time onset, double sigma) {
  // Each coefficient's regressor of eq. (1), (10) as monomials (drift_model.h
  // CoefficientMonomials).
  std::vector<BasisTerm> terms;
  for (int j = 0; j < step_rad_s.size(); ++j) {
    for (const CoefficientMonomial& m : CoefficientMonomials(first + j)) {
      BasisTerm t;
      t.kind = BasisKind::kSpinAxisHarmonic;
      t.axis = m.axis;
      t.exponents = m.exponents;
      t.epoch = onset;
      t.value = m.sign * step_rad_s(j);
      t.sigma = sigma;
      terms.push_back(t);
    }
  }
  return terms;
}

std::vector<CoefficientGroup> StepGroupsInUse(const GyroConfig& gyro) {
  const DriftVector value = gyro.model.AsVector(), sigma = gyro.model_sigma.AsVector();
  auto in_use = [&](int first, int count) {
    for (int i = first; i < first + count; ++i) {
      if (value(i) != 0.0 || sigma(i) > 0.0) return true;
    }
    return false;
  };
  // The fixed terms' table (model_terms.h), in theta order: k0 every model's; C1 is the drift
  // step's; the others where in use. The step's name is the key's with "Step" before its unit.
  std::vector<CoefficientGroup> out;
  for (const FixedTermKey& key : FixedTermKeys()) {
    if (key.first_theta_index == kThetaC1) continue;
    const int count = std::max(key.components, 1);  // a scalar key has no components
    if (key.first_theta_index != kThetaK0 && !in_use(key.first_theta_index, count)) continue;
    std::string json_name(key.json_key);
    const size_t unit_at = json_name.find("DegH");
    json_name.insert(unit_at == std::string::npos ? json_name.size() : unit_at, "Step");
    out.push_back({std::string(key.symbol), json_name, key.first_theta_index, count});
  }
  return out;
}

// Whether a step found by releasing coefficients at its onset carries its likelihood gain
// (docs/discovery.md, "A step must carry its gain"). Releasing a state's variance at T does two
// things: it lets the filter estimate a step, and it widens the covariance at T. Where the
// model's covariance is too small there (after a star-tracker outage, say), the widening alone
// lowers -2 log L, with no coefficient changed. So the step found must carry the gain itself: a
// run of the model without any release, the step `step_rad_s` (the group's estimate after the
// onset less the one at it) held at that value from the onset as switched-on basis terms
// (CoefficientStepTerms, sigma 0), must improve -2 log L on the run without the step by at least
// the chi-square bound of `count` degrees of freedom at level alpha (a likelihood ratio with the
// group's coefficients estimated). One run more per step found. Returns an empty string when it
// does (or when the gyro's basis has no room for the terms: the evidence alone decides), else
// the note that says why nothing was fitted.
absl::StatusOr<std::string> StepWithoutItsGain(OnsetSearch& search, const std::string& name,
                                               int first, const Eigen::VectorXd& step_rad_s,
                                               absl::Time onset, double alpha, double gain) {
  SpacecraftConfig held = search.BaseConfig();
  ASSIGN_OR_RETURN(GyroConfig * g, CandidateGyro(held, search.candidate.gyro));
  const std::vector<BasisTerm> terms = CoefficientStepTerms(first, step_rad_s, onset, 0.0);
  if (g->basis_terms.size() + terms.size() > static_cast<size_t>(kMaxBasisTermsPerGyro)) {
    return std::string();
  }
  g->basis_terms.insert(g->basis_terms.end(), terms.begin(), terms.end());
  auto run = RunModel(held, search.fit.model.options, search.frames);
  ++search.fit.runs;
  if (!run.ok()) return run.status();
  const double held_gain = Profile(search.prefix).value - Profile(*run).value;
  const int count = static_cast<int>(step_rad_s.size());
  const double bound = ChiSquareQuantile(1.0 - alpha, static_cast<double>(count));
  if (held_gain >= bound) {
    search.fit.notes.push_back(absl::StrFormat(
        "held from its onset without the release, the step of %s improves -2 log L by %.1f (the "
        "%.0f%% chi-square bound %.2f for %d parameter%s): it carries its gain",
        name, held_gain, 100.0 * (1.0 - alpha), bound, count, count == 1 ? "" : "s"));
    return std::string();
  }
  return absl::StrFormat(
      "a step of %s not fitted: -2 log L improves by %.1f with the coefficient%s released at the "
      "best onset, but by %.1f with the step found held from it (below the %.0f%% chi-square bound "
      "%.2f for %d parameter%s): the gain comes from the variance released at the onset (the "
      "model's covariance too small there), not from a change of the coefficient%s",
      name, gain, count == 1 ? "" : "s", held_gain, 100.0 * (1.0 - alpha), bound, count,
      count == 1 ? "" : "s", count == 1 ? "" : "s");
}

namespace {

// One group's search and what it gives: the onset profile (its prior points and interval), the
// best onset's run and options, the step with its 1-sigma, and the evidence integrated over the
// onsets against the model without the step.
struct GroupStep {
  CoefficientGroup group;
  CandidateFit scratch;  // the profile's prior points and onset profile
  OnsetProfile profile;
  int best_frame = -1;
  ModelRun run;
  SessionOptions options;
  Eigen::VectorXd step, step_sigma;  // [rad/s]
  double evidence = 0.0;             // 2 ln B over the onsets
  absl::Time onset_time;
};

// The step of the group at the best onset: the estimate after it (the run's final) less the
// one at the onset (the checkpoint's); its 1-sigma combines both estimates' sigmas (the
// estimate before the onset enters the one after it through the prior only).
absl::Status StepOf(OnsetSearch& search, GroupStep& g) {
  auto at_onset = EstimationSession::FromCheckpoint(search.fit.model.config, search.best_options,
                                                    search.checkpoints[search.best_frame]);
  if (!at_onset.ok()) return at_onset.status();
  const std::vector<GyroEstimate> before_all = at_onset->Gyros();
  const GyroEstimate* before = FindEstimate(before_all, search.candidate.gyro);
  const GyroEstimate* after = FindEstimate(search.best_run.gyros, search.candidate.gyro);
  g.step = Eigen::VectorXd::Zero(g.group.count);
  g.step_sigma = Eigen::VectorXd::Zero(g.group.count);
  if (before == nullptr || after == nullptr) return absl::OkStatus();
  const DriftVector b = before->coefficients.AsVector(), a = after->coefficients.AsVector();
  const DriftVector sb = before->sigma.AsVector(), sa = after->sigma.AsVector();
  for (int j = 0; j < g.group.count; ++j) {
    const int i = g.group.first + j;
    g.step(j) = a(i) - b(i);
    g.step_sigma(j) = std::hypot(sa(i), sb(i));
  }
  return absl::OkStatus();
}

// The run without the step, the same for every group: made by the first group's search, its
// checkpoints and steps handed to the next.
struct SharedPrefix {
  std::map<int, SessionCheckpoint> checkpoints;
  ModelRun prefix;
};

// One group's onset search, its profile and evidence against `base_value` (the model's -2 log L
// without the step), and its step: appends to `steps` a group whose step carries its gain, to
// `refused_notes` the note of one whose step does not.
absl::Status SearchGroup(const Candidate& candidate, CandidateFit& fit,
                         const std::vector<TelemetryFrame>& frames, const CoefficientGroup& group,
                         const std::vector<int>& grid_frames, double base_value,
                         const DiagnoseOptions& opt, SharedPrefix& shared,
                         std::vector<GroupStep>& steps, std::vector<std::string>& refused_notes) {
  OnsetSearch search{candidate, fit, frames};
  search.step_sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h);
  search.first = group.first;
  search.count = group.count;
  if (shared.checkpoints.empty()) {
    RETURN_IF_ERROR(RunPrefix(search, grid_frames));
  } else {  // the run without the step is the same for every group
    search.checkpoints = shared.checkpoints;
    search.prefix = shared.prefix;
  }
  ASSIGN_OR_RETURN(const bool searched, SearchOnsets(search, grid_frames, base_value, opt.alpha));
  shared.checkpoints = search.checkpoints;
  shared.prefix = search.prefix;
  if (!searched) return absl::OkStatus();
  GroupStep step;
  step.group = group;
  step.profile = ProfileOnsets(search, step.scratch);
  std::vector<std::pair<double, double>> points;
  for (const auto& [w, v] : step.scratch.prior_points) points.emplace_back(w, base_value - v);
  step.evidence = EvidenceOverPrior(points);
  RETURN_IF_ERROR(StepOf(search, step));
  ASSIGN_OR_RETURN(const std::string refused,
                   StepWithoutItsGain(search, group.name, group.first, step.step,
                                      frames[search.best_frame - 1].time, opt.alpha,
                                      base_value - search.best_value));
  if (!refused.empty()) {
    refused_notes.push_back(refused);
    return absl::OkStatus();
  }
  step.best_frame = search.best_frame;
  step.onset_time = frames[search.best_frame - 1].time;
  DescribeOnset(search, step.profile, step.scratch);
  step.run = std::move(search.best_run);
  step.options = search.best_options;
  steps.push_back(std::move(step));
  return absl::OkStatus();
}

// The evidence: the `group_count` groups equally likely a priori, each one's onsets integrated
// over the uniform prior (its prior points weighted by 1 / group_count). Returns the group of the
// largest evidence, the finding.
size_t AddGroupPriorPoints(const std::vector<GroupStep>& steps, size_t group_count,
                           CandidateFit& fit) {
  size_t best = 0;
  for (size_t k = 0; k < steps.size(); ++k) {
    for (const auto& [w, v] : steps[k].scratch.prior_points) {
      fit.prior_points.emplace_back(w / static_cast<double>(group_count), v);
    }
    if (steps[k].evidence > steps[best].evidence) best = k;
  }
  return best;
}

// The step of group `s` as the fit's: its run and options, its time behaviour, the step's
// parameters with their 1-sigma and the onset's, its basis terms (the prior c_sigma_deg_h) where
// `gyro`'s basis has room for them, and the finding's words.
void DescribeGroupStep(const Candidate& candidate, const GyroConfig& gyro, double c_sigma_deg_h,
                       GroupStep& s, CandidateFit& fit) {
  fit.parameters = s.group.count;
  fit.stepped = {s.group.first, s.group.count};
  fit.time = s.scratch.time;
  fit.time.kind = kTimeCoefficientStep;
  fit.onset_profile = s.scratch.onset_profile;
  fit.model.options = s.options;
  fit.run = std::move(s.run);

  const double deg_h = RadPerSecToDegPerHour(1.0);
  std::string sizes;
  for (int j = 0; j < s.group.count; ++j) {
    const std::string name = s.group.count == 1 ? std::string(s.group.json_name)
                                                : absl::StrFormat("%s[%d]", s.group.json_name, j);
    fit.fitted.push_back({name, s.step(j) * deg_h, s.step_sigma(j) * deg_h, "deg/h"});
    absl::StrAppend(&sizes, j == 0 ? "" : ", ",
                    absl::StrFormat("%+.4f +- %.4f", s.step(j) * deg_h, s.step_sigma(j) * deg_h));
  }
  const OnsetProfile& p = s.profile;
  const double onset_hours = p.points[p.best].first;
  fit.fitted.push_back({"onsetHours", onset_hours, 0.5 * (p.upper - p.lower), "h"});
  fit.fitted.push_back({"onsetLowerHours", p.lower, 0.0, "h"});
  fit.fitted.push_back({"onsetUpperHours", p.upper, 0.0, "h"});

  const double sigma = DegPerHourToRadPerSec(c_sigma_deg_h);
  const std::vector<BasisTerm> terms = CoefficientStepTerms(s.group.first, s.step, s.onset_time,
                                                            sigma);
  const int held = static_cast<int>(gyro.basis_terms.size());
  if (held + static_cast<int>(terms.size()) <= kMaxBasisTermsPerGyro) {
    fit.basis_terms = terms;
  } else {
    fit.notes.push_back(absl::StrFormat(
        "no basis terms for the step: gyro %d's basis holds %d terms, at most %d (%d more needed)",
        candidate.gyro, held, kMaxBasisTermsPerGyro, terms.size()));
  }
  fit.description = absl::StrFormat(
      "a step of %s of gyro %d (eq. %s) at %.2f h from the start (95%% %.2f-%.2f h): %s%s deg/h "
      "(%s after the step less before it)",
      s.group.name, candidate.gyro, s.group.first == kThetaK0 || s.group.first >= kThetaMu
                                        ? "(1)"
                                        : "(10)",
      onset_hours, p.lower, p.upper, s.group.count == 1 ? "" : "(",
      absl::StrCat(sizes, s.group.count == 1 ? "" : ")"), s.group.name);
}

// The notes of every group's profile and of the runs the search took.
void AddGroupNotes(const std::vector<GroupStep>& steps, size_t group_count, CandidateFit& fit) {
  for (const GroupStep& other : steps) {
    std::string profile_text;
    for (const auto& [h, v] : other.profile.points) {
      absl::StrAppend(&profile_text,
                      absl::StrFormat(" %.2f:%.1f", h, v - other.profile.points[other.profile.best].second));
    }
    fit.notes.push_back(absl::StrFormat(
        "a step of %s: 2 ln B = %.1f integrated over %d onsets, the best at %.2f h; likelihood "
        "over the onset (h from the start: -2 log L above the best):%s",
        other.group.name, other.evidence, other.profile.points.size(),
        other.profile.points[other.profile.best].first, profile_text));
  }
  fit.notes.push_back(absl::StrFormat(
      "%d filter runs for %d group%s: one without the step, the others continued from its "
      "checkpoints (each the part of a run after its onset)",
      fit.runs, group_count, group_count == 1 ? "" : "s"));
}

}  // namespace

// The search as a sequence: the groups of the model in use made releasable, one run without the
// step with checkpoints shared by the groups, each group's onset search and profile, the group
// of the largest evidence, its step described and its basis terms.
absl::Status FitCoefficientStep(const Candidate& candidate, const FitContext& ctx,
                                CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  ASSIGN_OR_RETURN(const GyroConfig* g, CandidateGyro(fit.model.config, candidate.gyro));
  const std::vector<CoefficientGroup> groups = StepGroupsInUse(*g);
  for (const CoefficientGroup& group : groups) {
    ReleaseHeldCoefficients(fit.model.config, candidate.gyro, group.first, group.count,
                            DegPerHourToRadPerSec(kHeldSigmaDegH));
  }
  fit.time.kind = kTimeCoefficientStep;
  fit.parameters = 0;
  fit.run = *ctx.model_run;
  const std::vector<TelemetryFrame> frames =
      CorrectStarTracker(*ctx.frames, *ctx.rates, fit.model.correction);
  const std::vector<int> grid_frames = GridFrames(frames);
  if (grid_frames.empty()) return absl::OkStatus();  // too short: no step fitted
  const double base_value = Profile(*ctx.model_run).value;

  std::vector<GroupStep> steps;
  std::vector<std::string> refused_notes;  // groups whose step does not carry its gain
  SharedPrefix shared;
  for (const CoefficientGroup& group : groups) {
    RETURN_IF_ERROR(SearchGroup(candidate, fit, frames, group, grid_frames, base_value, opt,
                                shared, steps, refused_notes));
  }
  fit.notes.insert(fit.notes.end(), refused_notes.begin(), refused_notes.end());
  if (steps.empty()) {
    fit.not_fitted = absl::StrJoin(refused_notes, "; ");
    return absl::OkStatus();
  }
  const size_t best = AddGroupPriorPoints(steps, groups.size(), fit);
  DescribeGroupStep(candidate, *g, opt.c_sigma_deg_h, steps[best], fit);
  AddGroupNotes(steps, groups.size(), fit);
  return absl::OkStatus();
}

}  // namespace esg::estimator::discovery
