#include "estimator/discovery/selection.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <optional>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/discovery/basis_stage.h"
#include "estimator/discovery/channel_candidate.h"
#include "estimator/discovery/point_prediction.h"
#include "estimator/discovery/sun_terms.h"
#include "estimator/discovery/time_behaviour.h"
#include "estimator/discovery/turning_displacement.h"
#include "estimator/discovery/wander.h"
#include "estimator/statistics.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

namespace {

constexpr int kQuarters = 4;  // time blocks of the homogeneity test

// A candidate's score in the round.
struct Scored {
  int index;  // into the round's candidates and fits
  double delta, penalty, score, p, threshold;  // score: the evidence 2 ln B; p: 1 / B
  bool significant;
  std::array<double, kQuarters> quarters{};  // improvement of -2 log L per quarter
  bool homogeneous = true;
};

// The candidates decided by held-out prediction, with their held-out results.
using Contenders = std::vector<std::pair<int, HeldOutResult>>;

// Fits every candidate on top of `selected`, in parallel through the context's runner (costly
// candidates first for load balance). A fit skipped for cancellation stays empty. Progress counts
// the round's candidates: `already` of its `family` were fitted by an earlier stage of the round,
// so the fraction said never goes back.
std::vector<std::optional<absl::StatusOr<CandidateFit>>> FitCandidates(
    const std::vector<Candidate>& candidates, int round, int already, int family,
    const std::vector<int>& gyros, const SelectedModel& selected, DiagnosisContext& context) {
  const DiagnoseOptions& options = context.options();
  FitContext ctx;
  ctx.frames = &context.frames();
  ctx.rates = &context.rates();
  ctx.model = &selected.model;
  ctx.model_run = &selected.run;
  ctx.options = &options;
  ctx.gyros = gyros;
  ctx.regimes = &context.regimes();
  std::vector<std::optional<absl::StatusOr<CandidateFit>>> fits(candidates.size());
  std::vector<int> order(candidates.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  auto cost = [](const Candidate& c) {
    if (c.effect == Effect::kDriftStep) return 12;
    if (c.effect == Effect::kWarmUp) return 11;  // 7 + 4 time constants, full runs
    if (c.effect == Effect::kCoefficientStep) return 12;  // the drift step's onsets per group
    if (c.effect == Effect::kTransient) return 14;  // the step's onsets, then 10 time constants
    if (c.effect == Effect::kReadoutDistortion) return 2;  // a regression and a run
    if (c.effect == Effect::kSunDrift) return 3;  // six faces' regressions and a run
    if (c.effect == Effect::kTurningDisplacement) return 3;  // a period's regressions and a run
    if (c.effect == Effect::kChannelDrift) return kChannelCandidateRuns;  // full runs
    return c.effect == Effect::kRandomWalkDrift ? 5 : (c.gyro == 0 ? 3 : 1);
  };
  std::stable_sort(order.begin(), order.end(),
                   [&](int a, int b) { return cost(candidates[a]) > cost(candidates[b]); });
  std::atomic<int> done{0};
  context.ForEach(static_cast<int>(order.size()), [&](int j) {
    if (context.Stop()) return;
    const int i = order[j];
    fits[i] = FitCandidate(candidates[i], ctx);
    const int d = already + ++done;
    context.Say(0.05 + 0.8 * (round + static_cast<double>(d) / family) / options.max_effects,
                absl::StrFormat("round %d: %s fitted (%d/%d)", round + 1,
                                CandidateName(candidates[i]), d, family));
  });
  return fits;
}

// Evidence, significance and homogeneity of each fit against the selected model
// (docs/discovery.md "Evidence"): 2 ln B, B the Bayes factor of the model with the effect
// against the selected one, significant above 2 ln(family / alpha).
std::vector<Scored> Score(const std::vector<CandidateFit>& fits, const SelectedModel& selected,
                          int family, const DiagnosisContext& context) {
  const DiagnoseOptions& options = context.options();
  const std::vector<double> current_steps = StepDeviance(selected.run);
  std::vector<Scored> scored;
  for (size_t i = 0; i < fits.size(); ++i) {
    const CandidateFit& f = fits[i];
    const ProfiledDeviance d = Profile(f.run);
    Scored s;
    s.index = static_cast<int>(i);
    s.delta = selected.fit.value - d.value;
    // Parameters freed with a prior: the run's likelihood is their marginal likelihood. A
    // searched parameter: integrated over its prior's grid, or Laplace's approximation.
    double evidence = s.delta - f.occam;
    if (!f.prior_points.empty()) {
      std::vector<std::pair<double, double>> points;
      for (const auto& [w, value] : f.prior_points)
        points.emplace_back(w, selected.fit.value - value);
      evidence = EvidenceOverPrior(points);
    }
    s.score = evidence;
    s.penalty = s.delta - evidence;
    s.p = EvidenceBound(evidence);
    s.threshold = EvidenceThreshold(options.alpha, family);
    s.significant = f.parameters > 0 && evidence > s.threshold;
    const int k = std::max(1, f.parameters);
    // Homogeneity: the effects of the library are constant in time. With its parameters held
    // from the start at their final values, an effect that makes the fit worse in a quarter of
    // the recording by more than its cost there (k ln n_q, plus the chi-square quantile) while
    // improving it elsewhere is fitting a change in time (a fault, a jump), not the physics it
    // names. In the same currency: a quarter's -2 log L with the effect held against without
    // it is 2 ln B of the two simple models there; it may worsen by the k ln n_q its fitted
    // parameters can cost by chance, plus the evidence threshold over the quarters.
    const std::vector<double> cand_steps = StepDeviance(f.fixed_run ? *f.fixed_run : f.run);
    std::array<int, kQuarters> steps_in{};
    for (size_t j = 0; j < std::min(current_steps.size(), cand_steps.size()); ++j) {
      const int q = std::min(
          kQuarters - 1,
          static_cast<int>(kQuarters * selected.run.steps[j].frame / context.frames().size()));
      s.quarters[q] += current_steps[j] - cand_steps[j];
      ++steps_in[q];
    }
    // A step or a random walk describes a change in time itself: tested by its own likelihood
    // ratio above, not by this test of a constant effect. A drift that follows the sun has
    // constant coefficients of a known function of time: held from the start, it is tested.
    const bool constant = f.time.kind == "constant" || f.time.kind == kTimeFollowsSun;
    for (int q = 0; q < kQuarters && constant; ++q) {
      const double cost = k * std::log(std::max(2, steps_in[q])) +
                          EvidenceThreshold(options.alpha, kQuarters);
      if (s.quarters[q] < -cost) s.homogeneous = false;
    }
    scored.push_back(s);
  }
  return scored;
}

// The significant candidates, best score first. Deterministic effects first: the random walk is
// the model's allowance for what no deterministic term explains, raised only when none of them
// does. The best-scoring significant candidate must be homogeneous in time; when it is not, the
// mismatch is a change in time (the smaller candidates that pass are its spill-over into the
// other gyros through the shared star tracker): none is returned and `inhomogeneous_only` is set.
// The fits in `refused` (an effect that failed its physics check, CheckConstantEffect) are left
// out, significant or not.
std::vector<Scored> SignificantInOrder(const std::vector<Scored>& scored,
                                       const std::vector<CandidateFit>& fits,
                                       const std::vector<int>& refused, bool& inhomogeneous_only) {
  std::vector<Scored> significant;
  inhomogeneous_only = false;
  for (int pass = 0; pass < 2 && significant.empty() && !inhomogeneous_only; ++pass) {
    std::vector<Scored> pool;
    for (const Scored& s : scored) {
      const bool rw = fits[s.index].candidate.effect == Effect::kRandomWalkDrift;
      const bool out = std::find(refused.begin(), refused.end(), s.index) != refused.end();
      if (s.significant && !out && rw == (pass == 1)) pool.push_back(s);
    }
    if (pool.empty()) continue;
    const auto top =
        std::max_element(pool.begin(), pool.end(),
                         [](const Scored& a, const Scored& b) { return a.score < b.score; });
    if (!top->homogeneous) {
      // A change in time. A raised random walk (its own test) that explains at least as much
      // describes it; otherwise it is unexplained.
      const Scored* walk = nullptr;
      for (const Scored& x : scored) {
        if (fits[x.index].candidate.effect == Effect::kRandomWalkDrift && x.significant &&
            (walk == nullptr || x.score > walk->score)) {
          walk = &x;
        }
      }
      if (pass == 0 && walk != nullptr && walk->score >= top->score) continue;
      inhomogeneous_only = true;
      break;
    }
    for (const Scored& s : pool) {
      if (s.homogeneous) significant.push_back(s);
    }
  }
  std::sort(significant.begin(), significant.end(),
            [](const Scored& a, const Scored& b) { return a.score > b.score; });
  return significant;
}

// A drift instability can be partly fitted by a deterministic term. When the random walk is
// significant too, the best deterministic candidate is tested on top of it (the nested
// comparison): if it adds nothing significant beyond the raised random walk, the random walk is
// the explanation and `significant` becomes it alone. Returns the note for the finding (empty
// when the comparison was not made).
absl::StatusOr<std::string> PreferRandomWalk(const std::vector<Scored>& scored,
                                             const std::vector<CandidateFit>& fits, int family,
                                             const std::vector<int>& failed,
                                             std::vector<Scored>& significant,
                                             DiagnosisContext& context) {
  if (significant.empty() ||
      fits[significant.front().index].candidate.effect == Effect::kRandomWalkDrift) {
    return std::string();
  }
  const Scored* rw = nullptr;  // the best-scoring significant random walk, common or per gyro
  for (const Scored& x : scored) {
    if (fits[x.index].candidate.effect == Effect::kRandomWalkDrift && x.significant &&
        x.homogeneous && std::find(failed.begin(), failed.end(), x.index) == failed.end() &&
        (rw == nullptr || x.score > rw->score))
      rw = &x;
  }
  if (rw == nullptr) return std::string();
  const CandidateFit& det = fits[significant.front().index];
  const CandidateFit& walk = fits[rw->index];
  ModelState both = det.model;
  both.config.random_walk = walk.model.config.random_walk;
  both.options.random_walk_by_gyro = walk.model.options.random_walk_by_gyro;
  auto run = context.CheckedRun(both, /*held_out=*/false);
  if (!run.ok()) return run.status();
  // The deterministic effect's evidence on top of the walk: its likelihood gain there, less
  // the prior's cost of its searched parameters (as in its own score).
  const double gain = Profile(walk.run).value - Profile(*run).value - significant.front().penalty;
  const double threshold = EvidenceThreshold(context.options().alpha, family);
  std::string note = absl::StrFormat(
      "on top of a random walk raised to %.4f deg/h/sqrt(h) (%s) its evidence is still 2 ln B = "
      "%.1f (threshold %.1f)",
      SiToDegPerHourSqrtHour(walk.fitted.empty() ? walk.model.config.random_walk
                                                 : DegPerHourSqrtHourToSi(walk.fitted[0].value)),
      CandidateName(walk.candidate), gain, threshold);
  if (!(gain > threshold)) {
    // A turning displacement is a change in time itself, as a walk is, and a walk raised enough
    // follows any slow change: the nested test both ways. When the walk adds nothing
    // significant on top of the turn either, the two describe the same drift and the larger
    // evidence decides (the walk's intensity was fitted without the turn, so it absorbs it).
    if (det.candidate.effect == Effect::kTurningDisplacement) {
      const double walk_gain = Profile(det.run).value - Profile(*run).value - rw->penalty;
      if (!(walk_gain > threshold) && significant.front().score > rw->score) {
        return absl::StrFormat(
            "on top of a random walk raised to %.4f deg/h/sqrt(h) (%s) it adds 2 ln B = %.1f, "
            "and the walk adds %.1f on top of it (threshold %.1f): the two describe the same "
            "drift, and the turn's evidence is the larger (2 ln B %.1f against %.1f)",
            SiToDegPerHourSqrtHour(walk.fitted.empty()
                                       ? walk.model.config.random_walk
                                       : DegPerHourSqrtHourToSi(walk.fitted[0].value)),
            CandidateName(walk.candidate), gain, walk_gain, threshold,
            significant.front().score, rw->score);
      }
    }
    significant.assign(1, *rw);
    note = absl::StrFormat(
        "%s fits part of it but adds nothing significant on top of the raised random walk "
        "(2 ln B = %.1f, threshold %.1f)",
        CandidateName(det.candidate), gain, threshold);
  }
  return note;
}

// Held-out runs of the fits `indices` (a fit without parameters is skipped), in parallel; a run
// skipped is left empty.
std::vector<std::optional<absl::StatusOr<ModelRun>>> HeldOutRuns(
    const std::vector<int>& indices, const std::vector<CandidateFit>& fits, bool skip_empty,
    DiagnosisContext& context) {
  std::vector<std::optional<absl::StatusOr<ModelRun>>> held(indices.size());
  context.ForEach(static_cast<int>(indices.size()), [&](int j) {
    if (context.Stop()) return;
    const CandidateFit& f = fits[indices[j]];
    if (skip_empty && f.parameters == 0) return;
    held[j] = context.Run(f.model, /*held_out=*/true);
  });
  return held;
}

// Among the significant candidates the best evidence wins; candidates the recording does not
// tell apart (within kDecisiveDeviance of the best) are decided by held-out prediction: the
// lowest held-out deviance (-2 log predictive density), the same currency out of sample. Returns the index of the chosen fit; `contenders` gets the held-out results when they
// decided.
absl::StatusOr<int> ChooseAmongSignificant(const std::vector<Scored>& significant,
                                           const std::vector<CandidateFit>& fits, int round,
                                           Contenders& contenders, DiagnosisContext& context) {
  int chosen = significant.front().index;
  std::vector<int> close;
  for (const Scored& s : significant) {
    if (s.score >= significant.front().score - kDecisiveDeviance) close.push_back(s.index);
  }
  if (close.size() <= 1 || context.gaps().empty()) return chosen;
  context.Say(0.05 + 0.8 * (round + 0.95) / context.options().max_effects,
              "held-out comparison of close candidates");
  auto held = HeldOutRuns(close, fits, /*skip_empty=*/false, context);
  if (context.Stopped()) return DiagnosisContext::Cancelled();
  context.CountRuns(static_cast<int>(close.size()));
  double best = 1e300;
  for (size_t j = 0; j < close.size(); ++j) {
    if (!held[j]->ok()) return held[j]->status();
    HeldOutResult r = SummariseHeldOut(**held[j], context.gaps(), context.regimes(),
                                       context.frames());
    if (r.deviance < best) {
      best = r.deviance;
      chosen = close[j];
    }
    contenders.emplace_back(close[j], std::move(r));
  }
  return chosen;
}

// Concealed effects: nothing significant in-sample (the residual-drift states absorb the effect
// where it was calibrated), yet the selected model mispredicts the held-out regimes. Then the
// candidates are scored by held-out prediction: the one whose held-out deviance (-2 log
// predictive density) falls the most, by more than the evidence threshold over the round's
// candidates, is taken (the drop is 2 ln of the ratio of the two models' predictive densities
// of data neither was fitted to: no parameter count enters), unless it makes the held-out point
// prediction worse (point_prediction.h; those go to `worsened` with their notes). Returns its
// index or -1; `contenders` gets the held-out results when one is taken.
absl::StatusOr<int> ChooseByHeldOut(const std::vector<Scored>& scored,
                                    const std::vector<CandidateFit>& fits, int round,
                                    SelectedModel& selected, Contenders& contenders,
                                    std::vector<std::pair<int, std::string>>& worsened,
                                    DiagnosisContext& context) {
  const DiagnoseOptions& options = context.options();
  if (!selected.held_out_current && !context.gaps().empty()) {
    auto held = context.CheckedRun(selected.model, /*held_out=*/true);
    if (!held.ok()) return held.status();
    selected.held_out =
        SummariseHeldOut(*held, context.gaps(), context.regimes(), context.frames());
    selected.held_out_current = true;
  }
  if (!MispredictsHeldOut(selected.held_out, options.alpha)) return -1;
  context.Say(0.05 + 0.8 * (round + 0.95) / options.max_effects,
              "held-out scoring of the candidates (concealed mismatch)");
  std::vector<int> indices;
  for (const Scored& s : scored) indices.push_back(s.index);
  auto held = HeldOutRuns(indices, fits, /*skip_empty=*/true, context);
  if (context.Stopped()) return DiagnosisContext::Cancelled();
  int chosen = -1;
  double best_drop = 0.0;
  for (size_t j = 0; j < scored.size(); ++j) {
    if (!held[j].has_value()) continue;
    context.CountRuns(1);
    if (!held[j]->ok()) return held[j]->status();
    HeldOutResult r = SummariseHeldOut(**held[j], context.gaps(), context.regimes(),
                                       context.frames());
    const double drop = selected.held_out.deviance - r.deviance;
    const double needed =
        EvidenceThreshold(options.alpha, static_cast<int>(scored.size()));
    // The point-prediction guard (point_prediction.h): a drop of the predictive density bought
    // by a wider covariance while the predicted attitude drifts away faster is not taken.
    if (drop > needed && scored[j].homogeneous && WorsensPointPrediction(selected.held_out, r)) {
      worsened.emplace_back(scored[j].index,
                            PointPredictionNote(CandidateName(fits[scored[j].index].candidate),
                                                selected.held_out, r));
    } else if (drop > needed && drop > best_drop && scored[j].homogeneous) {
      best_drop = drop;
      chosen = scored[j].index;
    }
    contenders.emplace_back(scored[j].index, std::move(r));
  }
  if (chosen < 0) contenders.clear();
  return chosen;
}

// The round's choice through the point-prediction guard (point_prediction.h): the significant
// candidates (ChooseAmongSignificant), else, unless the mismatch is a change in time, the
// candidates scored by held-out prediction (ChooseByHeldOut), leaving out the fits that failed
// their physics check. A chosen fit whose held-out gap drift is more than 5% worse than the
// selected model's is not taken, whatever its evidence or predictive density, and the choice is
// made again without it.
struct Choice {
  int chosen = -1;
  bool held_out_selected = false;
  Contenders contenders;
  // The chosen fit's held-out prediction when the guard ran it (not among the contenders).
  std::optional<HeldOutResult> guard_held_out;
  std::vector<std::pair<int, std::string>> worsened;  // fits the guard left out, their notes
};
absl::StatusOr<Choice> ChooseGuarded(std::vector<Scored> significant,
                                     const std::vector<Scored>& scored,
                                     const std::vector<CandidateFit>& fits,
                                     const std::vector<int>& failed, bool inhomogeneous_only,
                                     int round, SelectedModel& selected,
                                     DiagnosisContext& context) {
  Choice out;
  auto refused = [&](int index) {
    return std::any_of(out.worsened.begin(), out.worsened.end(),
                       [&](const auto& w) { return w.first == index; });
  };
  for (;;) {
    out.chosen = -1;
    out.held_out_selected = false;
    out.contenders.clear();
    std::erase_if(significant, [&](const Scored& s) { return refused(s.index); });
    if (!significant.empty()) {
      auto c = ChooseAmongSignificant(significant, fits, round, out.contenders, context);
      if (!c.ok()) return c.status();
      out.chosen = *c;
    }
    if (out.chosen < 0 && !inhomogeneous_only) {
      std::vector<Scored> left;  // an effect that failed its physics check is not one
      for (const Scored& x : scored) {
        if (std::find(failed.begin(), failed.end(), x.index) == failed.end() &&
            !refused(x.index)) {
          left.push_back(x);
        }
      }
      auto c = ChooseByHeldOut(left, fits, round, selected, out.contenders, out.worsened, context);
      if (!c.ok()) return c.status();
      out.chosen = *c;
      out.held_out_selected = out.chosen >= 0;
    }
    if (out.chosen < 0) return out;
    const CandidateFit& f = fits[out.chosen];
    const auto ran = std::find_if(out.contenders.begin(), out.contenders.end(),
                                  [&](const auto& c) { return c.first == out.chosen; });
    if (ran == out.contenders.end()) {
      auto check = CheckPointPrediction(f.model, CandidateName(f.candidate), selected, context);
      if (!check.ok()) return check.status();
      if (!check->worsens) {
        if (!context.gaps().empty()) out.guard_held_out = std::move(check->held_out);
        return out;
      }
      out.worsened.emplace_back(out.chosen, std::move(check->note));
      continue;
    }
    if (absl::Status s = MakeHeldOutCurrent(selected, context); !s.ok()) return s;
    if (!WorsensPointPrediction(selected.held_out, ran->second)) return out;
    out.worsened.emplace_back(
        out.chosen, PointPredictionNote(CandidateName(f.candidate), selected.held_out, ran->second));
  }
}

CandidateScore Row(const Scored& s, const CandidateFit& f, int round, int chosen) {
  CandidateScore row;
  row.effect = EffectId(f.candidate.effect);
  row.gyro = f.candidate.gyro;
  row.round = round;
  row.parameters = f.parameters;
  row.delta_deviance = s.delta;
  row.penalty = s.penalty;
  row.score = s.score;
  row.p_value = s.p;
  row.significant = s.significant;
  row.homogeneous = s.homogeneous;
  row.selected = s.index == chosen;
  row.time_behaviour = f.time.kind;
  row.not_fitted = f.not_fitted;
  if (f.time.kind == "step" || f.time.kind == kTimeCoefficientStep ||
      f.time.kind == kTimeTransient) {
    row.onset_hours = f.time.onset_hours;
  }
  return row;
}

// The finding of the chosen fit, with its evidence and the notes that support it; takes its
// held-out result into `selected` when held-out prediction was run for it.
Finding MakeFinding(const Scored& s, const std::vector<CandidateFit>& fits, int chosen, int round,
                    const std::string& rw_note, bool held_out_selected,
                    const Contenders& contenders, SelectedModel& selected) {
  const CandidateFit& f = fits[chosen];
  Finding finding;
  finding.effect = EffectId(f.candidate.effect);
  if (f.candidate.effect == Effect::kReadoutDistortion) {  // the basis's readout group
    finding.effect = kEffectBasisTerm;
    finding.description = f.description;
    finding.readout_distortion = f.readout_distortion;
  }
  if (f.candidate.effect == Effect::kChannelDrift) {  // three channel terms of the basis
    finding.effect = kEffectBasisTerm;
    finding.description = f.description;
    finding.basis_terms = f.basis_terms;
  }
  if (f.candidate.effect == Effect::kSunDrift) {  // the basis's sun families
    finding.effect = kEffectBasisTerm;
    finding.description = f.description;
  }
  // Three exponential_decay terms of the basis; spin_axis_harmonic terms switched on at a
  // coefficient step's onset (D110).
  if (f.candidate.effect == Effect::kWarmUp || f.candidate.effect == Effect::kCoefficientStep ||
      f.candidate.effect == Effect::kTransient ||
      f.candidate.effect == Effect::kTurningDisplacement) {
    finding.effect = kEffectBasisTerm;
    finding.description = f.description;
    finding.basis_terms = f.basis_terms;
  }
  finding.gyro = f.candidate.gyro;
  finding.parameters = f.fitted;
  finding.time = f.time;
  finding.displacement_trend = f.displacement_trend;
  if (!f.onset_profile.empty()) {
    double best = f.onset_profile.front().second;
    for (const auto& point : f.onset_profile) best = std::min(best, point.second);
    for (const auto& [hours, value] : f.onset_profile)
      finding.time.onset_profile.emplace_back(hours, value - best);
  }
  finding.evidence.delta_deviance = s.delta;
  finding.evidence.penalty = s.penalty;
  finding.evidence.evidence = s.score;
  finding.evidence.parameters = f.parameters;
  finding.evidence.p_value = s.p;
  finding.evidence.threshold = s.threshold;
  finding.evidence.round = round;
  finding.evidence.notes = f.notes;
  finding.explanation = ExplainFinding(finding);
  if (!rw_note.empty()) finding.evidence.notes.push_back(rw_note);
  if (held_out_selected) {
    finding.evidence.notes.insert(
        finding.evidence.notes.begin(),
        "concealed: not significant in-sample (absorbed where calibrated), found by "
        "held-out prediction across regimes");
  }
  for (const auto& [index, r] : contenders) {
    if (index == chosen) {
      finding.evidence.held_out_nees_before = selected.held_out.nees;
      finding.evidence.held_out_nees_after = r.nees;
      finding.evidence.held_out_deviance_before = selected.held_out.deviance;
      finding.evidence.held_out_deviance_after = r.deviance;
      finding.evidence.held_out_dof = r.dof;
      selected.held_out = r;
    } else if (!held_out_selected) {
      finding.evidence.notes.push_back(absl::StrFormat(
          "%s fits the star tracker almost as well (2 ln B within %.0f) but predicts the "
          "held-out spans worse: held-out -2 log predictive density %.1f higher (NEES %.1f "
          "against %.1f)",
          CandidateName(fits[index].candidate), kDecisiveDeviance,
          r.deviance - std::find_if(contenders.begin(), contenders.end(), [&](const auto& c) {
                         return c.first == chosen;
                       })->second.deviance,
          r.nees,
          std::find_if(contenders.begin(), contenders.end(), [&](const auto& c) {
            return c.first == chosen;
          })->second.nees));
    }
  }
  const std::string behaviour =
      f.time.kind == "step"
          ? "a step: no change before its onset, its evidence integrated over the onset"
      : f.time.kind == "random_walk"
          ? "a random walk: its evidence integrated over the intensity, not the constant-effect "
            "test"
      : f.time.kind == kTimeFollowsSun
          ? "a drift that follows the sun: its coefficients constant in time, held from the start"
      : f.time.kind == kTimeFollowsChannel
          ? "a drift that follows a housekeeping channel: its coefficients constant, the channel "
            "changing in time; its evidence integrated over the forms and the lag, not the "
            "constant-effect test"
      : f.time.kind == kTimeWarmUp
          ? "a warm-up: a transient decaying from the start, its evidence integrated over the "
            "time constant, not the constant-effect test"
      : f.time.kind == kTimeTransient
          ? "a transient from an onset: no change before it, its evidence integrated over the "
            "onset and the time constant, not the constant-effect test"
      : f.time.kind == kTimeCoefficientStep
          ? "a step of drift coefficients: no change before its onset, its evidence integrated "
            "over the onset and the coefficient group, not the constant-effect test"
      : f.time.kind == kTimeTurning
          ? "a turning displacement: C1 and C2 cycling with a period, its evidence integrated "
            "over the period, not the constant-effect test"
          : "constant in time, as a physical effect of the library is";
  finding.evidence.notes.push_back(absl::StrFormat(
      "improvement per quarter of the recording (-2 log L): %.1f, %.1f, %.1f, %.1f (%s)",
      s.quarters[0], s.quarters[1], s.quarters[2], s.quarters[3], behaviour));
  return finding;
}

// At most this many constant effects of a round fail their physics checks before the round goes
// on without checking further ones.
constexpr int kMaxFailedChecks = 3;

// The physics check that decides whether a constant effect of the library for one gyro is what
// it names (docs/discovery.md, "Physics checks that decide"): a rotor displacement, a fourth
// harmonic, unequal stiffness (functions of the spin axis in case axes) and a misalignment (a
// rotation of the readout) change their signature with the attitude, so they fit part of any
// drift of that gyro that changes in time. On the gyro's deviation from the current model
// (wander.h), a drift that returns to its mean describing it decisively better (by
// kDecisiveDeviance), while the effect's terms add nothing significant on top of it, says the
// constant effect is not the physics (with the open-ended stage on). An effect that fails is not
// taken as itself: the round goes on to the time behaviours and the open-ended stage, which
// decide what the drift is. `note` says what was compared, whether it passed or not.
struct PhysicsCheck {
  bool fails = false;
  std::string note;
};
absl::StatusOr<PhysicsCheck> CheckConstantEffect(const CandidateFit& fit,
                                                 const SelectedModel& selected, int family,
                                                 const DiagnosisContext& context) {
  PhysicsCheck out;
  const Candidate& c = fit.candidate;
  const DiagnoseOptions& options = context.options();
  if ((c.effect == Effect::kSunDrift || c.effect == Effect::kTurningDisplacement) &&
      fit.wander_compared) {
    // The sun's terms at the best lag (a turning displacement's at the best period), compared on
    // the deviation the candidate regressed, by the open-ended stage's rule for its terms (GyrosOutdoneByAStationaryDrift): a group of the
    // basis whose gyro's deviation a drift that returns to its mean describes better is not
    // taken. (The library's rule for its constant effects, decisively better and nothing on top,
    // let the sun's terms of a switching drift through: what a stationary drift leaves of a
    // switching one is not white, and a lagged illumination fits part of it.)
    const double threshold = EvidenceThreshold(options.alpha, family);
    const bool sun = c.effect == Effect::kSunDrift;
    const char* terms = sun ? "the sun's terms" : "the turning terms (less the period's Occam term)";
    const char* what = sun ? "a drift that follows the sun" : "a turning rotor displacement";
    out.fails = fit.wander_stationary > fit.wander_effect;
    out.note =
        out.fails
            ? absl::StrFormat(
                  "%s fits part of gyro %d's drift, but on the gyro's deviation a drift that "
                  "returns to its mean describes it better (2 ln B = %.1f against %.1f; "
                  "%s add 2 ln B = %.1f on top of it, threshold %.1f): not taken as %s",
                  CandidateName(c), c.gyro, fit.wander_stationary, fit.wander_effect, terms,
                  fit.wander_on_top, threshold, what)
            : absl::StrFormat(
                  "on gyro %d's deviation %s have 2 ln B = %.1f, more than a drift that returns "
                  "to its mean (2 ln B = %.1f; the terms add %.1f on top of it, threshold %.1f): "
                  "%s, not a wandering drift",
                  c.gyro, terms, fit.wander_effect, fit.wander_stationary, fit.wander_on_top,
                  threshold, what);
    return out;
  }
  if (!options.open_ended || c.gyro <= 0 ||
      !(c.effect == Effect::kRotorDisplacement || c.effect == Effect::kFourthHarmonic ||
        c.effect == Effect::kUnequalStiffness || c.effect == Effect::kGyroMisalignment)) {
    return out;
  }
  // A rotor displacement must be seen in the suspension voltages where they can show it (eq. (3)).
  std::string voltage_note;
  if (c.effect == Effect::kRotorDisplacement) {
    if (const GyroEstimate* g = FindEstimate(fit.run.gyros, c.gyro)) {
      const VoltageAgreement v =
          CheckDisplacementAgainstVoltages(fit.model.config, context.frames(), c.gyro,
                                           g->coefficients.C1);
      if (!v.agrees) {
        out.fails = true;
        out.note = absl::StrFormat("%s fits part of gyro %d's drift, but %s: not taken",
                                   CandidateName(c), c.gyro, v.note);
        return out;
      }
      voltage_note = absl::StrCat("; ", v.note);
    }
  }
  auto e = CompareConstantEffectOf(selected, context, c);
  if (!e.ok()) return e.status();
  const double threshold = EvidenceThreshold(options.alpha, family);
  out.fails = e->stationary > e->effect + kDecisiveDeviance && !(e->on_top > threshold);
  out.note = out.fails
                 ? absl::StrFormat(
                       "%s fits part of gyro %d's drift, but on the gyro's deviation a drift "
                       "that returns to its mean describes it decisively better (2 ln B = %.1f "
                       "against %.1f) and the effect's terms add 2 ln B = %.1f on top of it "
                       "(threshold %.1f): not taken as a constant effect",
                       CandidateName(c), c.gyro, e->stationary, e->effect, e->on_top, threshold)
                 : absl::StrFormat(
                       "on gyro %d's deviation its terms have 2 ln B = %.1f, and add %.1f on top "
                       "of a drift that returns to its mean (2 ln B = %.1f alone; threshold "
                       "%.1f): a constant effect, not a wandering drift",
                       c.gyro, e->effect, e->on_top, e->stationary, threshold);
  if (!out.fails) out.note += voltage_note;
  return out;
}

// The working state of one selection round, shared by its decisions below.
struct RoundState {
  std::vector<Candidate> candidates;
  // Two stages. The constant effects (and the common random walk) first; the time behaviours
  // (a drift step per gyro, a random walk per gyro: many runs each) only when those leave the
  // round open: nothing significant, a change in time (the best is inhomogeneous), or a random
  // walk. Every threshold counts the whole round's candidates, fitted or not (2 ln(M / alpha)).
  std::vector<Candidate> constant, timed;
  int family = 0;  // M: each comparison once, a sun candidate one per face it may try (D101)
  std::vector<CandidateFit> fits;
  std::vector<Scored> scored;
  std::vector<Scored> significant;
  bool inhomogeneous_only = false;
  std::string rw_note;  // PreferRandomWalk's note for the finding
  // Constant effects of one gyro that fail their physics checks (CheckConstantEffect): left out
  // of the selection (their rows keep what the evidence says); their notes.
  std::vector<int> failed;
  std::vector<std::pair<int, std::string>> failed_notes;    // gyro, note
  std::vector<std::pair<int, std::string>> constant_notes;  // fit index, the check it passed
  std::string readout_note;  // a readout jump explains the round as well (D43)
  std::string basis_note;    // the open-ended basis was compared and not taken
  // The comparison of a per-gyro time behaviour with a drift that returns to its mean (wander.h),
  // computed once when needed.
  std::optional<DriftBehaviourEvidence> behaviour;
  std::string wander_note;
  Mismatch wander_where;
  double wander_evidence = -1.0;
};

// The round's candidates, split into its two stages, and M.
void ListRoundCandidates(RoundState& st, const std::vector<int>& gyros,
                         const SelectedModel& selected, const DiagnoseOptions& options) {
  const bool with_orbit = options.orbit != nullptr;
  st.candidates = ListCandidates(selected.model, gyros, options.effects, with_orbit);
  if (!options.open_ended) {  // the basis's readout group and sun families belong to it
    std::erase_if(st.candidates, [](const Candidate& c) {
      return c.effect == Effect::kReadoutDistortion || c.effect == Effect::kSunDrift;
    });
  }
  for (const Candidate& c : st.candidates) {
    const bool time_behaviour = c.effect == Effect::kDriftStep || c.effect == Effect::kWarmUp ||
                                c.effect == Effect::kCoefficientStep ||
                                c.effect == Effect::kTransient ||
                                c.effect == Effect::kTurningDisplacement ||
                                (c.effect == Effect::kRandomWalkDrift && c.gyro > 0);
    (time_behaviour ? st.timed : st.constant).push_back(c);
  }
  for (const Candidate& c : st.candidates) {
    st.family += CandidateComparisons(c, selected.model, with_orbit);
  }
}

// Fits a stage's candidates into st.fits.
absl::Status FitStage(RoundState& st, const std::vector<Candidate>& stage, int round,
                      const std::vector<int>& gyros, const SelectedModel& selected,
                      DiagnosisContext& context) {
  auto fitted = FitCandidates(stage, round, static_cast<int>(st.fits.size()),
                              static_cast<int>(st.candidates.size()), gyros, selected, context);
  if (context.Stopped()) return DiagnosisContext::Cancelled();
  for (auto& f : fitted) {
    if (!f->ok()) return f->status();
    context.CountRuns((*f)->runs);
    st.fits.push_back(std::move(**f));
  }
  return absl::OkStatus();
}

// The significant candidates of the round, stage by stage: the best must pass its physics check
// (CheckConstantEffect), or, when a walk tops, the walk of every gyro must be common
// (CheckCommonWalk); a candidate that fails is left out and the next is tried, up to
// kMaxFailedChecks.
absl::Status SettleSignificant(RoundState& st, int round, const std::vector<int>& gyros,
                               const SelectedModel& selected, DiagnosisContext& context) {
  for (int stage = 0; stage < 2; ++stage) {
    RETURN_IF_ERROR(
        FitStage(st, stage == 0 ? st.constant : st.timed, round, gyros, selected, context));
    bool settled = false;
    st.scored = Score(st.fits, selected, st.family, context);
    for (;;) {
      st.significant = SignificantInOrder(st.scored, st.fits, st.failed, st.inhomogeneous_only);
      ASSIGN_OR_RETURN(st.rw_note, PreferRandomWalk(st.scored, st.fits, st.family, st.failed,
                                                    st.significant, context));
      settled = !st.significant.empty() &&
                st.fits[st.significant.front().index].candidate.effect != Effect::kRandomWalkDrift;
      if (st.significant.empty() || static_cast<int>(st.failed.size()) >= kMaxFailedChecks) break;
      const int top = st.significant.front().index;
      if (!settled) {
        // A walk tops: the walk of every gyro must be common (wander.h CheckCommonWalk), tested
        // once every candidate of the round is fitted.
        if (stage == 0 && !st.timed.empty()) break;
        if (st.fits[top].candidate.gyro != 0 || gyros.size() < 2) break;
        auto common = CheckCommonWalk(selected, context, gyros);
        if (!common.ok()) return common.status();
        if (!common->fails) {
          st.constant_notes.emplace_back(top, std::move(common->note));
          break;
        }
        st.failed.push_back(top);
        st.failed_notes.emplace_back(0, std::move(common->note));
        continue;
      }
      auto check = CheckConstantEffect(st.fits[top], selected, st.family, context);
      if (!check.ok()) return check.status();
      if (!check->fails) {
        if (!check->note.empty()) st.constant_notes.emplace_back(top, std::move(check->note));
        break;
      }
      st.failed.push_back(top);
      st.failed_notes.emplace_back(st.fits[top].candidate.gyro, std::move(check->note));
    }
    if (settled || st.timed.empty()) break;
  }
  return absl::OkStatus();
}

// A time behaviour must explain the recording better than a jump of the gyro's readings at the
// onset (D43): a step of the readings is no physics of the library, and a drift step or a walk
// that fits it only in part is the nearest candidate forced onto a fault. Same currency: the
// jump's evidence 2 ln B, its best onset's likelihood gain less the cost of the onset's prior
// (the step's own, over the same onsets; the jump has 3 parameters freed with a prior, as the
// step). When the readout jump does at least as well, nothing is taken and the mismatch is
// left unexplained, located in time.
void PreferReadoutJump(RoundState& st, const SelectedModel& selected, RoundResult& result) {
  if (st.significant.empty()) return;
  const Scored& top = st.significant.front();
  const Candidate& c = st.fits[top.index].candidate;
  const bool timed_top = c.effect == Effect::kDriftStep || c.effect == Effect::kRandomWalkDrift ||
                         c.effect == Effect::kCoefficientStep || c.effect == Effect::kTransient;
  const CandidateFit* jump = nullptr;
  double onset_cost = 0.0;
  for (const Scored& x : st.scored) {
    const CandidateFit& f = st.fits[x.index];
    if (!timed_top || f.candidate.effect != Effect::kDriftStep || !f.readout_fitted) continue;
    if (c.gyro > 0 && f.candidate.gyro != c.gyro) continue;  // a walk of all gyros: any gyro
    if (jump == nullptr || f.readout_value < jump->readout_value) {
      jump = &f;
      onset_cost = x.penalty;
    }
  }
  if (jump == nullptr) return;
  const double jump_score = selected.fit.value - jump->readout_value - onset_cost;
  if (jump_score < top.score) return;
  st.readout_note = absl::StrFormat(
      "resembles a step of gyro %d's readings at %.2f h (a readout jump, a fault outside "
      "the library): its misalignment released at that instant has evidence 2 ln B = "
      "%.1f against %.1f for %s, which fits it only in part",
      jump->candidate.gyro, jump->readout_onset_hours, jump_score, top.score, CandidateName(c));
  st.significant.clear();
  st.inhomogeneous_only = true;
  result.readout_jump_evidence = jump_score;
}

// st.behaviour for the gyro of `top`, the round's top candidate, computed once.
absl::Status BehaviourOf(RoundState& st, const SelectedModel& selected,
                         DiagnosisContext& context, const CandidateFit& top) {
  if (st.behaviour.has_value()) return absl::OkStatus();
  // "One step" in the candidate's own form: a coefficient step's coefficients stepping, else a
  // case-fixed drift (wander.h).
  ASSIGN_OR_RETURN(st.behaviour,
                   CompareDriftBehavioursOf(selected, context, top.candidate.gyro, top.stepped));
  return absl::OkStatus();
}

// The open-ended basis's terms against the time behaviour on the held-out spans: not worse by
// -2 log predictive density, nor by the point prediction (point_prediction.h). Sets
// basis->extended's held-out result when they predict; appends the comparison to `held_note`.
absl::StatusOr<bool> BasisPredicts(BasisStageResult& basis, const CandidateFit& top,
                                   SelectedModel& selected, DiagnosisContext& context,
                                   std::string& held_note) {
  ASSIGN_OR_RETURN(ModelRun held_basis,
                   context.CheckedRun(basis.extended->model, /*held_out=*/true));
  ASSIGN_OR_RETURN(ModelRun held_top, context.CheckedRun(top.model, /*held_out=*/true));
  const HeldOutResult hb =
      SummariseHeldOut(held_basis, context.gaps(), context.regimes(), context.frames());
  const HeldOutResult ht =
      SummariseHeldOut(held_top, context.gaps(), context.regimes(), context.frames());
  bool predicts = hb.deviance <= ht.deviance;
  held_note = absl::StrFormat(
      "; held-out -2 log predictive density %.1f with the basis's terms against %.1f "
      "with %s",
      hb.deviance, ht.deviance, CandidateName(top.candidate));
  // Nor may the terms make the held-out point prediction worse (point_prediction.h).
  RETURN_IF_ERROR(MakeHeldOutCurrent(selected, context));
  if (predicts && WorsensPointPrediction(selected.held_out, hb)) {
    predicts = false;
    absl::StrAppend(&held_note, "; ",
                    PointPredictionNote("the basis's terms", selected.held_out, hb));
  }
  if (predicts) {
    basis.extended->held_out = hb;
    basis.extended->held_out_current = true;
  }
  return predicts;
}

// Takes the open-ended basis's terms as the round's findings (before the time behaviour `top`).
void TakeBasisTerms(RoundState& st, BasisStageResult& basis, const CandidateFit& top, int round,
                    const std::string& comparison, const std::string& outdone_note,
                    SelectedModel& selected, RoundResult& result) {
  for (const Scored& x : st.scored) result.rows.push_back(Row(x, st.fits[x.index], round, -1));
  // The round's notes once, on the first of the terms taken together; the others point to it.
  Finding& first = basis.findings.front();
  for (const auto& failed_note : st.failed_notes) {
    first.evidence.notes.push_back(failed_note.second);
  }
  first.evidence.notes.push_back(absl::StrCat(
      comparison,
      ": a deterministic drift, taken before the time behaviour, which the next round "
      "tests again"));
  if (!outdone_note.empty()) {
    first.evidence.notes.push_back(absl::StrCat("terms of other gyros left out", outdone_note,
                                                ": the stage ran again without those gyros"));
  }
  for (size_t k = 1; k < basis.findings.size(); ++k) {
    basis.findings[k].evidence.notes.push_back(absl::StrFormat(
        "taken together with the stage's first term (gyro %d, listed before it) against "
        "%s; the round's notes are on that finding",
        basis.findings.front().gyro, CandidateName(top.candidate)));
  }
  CandidateScore row;
  row.effect = kEffectBasisTerm;
  row.gyro = basis.findings.front().gyro;
  row.round = round;
  row.parameters = static_cast<int>(basis.added_terms.size());
  row.delta_deviance = row.score = basis.refit_evidence;
  row.p_value = EvidenceBound(basis.refit_evidence);
  row.significant = row.selected = true;
  row.time_behaviour = basis.findings.front().time.kind;
  result.rows.push_back(row);
  result.finding = basis.findings.front();
  result.more_findings.assign(basis.findings.begin() + 1, basis.findings.end());
  result.residual_drift = basis.residual_drift;
  selected = std::move(*basis.extended);
}

// Physics outside the library before a time behaviour (docs/discovery.md, "The open-ended
// stage"): a random walk or a drift step absorbs a deterministic drift the library lacks (one
// cycling with the orbit, one growing). When one tops the round, the open-ended stage runs on
// the current model, and its terms are taken instead when they add significant evidence on
// top of the time behaviour (the nested comparison of PreferRandomWalk, same currency); the
// time behaviour is tested again in the next round. Returns whether the terms were taken (then
// `result` and `selected` hold them); else st.basis_note says why not, when they were compared.
absl::StatusOr<bool> PreferBasisToTimeBehaviour(RoundState& st, int round,
                                                const std::vector<int>& gyros,
                                                SelectedModel& selected,
                                                DiagnosisContext& context, RoundResult& result) {
  const DiagnoseOptions& options = context.options();
  if (st.significant.empty() || !options.open_ended) return false;
  const CandidateFit& top = st.fits[st.significant.front().index];
  if (top.candidate.effect != Effect::kRandomWalkDrift &&
      top.candidate.effect != Effect::kDriftStep) {
    return false;
  }
  ASSIGN_OR_RETURN(BasisStageResult basis, RunBasisStage(selected, context, gyros, round));
  // Terms for another gyro whose drift returns to its mean are not taken along with the time
  // behaviour's gyro's (that gyro's own are tested below): the stage runs again without those
  // gyros.
  std::string outdone_note;
  if (basis.extended.has_value() && !basis.findings.empty()) {
    ASSIGN_OR_RETURN(auto outdone, GyrosOutdoneByAStationaryDrift(basis, selected, context, {},
                                                                  {top.candidate.gyro},
                                                                  options.alpha));
    if (!outdone.gyros.empty()) {
      outdone_note = outdone.note;
      result.outdone_gyros = outdone.gyros;
      ASSIGN_OR_RETURN(basis, RunBasisStage(selected, context, outdone.Others(gyros), round));
    }
  }
  if (!basis.extended.has_value() || basis.findings.empty()) return false;
  ASSIGN_OR_RETURN(ModelRun both,
                   context.CheckedRun(WithBasisTerms(top.model, basis), /*held_out=*/false));
  const double gain = Profile(top.run).value - Profile(both).value;
  const std::string versus = absl::StrFormat(
      "on top of %s (2 ln B = %.1f) the open-ended basis's terms add 2 ln B = %.1f "
      "(threshold %.1f)",
      CandidateName(top.candidate), st.significant.front().score, gain, basis.refit_threshold);
  // A deterministic term must also predict: on the held-out spans its -2 log predictive
  // density must not be worse than the time behaviour's (terms fitted to a random process, a
  // drift switching at random, predict the withheld spans wrongly and confidently).
  bool predicts = true;
  std::string held_note;
  if (gain > basis.refit_threshold && !context.gaps().empty()) {
    ASSIGN_OR_RETURN(predicts, BasisPredicts(basis, top, selected, context, held_note));
  }
  // Deterministic terms for a gyro whose drift returns to its mean must describe its deviation
  // better than that stationary drift, in the reduced regression's currency.
  bool describes = true;
  if (gain > basis.refit_threshold && predicts && top.candidate.gyro > 0) {
    double basis_evidence = 0.0;
    bool in_gyro = false;
    for (const SelectedGroup& g : basis.stage.selected) {
      if (g.gyro != top.candidate.gyro) continue;
      basis_evidence += g.evidence;
      in_gyro = true;
    }
    if (in_gyro) {
      RETURN_IF_ERROR(BehaviourOf(st, selected, context, top));
      if (st.behaviour->stationary > basis_evidence) {
        describes = false;
        absl::StrAppend(&held_note, absl::StrFormat(
            "; the basis's terms for gyro %d (2 ln B = %.1f in the reduced regression) "
            "describe its deviation less well than a drift that returns to its mean "
            "(2 ln B = %.1f)",
            top.candidate.gyro, basis_evidence, st.behaviour->stationary));
      }
    }
  }
  if (gain > basis.refit_threshold && predicts && describes) {
    TakeBasisTerms(st, basis, top, round, absl::StrCat(versus, held_note), outdone_note,
                   selected, result);
    return true;
  }
  st.basis_note = absl::StrCat(versus, held_note,
                               !predicts ? ": the basis's terms do not predict the "
                                           "held-out spans as well, the time behaviour is kept"
                                         : ": the time behaviour is kept");
  return false;
}

// A time behaviour of one gyro (the basis did not replace it) changes its drift once (a step)
// or without bound (a walk); a drift that returns to its mean, switching at random between
// levels or driven by a quantity the telemetry does not carry, is neither (wander.h). When a
// stationary drift describes the gyro's deviation decisively better than both, nothing is
// taken: the mismatch is left unexplained, located to the gyro, and described.
// A warm-up at the top is checked so only after the point-prediction guard refused it
// (`refused_warm_up`, SelectionRound): a true warm-up, a decay, is also described well by a
// stationary drift relaxing to its mean, so the check before the guard would leave it unexplained.
absl::Status PreferStationaryDrift(RoundState& st, const SelectedModel& selected,
                                   DiagnosisContext& context, bool refused_warm_up = false) {
  if (st.significant.empty()) return absl::OkStatus();
  const CandidateFit& top = st.fits[st.significant.front().index];
  const Candidate& c = top.candidate;
  // A transient from an onset decays as a warm-up does: the same rule.
  const bool warm_up =
      refused_warm_up && (c.effect == Effect::kWarmUp || c.effect == Effect::kTransient);
  if (c.gyro <= 0 ||
      (c.effect != Effect::kDriftStep && c.effect != Effect::kRandomWalkDrift &&
       c.effect != Effect::kCoefficientStep && !warm_up)) {
    return absl::OkStatus();
  }
  RETURN_IF_ERROR(BehaviourOf(st, selected, context, top));
  if (!ReturnsToItsMean(*st.behaviour, EvidenceThreshold(context.options().alpha, 1))) {
    return absl::OkStatus();
  }
  st.wander_note = absl::StrCat(ReturnsToItsMeanText(*st.behaviour), "; ", CandidateName(c),
                                " is not taken");
  st.wander_where =
      WanderLocation(c.gyro, context.frames(), ReturnsToItsMeanBound(*st.behaviour));
  st.wander_evidence = st.behaviour->stationary;
  st.significant.clear();
  st.inhomogeneous_only = true;
  return absl::OkStatus();
}

// A transient from an onset is one decay (docs/discovery.md, "A transient from an onset"): with it
// in the model, what is left of its gyro's drift must not return to its mean. When a stationary
// drift still describes the gyro's deviation from the model with the transient decisively better
// than one step or a raised walk (ReturnsToItsMean), the decay is one excursion of a drift that
// wanders, not a transient: nothing is taken, and the mismatch is left unexplained, located to the
// gyro, as PreferStationaryDrift leaves it. Otherwise the comparison is a note of the finding.
absl::Status TransientLeavesNoWanderingDrift(RoundState& st, Choice& choice,
                                             const SelectedModel& selected,
                                             DiagnosisContext& context) {
  if (choice.chosen < 0) return absl::OkStatus();
  const CandidateFit& f = st.fits[choice.chosen];
  if (f.candidate.effect != Effect::kTransient || f.candidate.gyro <= 0) return absl::OkStatus();
  SelectedModel with;
  with.model = f.model;
  // The gyro's basis terms at the run's estimates: the model holds the transient's terms at their
  // prior mean (0), and the deviation takes the configured value of a term other than a
  // channel's (deviation.h), so without this it would measure the drift the transient fits too.
  for (GyroConfig& g : with.model.config.gyros) {
    if (g.id != f.candidate.gyro) continue;
    for (const GyroEstimate& e : f.run.gyros) {
      if (e.id != g.id || e.basis_terms.size() != g.basis_terms.size()) continue;
      for (size_t k = 0; k < g.basis_terms.size(); ++k) {
        g.basis_terms[k].value = e.basis_terms[k].value;
      }
    }
  }
  with.run = f.run;
  with.fit = Profile(with.run);
  with.held_out = selected.held_out;
  with.held_out_current = false;
  ASSIGN_OR_RETURN(const DriftBehaviourEvidence left,
                   CompareDriftBehavioursOf(with, context, f.candidate.gyro));
  const std::string versus = absl::StrFormat(
      "with %s in the model, on gyro %d's deviation a drift that returns to its mean has 2 ln "
      "B = %.1f, one step %.1f, a raised walk %.1f",
      CandidateName(f.candidate), f.candidate.gyro, left.stationary, left.step, left.walk);
  if (!ReturnsToItsMean(left, EvidenceThreshold(context.options().alpha, 1))) {
    st.constant_notes.emplace_back(choice.chosen,
                                   absl::StrCat(versus, ": the transient leaves no drift that "
                                                        "returns to its mean"));
    return absl::OkStatus();
  }
  st.wander_note = absl::StrCat(
      CandidateName(f.candidate), " fits one decay of gyro ", f.candidate.gyro,
      "'s drift, but with it ", ReturnsToItsMeanText(left), "; ", CandidateName(f.candidate),
      " is not taken: a transient is one decay, and what it leaves still returns to its mean");
  st.wander_where =
      WanderLocation(f.candidate.gyro, context.frames(), ReturnsToItsMeanBound(left));
  st.wander_evidence = left.stationary;
  st.significant.clear();
  st.inhomogeneous_only = true;
  choice.chosen = -1;
  choice.contenders.clear();
  choice.guard_held_out.reset();
  return absl::OkStatus();
}

// Nothing taken: why, in `result`.
void DescribeUnresolved(RoundState& st, const Choice& choice, const SelectedModel& selected,
                        RoundResult& result) {
  if (!st.wander_note.empty()) {
    result.unresolved = st.wander_note;
    result.unresolved_gyro = st.wander_where.gyro;
    result.unresolved_note = st.readout_note;
    result.unresolved_where = st.wander_where;
    result.stationary_evidence = st.wander_evidence;
    for (const auto& [gyro, note] : st.failed_notes) {
      // Its own effects' notes, and a common walk's that this drift made fail.
      if (gyro == st.wander_where.gyro || gyro == 0) {
        absl::StrAppend(&result.unresolved, "; ", note);
      }
    }
    for (CandidateFit& f : st.fits) {
      if (f.candidate.effect != Effect::kRandomWalkDrift ||
          f.candidate.gyro != st.wander_where.gyro || f.fitted.empty()) {
        continue;
      }
      SelectedModel stand_in;
      stand_in.model = f.model;
      stand_in.run = std::move(f.run);
      stand_in.fit = Profile(stand_in.run);
      stand_in.held_out = selected.held_out;
      stand_in.held_out_current = false;
      result.stand_in = std::move(stand_in);
      result.stand_in_walk_deg_h_sqrt_h = f.fitted.front().value;
      break;
    }
  } else if (st.inhomogeneous_only) {
    result.unresolved =
        "the candidates that fit it improve only part of the recording and worsen the rest (a "
        "change in time such as a fault, not a constant effect)";
    result.unresolved_note = st.readout_note;
  } else if (!st.failed_notes.empty()) {
    // Nothing else explains it: what the failed effect fitted is not what it names, and neither
    // the library's time behaviours nor the basis describe it.
    result.unresolved = st.failed_notes.front().second;
    result.unresolved_gyro = st.failed_notes.front().first;
  } else if (!choice.worsened.empty()) {
    // What fits it in-sample or by its predictive density predicts the attitude worse.
    result.unresolved = choice.worsened.front().second;
    result.unresolved_gyro = st.fits[choice.worsened.front().first].candidate.gyro;
  }
}

// The chosen fit becomes the round's finding, with the round's notes, and the selected model.
void TakeChosen(RoundState& st, Choice& choice, int round, SelectedModel& selected,
                RoundResult& result) {
  const int chosen = choice.chosen;
  const Contenders& contenders = choice.contenders;
  CandidateFit& f = st.fits[chosen];
  const Scored& s = *std::find_if(st.scored.begin(), st.scored.end(),
                                  [&](const Scored& x) { return x.index == chosen; });
  result.finding = MakeFinding(s, st.fits, chosen, round, st.rw_note, choice.held_out_selected,
                               contenders, selected);
  if (!st.basis_note.empty()) result.finding->evidence.notes.push_back(st.basis_note);
  for (const auto& failed_note : st.failed_notes) {
    result.finding->evidence.notes.push_back(failed_note.second);
  }
  for (const auto& [index, note] : st.constant_notes) {
    if (index == chosen) result.finding->evidence.notes.push_back(note);
  }
  for (const auto& worse : choice.worsened) result.finding->evidence.notes.push_back(worse.second);

  selected.held_out_current = std::any_of(contenders.begin(), contenders.end(),
                                          [&](const auto& c) { return c.first == chosen; });
  if (choice.guard_held_out.has_value()) {
    // The guard's run of the chosen model: its held-out prediction with and without the effect.
    Evidence& e = result.finding->evidence;
    if (e.held_out_nees_after < 0) {
      e.held_out_nees_before = selected.held_out.nees;
      e.held_out_nees_after = choice.guard_held_out->nees;
      e.held_out_deviance_before = selected.held_out.deviance;
      e.held_out_deviance_after = choice.guard_held_out->deviance;
      e.held_out_dof = choice.guard_held_out->dof;
    }
    selected.held_out = std::move(*choice.guard_held_out);
    selected.held_out_current = true;
  }
  selected.model = f.model;
  selected.run = std::move(f.run);
  selected.fit = Profile(selected.run);
}

}  // namespace

// One round as a sequence of decisions: list and fit the candidates in two stages until the
// significant ones settle; a readout jump (D43), the open-ended basis or a drift that returns to
// its mean may stand in for a time behaviour; the guarded choice; then the finding, or why
// nothing is taken.
absl::StatusOr<RoundResult> SelectionRound(int round, const std::vector<int>& gyros,
                                           SelectedModel& selected, DiagnosisContext& context) {
  const DiagnoseOptions& options = context.options();
  RoundResult result;
  if (context.Stop()) return DiagnosisContext::Cancelled();
  RoundState st;
  ListRoundCandidates(st, gyros, selected, options);
  if (st.candidates.empty()) return result;
  context.Say(0.05 + 0.8 * round / options.max_effects,
              absl::StrFormat("round %d: %d candidates", round + 1, st.candidates.size()));
  RETURN_IF_ERROR(SettleSignificant(st, round, gyros, selected, context));
  PreferReadoutJump(st, selected, result);
  ASSIGN_OR_RETURN(const bool basis_taken,
                   PreferBasisToTimeBehaviour(st, round, gyros, selected, context, result));
  if (basis_taken) return result;
  RETURN_IF_ERROR(PreferStationaryDrift(st, selected, context));
  ASSIGN_OR_RETURN(Choice choice, ChooseGuarded(st.significant, st.scored, st.fits, st.failed,
                                                st.inhomogeneous_only, round, selected, context));
  // A warm-up (or a transient from an onset) that topped the round but predicts the held-out
  // spans worse (the guard refused it) is a drift of its gyro that changes otherwise than by one
  // decay: as for a step or a walk at the top, nothing is taken when a drift that returns to its
  // mean describes that gyro's deviation decisively better (else the round would go on to a
  // constant effect of another gyro, fitted to the spill-over of that drift).
  if (!st.significant.empty() && choice.chosen != st.significant.front().index &&
      (st.fits[st.significant.front().index].candidate.effect == Effect::kWarmUp ||
       st.fits[st.significant.front().index].candidate.effect == Effect::kTransient) &&
      std::any_of(choice.worsened.begin(), choice.worsened.end(), [&](const auto& w) {
        return w.first == st.significant.front().index;
      })) {
    RETURN_IF_ERROR(PreferStationaryDrift(st, selected, context, /*refused_warm_up=*/true));
    if (st.significant.empty()) {
      choice.chosen = -1;
      choice.contenders.clear();
      choice.guard_held_out.reset();
    }
  }
  RETURN_IF_ERROR(TransientLeavesNoWanderingDrift(st, choice, selected, context));
  for (const Scored& s : st.scored) {
    result.rows.push_back(Row(s, st.fits[s.index], round, choice.chosen));
  }
  if (choice.chosen < 0) {
    DescribeUnresolved(st, choice, selected, result);
  } else {
    TakeChosen(st, choice, round, selected, result);
  }
  return result;
}

}  // namespace esg::estimator::discovery
