#include "estimator/discovery/report.h"

#include <cmath>
#include <string_view>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/model_terms.h"
#include "estimator/utc_time.h"

namespace esg::estimator::discovery {

const char* EffectId(Effect e) {
  switch (e) {
    case Effect::kRotorDisplacement:
      return "rotor_displacement";
    case Effect::kFourthHarmonic:
      return "fourth_harmonic";
    case Effect::kUnequalStiffness:
      return "unequal_stiffness";
    case Effect::kGyroMisalignment:
      return "gyro_misalignment";
    case Effect::kStarTrackerMisalignment:
      return "star_tracker_misalignment";
    case Effect::kStarTrackerLatency:
      return "star_tracker_latency";
    case Effect::kRandomWalkDrift:
      return "random_walk_drift";
    case Effect::kDriftStep:
      return "drift_step";
    case Effect::kReadoutDistortion:
      return "readout_distortion";
    case Effect::kSunDrift:
      return "sun_drift";
    case Effect::kChannelDrift:
      return "channel_drift";
    case Effect::kWarmUp:
      return "warm_up";
    case Effect::kCoefficientStep:
      return "coefficient_step";
    case Effect::kTransient:
      return "transient";
    case Effect::kStarTrackerCycle:
      return "star_tracker_orbital_misalignment";
    case Effect::kTurningDisplacement:
      return "turning_displacement";
  }
  return "?";
}

const Parameter* FindParameter(const std::vector<Parameter>& ps, absl::string_view name) {
  for (const Parameter& p : ps) {
    if (p.name == name) return &p;
  }
  return nullptr;
}

std::optional<Effect> EffectFromId(absl::string_view id) {
  for (Effect e : {Effect::kRotorDisplacement, Effect::kFourthHarmonic, Effect::kUnequalStiffness,
                   Effect::kGyroMisalignment, Effect::kStarTrackerMisalignment,
                   Effect::kStarTrackerLatency, Effect::kRandomWalkDrift, Effect::kDriftStep,
                   Effect::kReadoutDistortion, Effect::kSunDrift, Effect::kChannelDrift, Effect::kWarmUp,
                   Effect::kCoefficientStep, Effect::kTransient,
                   Effect::kStarTrackerCycle, Effect::kTurningDisplacement}) {
    if (id == EffectId(e)) return e;
  }
  return std::nullopt;
}

namespace {

// `decimals` digits after the point (a count, not a format string: absl::StrFormat checks its
// format at compile time under clang).
std::string VectorText(const std::vector<Parameter>& ps, const std::string& name, int decimals) {
  std::vector<std::string> parts;
  for (int i = 0; i < 3; ++i) {
    const Parameter* p = FindParameter(ps, absl::StrFormat("%s[%d]", name, i));
    if (p == nullptr) return "";
    parts.push_back(p->sigma > 0 ? absl::StrFormat("%.*f+-%.*f", decimals, p->value, decimals,
                                                   p->sigma)
                                 : absl::StrFormat("%.*f", decimals, p->value));
  }
  return absl::StrCat("[", absl::StrJoin(parts, ", "), "]");
}

// The fixed terms an effect frees (estimator/model_terms.h `effect`), one "<symbol> = <value>
// <unit>" per symbol in table order, a symbol's components as one vector: for unequal stiffness
// "mu = [...] deg/h, nu = [...] deg/h".
std::string FreedTermsText(const std::vector<Parameter>& ps, absl::string_view effect) {
  std::vector<std::string> parts;
  absl::string_view last_symbol;
  for (const FixedTermDescriptor& term : kFixedTerms) {
    if (term.effect != effect || term.symbol == last_symbol) continue;
    last_symbol = term.symbol;
    const Parameter* scalar = FindParameter(ps, std::string(term.json_key));
    const std::string value =
        term.component >= 0 ? VectorText(ps, std::string(term.json_key), 3)
                            : absl::StrFormat("%.3f", scalar ? scalar->value : 0.0);
    parts.push_back(absl::StrCat(term.symbol, " = ", value, " ", term.unit));
  }
  return absl::StrJoin(parts, ", ");
}


// docs/discovery.md "Evidence": 2 ln B, and for searched parameters the prior's cost.
std::string EvidenceText(const Evidence& e) {
  return e.penalty != 0.0
             ? absl::StrFormat(
                   "evidence 2 ln B = %.1f for %d parameter%s (-2 log L improves by %.1f, less "
                   "%.1f for the searched parameters' prior range; threshold %.1f, false-alarm "
                   "probability below 1/B = %.2g)",
                   e.evidence, e.parameters, e.parameters == 1 ? "" : "s", e.delta_deviance,
                   e.penalty, e.threshold, e.p_value)
             : absl::StrFormat(
                   "evidence 2 ln B = %.1f for %d parameter%s (the marginal likelihood improves "
                   "by that much in -2 log L; threshold %.1f, false-alarm probability below 1/B "
                   "= %.2g)",
                   e.evidence, e.parameters, e.parameters == 1 ? "" : "s", e.threshold,
                   e.p_value);
}

// One explanation per effect of the library: the finding in words, then `stats` (its evidence).
using Explain = std::string (*)(const Finding& f, const std::string& stats);

std::string ExplainRotorDisplacement(const Finding& f, const std::string& stats) {
  const auto& ps = f.parameters;
  const Parameter* angle = FindParameter(ps, "lineAngleDeg");
  const Parameter* size = FindParameter(ps, "displacementSizeUm");
  const Parameter* chi2 = FindParameter(ps, "collinearityChi2");
  const Parameter* dof = FindParameter(ps, "collinearityDof");
  const Parameter* p = FindParameter(ps, "collinearityP");
  const Parameter* c10 = FindParameter(ps, "c10DegH");
  const Parameter* c20 = FindParameter(ps, "c20DegH");
  const Parameter* lambda_sigma = FindParameter(ps, "lambdaSigmaDeg");
  const std::string voltages =
      size ? absl::StrFormat("; suspension offset voltages imply a %.2f um displacement (eq. (3))",
                             size->value)
           : "";
  const std::string test =
      chi2 && dof && p ? absl::StrFormat("chi2 = %.1f on %.0f dof, p = %.2g", chi2->value,
                                         dof->value, p->value)
                       : "";
  // One physical term: C1 and C2 collinear within their covariance are one displacement.
  if (p && dof && c10 && c20 && lambda_sigma && dof->value > 0 && p->value > kCollinearityP) {
    return absl::StrFormat(
        "gyro %d: one displaced rotor (eq. (8)-(10)) along lambda = %s +- %.1f deg (case "
        "axes), C10 = %.4f +- %.4f deg/h, C20 = %.4f +- %.4f deg/h: the six terms of C1 and C2 "
        "found (%s) are this one displacement, collinear within their covariance (%s; "
        "collinearity not rejected at %.2g)%s; %s",
        f.gyro, VectorText(ps, "lambda", 2), lambda_sigma->value, c10->value, c10->sigma,
        c20->value, c20->sigma, FreedTermsText(ps, f.effect), test, kCollinearityP, voltages,
        stats);
  }
  return absl::StrFormat(
      "gyro %d drifts with odd harmonics of a displaced rotor (eq. (8)-(10)): %s, %.0f deg "
      "apart as lines%s%s; %s",
      f.gyro, FreedTermsText(ps, f.effect), angle ? angle->value : 0.0,
      p && dof && dof->value > 0
          ? absl::StrFormat("; not collinear as one displacement makes them (%s, below %.2g): "
                            "more acts on C1 and C2 than one displaced rotor",
                            test, kCollinearityP)
          : "",
      voltages, stats);
}

std::string ExplainFourthHarmonic(const Finding& f, const std::string& stats) {
  const Parameter* k0 = FindParameter(f.parameters, "k0DegH");
  return absl::StrFormat(
      "gyro %d: the 4th-harmonic coefficient k0 (eq. (1)) is missing or wrong: it "
      "calibrates to %.4f +- %.4f deg/h; %s",
      f.gyro, k0 ? k0->value : 0.0, k0 ? k0->sigma : 0.0, stats);
}

std::string ExplainUnequalStiffness(const Finding& f, const std::string& stats) {
  return absl::StrFormat("gyro %d: unequal suspension stiffness (eq. (1)): %s; %s", f.gyro,
                         FreedTermsText(f.parameters, f.effect), stats);
}

std::string ExplainGyroMisalignment(const Finding& f, const std::string& stats) {
  return absl::StrFormat(
      "gyro %d case axes are misaligned to the body by %s arcsec (rotation vector, "
      "body axes); %s",
      f.gyro, VectorText(f.parameters, "misalignmentArcsec", 1), stats);
}

std::string ExplainStarTrackerMisalignment(const Finding& f, const std::string& stats) {
  return absl::StrFormat(
      "the star tracker is misaligned to the body by %s arcsec (rotation vector, body "
      "axes), common to all gyros; %s",
      VectorText(f.parameters, "misalignmentArcsec", 1), stats);
}

std::string ExplainStarTrackerOrbitalMisalignment(const Finding& f, const std::string& stats) {
  const auto& ps = f.parameters;
  const Parameter* a = FindParameter(ps, "cycleAmplitudeArcsec");
  const Parameter* minor = FindParameter(ps, "cycleMinorArcsec");
  const Parameter* period = FindParameter(ps, "cyclePeriodMin");
  return absl::StrFormat(
      "the star tracker's mount turns with the orbit (period %.1f min): by %.1f +- %.1f arcsec "
      "about body axis %s at its largest (%.1f arcsec about the axis across it), common to all "
      "gyros (a thermo-elastic misalignment); rotation c cos(phi) + s sin(phi), phi the orbital "
      "phase from the first frame, c = %s, s = %s arcsec (body axes); %s",
      period ? period->value : 0.0, a ? a->value : 0.0, a ? a->sigma : 0.0,
      VectorText(ps, "cycleAxis", 2), minor ? minor->value : 0.0,
      VectorText(ps, "cycleCosArcsec", 1), VectorText(ps, "cycleSinArcsec", 1), stats);
}

std::string ExplainStarTrackerLatency(const Finding& f, const std::string& stats) {
  const Parameter* tau = FindParameter(f.parameters, "latencyMs");
  return absl::StrFormat(
      "the star-tracker time tag is %s by %.0f +- %.0f ms (the attitude it reports is "
      "that of %.0f ms %s); %s",
      tau && tau->value < 0 ? "early" : "late", tau ? std::abs(tau->value) : 0.0,
      tau ? tau->sigma : 0.0, tau ? std::abs(tau->value) : 0.0,
      tau && tau->value < 0 ? "later" : "earlier", stats);
}

std::string ExplainRandomWalkDrift(const Finding& f, const std::string& stats) {
  const Parameter* q = FindParameter(f.parameters, "randomWalkDegHSqrtH");
  const Parameter* q0 = FindParameter(f.parameters, "configuredRandomWalkDegHSqrtH");
  return absl::StrFormat(
      "the drift %s is less stable than configured: random-walk intensity (eq. (11)) %.4f "
      "deg/h/sqrt(h) against %.4f configured; %s",
      f.gyro > 0 ? absl::StrFormat("of gyro %d alone", f.gyro) : "of every gyro",
      q ? q->value : 0.0, q0 ? q0->value : 0.0, stats);
}

std::string ExplainDriftStep(const Finding& f, const std::string& stats) {
  const Parameter* size = FindParameter(f.parameters, "driftStepSizeDegH");
  const TimeBehaviour& t = f.time;
  const double half_width_h = 0.5 * (t.onset_upper_hours - t.onset_lower_hours);
  const std::string half_width = half_width_h < 1.0
                                     ? absl::StrFormat("%.0f min", half_width_h * 60.0)
                                     : absl::StrFormat("%.1f h", half_width_h);
  return absl::StrFormat(
      "drift step of %.3f +- %.3f deg/h in gyro %d at %s +- %s (%.2f h from the start; "
      "95%% onset interval %.2f-%.2f h, %s - %s): a drift constant in case axes, d = %s deg/h, "
      "switched on then (a step of C1 by -d in eq. (10)); %s, best of %d onsets",
      size ? size->value : 0.0, size ? size->sigma : 0.0, f.gyro, FormatUtc(t.onset), half_width,
      t.onset_hours, t.onset_lower_hours, t.onset_upper_hours, FormatUtc(t.onset_lower),
      FormatUtc(t.onset_upper), VectorText(f.parameters, "driftStepDegH", 3), stats,
      t.onsets_searched);
}

// A basis finding's description is already its words.
std::string ExplainBasisTerm(const Finding& f, const std::string& stats) {
  return absl::StrCat(f.description, "; ", stats);
}

constexpr std::pair<std::string_view, Explain> kExplanations[] = {
    {kEffectBasisTerm, ExplainBasisTerm},
    {"rotor_displacement", ExplainRotorDisplacement},
    {"fourth_harmonic", ExplainFourthHarmonic},
    {"unequal_stiffness", ExplainUnequalStiffness},
    {"gyro_misalignment", ExplainGyroMisalignment},
    {"star_tracker_misalignment", ExplainStarTrackerMisalignment},
    {"star_tracker_orbital_misalignment", ExplainStarTrackerOrbitalMisalignment},
    {"star_tracker_latency", ExplainStarTrackerLatency},
    {"random_walk_drift", ExplainRandomWalkDrift},
    {"drift_step", ExplainDriftStep},
};

}  // namespace

SpacecraftConfig WithBasisFindings(const SpacecraftConfig& config, const DiagnosisReport& report) {
  SpacecraftConfig out = config;
  for (const Finding& f : report.findings) {
    if (f.effect != kEffectBasisTerm) continue;
    for (GyroConfig& g : out.gyros) {
      if (g.id != f.gyro) continue;
      g.basis_terms.insert(g.basis_terms.end(), f.basis_terms.begin(), f.basis_terms.end());
      if (!f.readout_distortion.isZero(0.0)) g.readout_distortion = f.readout_distortion;
    }
  }
  return out;
}

std::string ExplainFinding(const Finding& f) {
  const std::string stats = EvidenceText(f.evidence);
  for (const auto& [effect, explain] : kExplanations) {
    if (f.effect == effect) return explain(f, stats);
  }
  return stats;
}

}  // namespace esg::estimator::discovery
