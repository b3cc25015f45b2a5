#include "estimator/discovery/diagnose.h"

#include <algorithm>
#include <cmath>
#include <optional>
#include <set>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/basis_term.h"
#include "estimator/calibration_model.h"
#include "estimator/discovery/candidates.h"
#include "estimator/discovery/consistency.h"
#include "estimator/discovery/context.h"
#include "estimator/discovery/forward_selection.h"
#include "estimator/discovery/held_out.h"
#include "estimator/discovery/location.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/selection.h"
#include "estimator/discovery/wander.h"
#include "estimator/discovery/what_is_left.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"

namespace esg::estimator::discovery {

namespace {

absl::Status CheckInput(const SpacecraftConfig& config, const std::vector<TelemetryFrame>& frames,
                        const DiagnoseOptions& options) {
  if (absl::Status s = ValidateConfig(config); !s.ok()) return s;
  if (frames.size() < 10) {
    return absl::InvalidArgumentError(
        absl::StrFormat("recording: %d frames, at least 10 needed", frames.size()));
  }
  for (size_t i = 1; i < frames.size(); ++i) {
    if (!(frames[i].time > frames[i - 1].time)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "recording: frame %d (%s) is not after frame %d", i, FormatUtc(frames[i].time), i - 1));
    }
  }
  if (!(options.alpha > 0.0 && options.alpha < 1.0)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("alpha: must be in (0, 1), got %g", options.alpha));
  }
  const double period_s = options.orbital_period_s;
  if (!(period_s == 0.0 || (period_s >= kMinOrbitalPeriodS && period_s <= kMaxOrbitalPeriodS))) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "orbital period: %g s is outside [%g, %g] s (or 0: from the recording)", period_s,
        kMinOrbitalPeriodS, kMaxOrbitalPeriodS));
  }
  if (options.orbit != nullptr) {
    const std::vector<TimeInterval> gaps =
        options.orbit->Gaps(frames.front().time, frames.back().time);
    if (!gaps.empty()) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "orbit: does not cover the recording (%s to %s): no state from %s to %s%s; deliver an "
          "orbit that covers the whole recording",
          FormatUtc(frames.front().time), FormatUtc(frames.back().time), FormatUtc(gaps[0].from),
          FormatUtc(gaps[0].to),
          gaps.size() > 1 ? absl::StrFormat(" and %d more gaps", gaps.size() - 1) : ""));
    }
  }
  int st_frames = 0;
  for (const TelemetryFrame& f : frames)
    st_frames += f.star_tracker.has_value() && f.star_tracker->valid;
  if (st_frames < 10) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "recording: %d valid star-tracker samples; the comparison needs at least 10", st_frames));
  }
  return absl::OkStatus();
}

// The user's model in the form the discovery extends: every term of eq. (1), (10) is in the
// filter, held at its configured value unless freed; terms outside the user's model are held at
// zero (docs/discovery.md, "The model": a term absent or zero without a sigma is not in it).
absl::StatusOr<ModelState> UserModel(const SpacecraftConfig& config, const DiagnoseOptions& opt) {
  auto spec = ParseModel(opt.model);
  if (!spec.ok()) return spec.status();
  ModelState m;
  m.config = config;
  const bool only_random_walk = !spec->HasFixedTerms();
  const auto mask = spec->TermMask();
  for (GyroConfig& g : m.config.gyros) {
    DriftVector value = g.model.AsVector(), sigma = g.model_sigma.AsVector();
    for (int i = 0; i < kNumDriftCoefficients; ++i) {
      if (only_random_walk) {
        sigma(i) = 0.0;  // model (11) alone: the configured model applied as it is
      } else if (!mask[i]) {
        value(i) = 0.0;
        sigma(i) = 0.0;
      }
    }
    g.model = DriftCoefficients::FromVector(value);
    g.model_sigma = DriftCoefficients::FromVector(sigma);
  }
  m.options.model.parts = kAllModelParts;
  m.options.model.random_walk = spec->random_walk;
  if (opt.integration_rate_hz > 0.0) m.config.filter.integration_rate_hz = opt.integration_rate_hz;
  // eq. (12) would exclude a gyro whose unmodelled drift makes its pair disagree with the star
  // tracker, and a model would then be scored on fewer data than another: during diagnosis the
  // pair test is off (outliers are still rejected by eq. (14)).
  m.config.filter.fault_threshold = kPi;
  return m;
}

std::string DescribeModel(const ModelState& m, const DiagnoseOptions& opt) {
  std::string text = absl::StrCat("configured model ", opt.model);
  if (!m.added.empty()) absl::StrAppend(&text, " + ", absl::StrJoin(m.added, " + "));
  return text;
}

// Running gyros: configured and reporting in at least half of the frames.
std::vector<int> RunningGyros(const SpacecraftConfig& config,
                              const std::vector<TelemetryFrame>& frames) {
  std::vector<int> gyros;
  for (const GyroConfig& g : config.gyros) {
    int n = 0;
    for (const TelemetryFrame& f : frames) n += f.gyros[g.id - 1].has_value();
    if (2 * n >= static_cast<int>(frames.size())) gyros.push_back(g.id);
  }
  return gyros;
}

FitSummary Summarise(const ModelState& model, const ModelRun& run, const ProfiledDeviance& fit,
                     const HeldOutResult& held_out, const DiagnoseOptions& options) {
  FitSummary s;
  s.model = DescribeModel(model, options);
  s.residual_rms_arcsec = ResidualRmsArcsec(run);
  s.deviance = fit.value;
  s.dispersion = fit.dispersion;
  s.gap_drift_rate_deg_h = held_out.rate_rms_deg_h;
  s.held_out_nees = held_out.nees;
  s.held_out_deviance = held_out.deviance;
  s.held_out_dof = held_out.dof;
  s.gaps = held_out.gaps;
  return s;
}

// The verdict (docs/discovery.md, "A verdict no stronger than its evidence"): none without
// findings; with findings of a model term, the consistency tests of the model with them
// (consistency.h); when one fails and no `unexplained` finding says what remains, one is added,
// located. Findings of a model term with an `unexplained` one (`unexplained_found` or added):
// partly_explained, with the summary of what they explain; else the first finding's effect.
void Conclude(bool model_findings, bool unexplained_found, const ProfiledDeviance& base_fit,
              const SelectedModel& selected, const HeldOutResult& base_held_out,
              const HeldOutResult& final_held_out, const Mismatch& remaining, double alpha,
              DiagnosisReport& report) {
  if (report.findings.empty()) {
    report.verdict = kVerdictNone;
    return;
  }
  report.verdict = report.findings.front().effect;
  if (!model_findings) return;
  report.consistency = CheckConsistency(selected.run, base_fit, selected.fit, base_held_out,
                                        final_held_out, alpha);
  if (!report.consistency.passed && !unexplained_found) {
    report.findings.push_back(
        RemainingAfterFindings(report.consistency, final_held_out, remaining).finding);
    unexplained_found = true;
  }
  if (!unexplained_found) return;
  report.verdict = kVerdictPartlyExplained;
  std::vector<const Finding*> remains;
  for (const Finding& f : report.findings) {
    if (f.effect == kVerdictUnexplained) remains.push_back(&f);
  }
  report.consistency.summary =
      PartlyExplainedSummary(report.consistency, report.before, report.after, remains);
}

// The options with the orbit's period: with an orbit and no period given, the orbital-phase
// harmonics take the orbit's period at the recording's middle (the Keplerian period through that
// state), when it is a plausible one.
DiagnoseOptions WithOrbitalPeriod(const DiagnoseOptions& requested,
                                  const std::vector<TelemetryFrame>& frames) {
  DiagnoseOptions options = requested;
  if (options.orbit != nullptr && options.orbital_period_s == 0.0) {
    const absl::StatusOr<OrbitState> middle =
        options.orbit->StateAt(frames.front().time + (frames.back().time - frames.front().time) / 2);
    const double period_s = middle.ok() ? KeplerPeriodS(*middle) : 0.0;
    if (period_s >= kMinOrbitalPeriodS && period_s <= kMaxOrbitalPeriodS) {
      options.orbital_period_s = period_s;
    }
  }
  return options;
}

// The report's recording: its first frame, its size, the orbit used and the running gyros.
DiagnosisReport StartReport(const SpacecraftConfig& config,
                            const std::vector<TelemetryFrame>& frames,
                            const DiagnoseOptions& options) {
  DiagnosisReport report;
  report.first_frame_time = frames.front().time;
  report.frames = static_cast<int>(frames.size());
  if (options.orbit != nullptr) {
    report.orbit = absl::StrCat(options.orbit_source.empty() ? "an orbit" : options.orbit_source,
                                ": used (the Earth's shadow in the sun's regressors)");
  } else {
    report.orbit = options.orbit_source;
  }
  report.gyros = RunningGyros(config, frames);
  return report;
}

// The user's model (selected.model): its full run and, with gaps, its held-out run, in parallel;
// fills selected.run and selected.fit, and `held_out` with the held-out run's summary.
absl::Status RunUserModel(DiagnosisContext& context, const std::vector<RegimeSpan>& regimes,
                          const std::vector<TelemetryFrame>& frames, SelectedModel& selected,
                          HeldOutResult& held_out) {
  std::optional<absl::StatusOr<ModelRun>> base_full, base_held;
  if (context.Stop()) return DiagnosisContext::Cancelled();
  context.ForEach(2, [&](int i) {
    if (context.Stop()) return;
    if (i == 0) {
      base_full = context.Run(selected.model, /*held_out=*/false);
    } else if (!context.gaps().empty()) {
      base_held = context.Run(selected.model, /*held_out=*/true);
    }
  });
  if (context.Stopped()) return DiagnosisContext::Cancelled();
  context.CountRuns(context.gaps().empty() ? 1 : 2);
  if (!base_full->ok()) return base_full->status();
  selected.run = std::move(**base_full);
  selected.fit = Profile(selected.run);
  if (base_held.has_value()) {
    if (!base_held->ok()) return base_held->status();
    held_out = SummariseHeldOut(**base_held, context.gaps(), regimes, frames);
  }
  return absl::OkStatus();
}

// What the extended model leaves: its held-out prediction, the mismatches located against the
// user's run, and what remains unexplained (a span whose residual excess stands out, held-out
// prediction beyond the filter's uncertainty, or noise beyond the configured one).
struct Assessment {
  HeldOutResult final_held_out;
  Mismatches mismatches;
  std::optional<Unexplained> remaining;
};

// The assessment of `selected` (its full run current; its held-out prediction run unless
// current), against the user's `base_run` and `base_held_out`. `selection`'s unresolved reason
// says why the candidates that fit were not taken, when they were not.
absl::Status Assess(const SelectedModel& selected, const ForwardSelection& selection,
                    const ModelRun& base_run, const HeldOutResult& base_held_out,
                    const std::vector<RegimeSpan>& regimes,
                    const std::vector<TelemetryFrame>& frames, DiagnosisContext& context,
                    Assessment& a) {
  if (context.Stop()) return DiagnosisContext::Cancelled();
  context.Say(0.9, "held-out prediction with the findings");
  a.final_held_out = base_held_out;
  if (selected.held_out_current) {
    a.final_held_out = selected.held_out;
  } else if (!selection.findings.empty() && !context.gaps().empty()) {
    auto held = context.CheckedRun(selected.model, /*held_out=*/true);
    if (!held.ok()) return held.status();
    a.final_held_out = SummariseHeldOut(*held, context.gaps(), regimes, frames);
  }
  const double alpha = context.options().alpha;
  a.mismatches = LocateMismatches(base_run, selected.run, regimes, frames, alpha);
  a.remaining = FindUnexplained(a.mismatches.remaining, selection.unresolved,
                                selection.unresolved_gyro, selection.unresolved_where,
                                a.final_held_out, selected.fit, !selection.findings.empty(),
                                alpha);
  return absl::OkStatus();
}

// A single finding's held-out evidence, when the selection left it unset: the user's and the
// extended model's held-out prediction.
void AddHeldOutEvidence(const HeldOutResult& base_held_out, const HeldOutResult& final_held_out,
                        DiagnosisReport& report) {
  if (report.findings.size() != 1 || report.findings.front().evidence.held_out_nees_after >= 0) {
    return;
  }
  Evidence& e = report.findings.front().evidence;
  e.held_out_nees_before = base_held_out.nees;
  e.held_out_nees_after = final_held_out.nees;
  e.held_out_deviance_before = base_held_out.deviance;
  e.held_out_deviance_after = final_held_out.deviance;
  e.held_out_dof = final_held_out.dof;
}

}  // namespace

// The diagnosis as a sequence: the input checked, the recording's regimes, the user's model run,
// the forward selection over the library, what it leaves assessed, the open-ended stage on what
// remains, the other gyros whose drift returns to its mean, and the verdict.
absl::StatusOr<DiagnosisReport> Diagnose(const SpacecraftConfig& config,
                                         const std::vector<TelemetryFrame>& frames,
                                         const DiagnoseOptions& requested,
                                         const DiagnoseProgressFn& progress) {
  if (absl::Status s = CheckInput(config, frames, requested); !s.ok()) return s;
  const DiagnoseOptions options = WithOrbitalPeriod(requested, frames);
  auto user = UserModel(config, options);
  if (!user.ok()) return user.status();
  DiagnosisContext context(frames, options, progress);
  if (context.Stop()) return DiagnosisContext::Cancelled();
  DiagnosisReport report = StartReport(config, frames, options);
  if (report.gyros.size() < 2) {
    return absl::InvalidArgumentError(
        "recording: fewer than two configured gyros report in half of the frames");
  }
  context.Say(0.0, "regimes");
  context.MeasureRecording(config);
  report.regimes = context.regimes();

  // The user's model: full run and held-out run in parallel.
  context.Say(0.02, "user model");
  SelectedModel selected;
  selected.model = *user;
  HeldOutResult base_held_out;
  if (absl::Status s = RunUserModel(context, report.regimes, frames, selected, base_held_out);
      !s.ok()) {
    return s;
  }
  const ModelRun base_run = selected.run;
  const ProfiledDeviance base_fit = selected.fit;
  report.before = Summarise(selected.model, selected.run, selected.fit, base_held_out, options);
  report.residuals_before = ResidualSeries(selected.run, frames);
  report.held_out_before = base_held_out.points;

  // Forward selection: one effect per round while one is found.
  selected.held_out = base_held_out;
  auto chosen = SelectEffects(report.gyros, selected, context);
  if (!chosen.ok()) return chosen.status();
  ForwardSelection& selection = *chosen;
  report.candidates = std::move(selection.rows);

  // The extended model: its held-out prediction (its full run is selected.run), and what remains.
  Assessment a;
  a.final_held_out = base_held_out;
  if (absl::Status s = Assess(selected, selection, base_run, base_held_out, report.regimes,
                              frames, context, a);
      !s.ok()) {
    return s;
  }

  // What the library left: the open-ended stage (what_is_left.h).
  std::string resembles;
  if (a.remaining.has_value() && options.open_ended) {
    context.Say(0.92, "open-ended stage");
    auto left = ExplainWhatSelectionLeft(selected, context, report.gyros, a.final_held_out,
                                         selection);
    if (!left.ok()) return left.status();
    resembles = std::move(left->resembles);
    if (left->taken) {
      if (absl::Status s = Assess(selected, selection, base_run, base_held_out, report.regimes,
                                  frames, context, a);
          !s.ok()) {
        return s;
      }
    }
  }
  report.findings = std::move(selection.findings);
  report.residual_drift = std::move(selection.residual_drift);
  std::set<int>& outdone_gyros = selection.outdone_gyros;

  // Another gyro whose drift returns to its mean is its own `unexplained` finding, listed before
  // the verdict's (which stays last, with the report's mismatch).
  if (a.remaining.has_value()) outdone_gyros.erase(a.remaining->finding.gyro);
  std::vector<Finding> wandering;
  if (!outdone_gyros.empty()) {
    auto found = OtherGyrosReturningToTheirMean(
        selected, context, outdone_gyros, a.final_held_out, !report.findings.empty(),
        static_cast<int>(report.gyros.size()), options.alpha);
    if (!found.ok()) return found.status();
    wandering = std::move(*found);
  }

  report.after = Summarise(selected.model, selected.run, selected.fit, a.final_held_out, options);
  report.residuals_after = ResidualSeries(selected.run, frames);
  report.held_out_after = a.final_held_out.points;
  AddHeldOutEvidence(base_held_out, a.final_held_out, report);
  report.mismatch = a.mismatches.base;
  const bool model_findings = !report.findings.empty();
  for (Finding& f : wandering) report.findings.push_back(std::move(f));
  if (a.remaining.has_value()) {
    for (const std::string* note :
         {&selection.unresolved_note, &selection.stand_in_note, &selection.later_unresolved}) {
      if (!note->empty()) a.remaining->finding.evidence.notes.push_back(*note);
    }
    if (!resembles.empty()) a.remaining->finding.evidence.notes.push_back(resembles);
    report.findings.push_back(a.remaining->finding);
    if (!model_findings) report.mismatch = a.remaining->where;
  }
  Conclude(model_findings, a.remaining.has_value() || !wandering.empty(), base_fit, selected,
           base_held_out, a.final_held_out, a.mismatches.remaining, options.alpha, report);
  report.filter_runs = context.filter_runs();
  context.Say(1.0, "done");
  return report;
}

}  // namespace esg::estimator::discovery
