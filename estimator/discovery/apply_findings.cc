// Findings to configuration; contract in apply_findings.h.
#include "estimator/discovery/apply_findings.h"

#include <algorithm>
#include <optional>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/discovery/candidate.h"
#include "estimator/discovery/sun_terms.h"
#include "estimator/discovery/turning_displacement.h"
#include "estimator/model_terms.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {
namespace {

std::string Name(const Finding& f) {
  return f.gyro > 0 ? absl::StrFormat("%s (gyro %d)", f.effect, f.gyro) : f.effect;
}

// A basis-term finding as applied by WithBasisFindings: its terms, at the fitted values.
std::string BasisFindingLine(const Finding& f, const std::string& name) {
  std::vector<std::string> labels;
  for (const BasisTerm& t : f.basis_terms) labels.push_back(BasisTermLabel(t));
  std::string line = absl::StrFormat("%s: gyros[%d].basisTerms += %d term%s", name, f.gyro,
                                     f.basis_terms.size(), f.basis_terms.size() == 1 ? "" : "s");
  if (!labels.empty()) absl::StrAppend(&line, " (", absl::StrJoin(labels, ", "), ")");
  if (!f.readout_distortion.isZero(0.0)) absl::StrAppend(&line, ", readoutDistortion set");
  absl::StrAppend(&line, ", at the fitted values, freed with the diagnosis's prior");
  return line;
}

// Whether the finding holds a parameter of a fixed term `effect` frees (model_terms.h).
bool HoldsFixedTermOf(const Finding& f, absl::string_view effect) {
  for (const FixedTermDescriptor& term : kFixedTerms) {
    if (term.effect == effect && FindParameter(f.parameters, FixedTermJsonName(term)) != nullptr) {
      return true;
    }
  }
  return false;
}

// The drift coefficients a finding frees (`freed`), set in gyro `g`'s model at their fitted
// values and freed with the diagnosis's prior.
void ApplyFreedCoefficients(const Finding& f, const std::string& name,
                            const FreedCoefficients& freed, GyroConfig& g,
                            AppliedFindings& out) {
  DriftVector value = g.model.AsVector();
  DriftVector sigma = g.model_sigma.AsVector();
  std::vector<std::string> set;
  for (const FixedTermDescriptor& term : kFixedTerms) {
    if (term.effect != f.effect) continue;
    const Parameter* p = FindParameter(f.parameters, FixedTermJsonName(term));
    if (p == nullptr) continue;
    value(term.theta_index) = DegPerHourToRadPerSec(p->value);
    sigma(term.theta_index) = std::max(sigma(term.theta_index), freed.sigma);
    set.push_back(std::string(term.label));
  }
  if (set.empty()) {
    out.not_applied.push_back(absl::StrCat(name, ": the report holds none of its coefficients"));
    return;
  }
  g.model = DriftCoefficients::FromVector(value);
  g.model_sigma = DriftCoefficients::FromVector(sigma);
  out.applied.push_back(absl::StrFormat(
      "%s: gyros[%d].model %s at the fitted values, freed with modelSigma %.3g deg/h", name,
      f.gyro, absl::StrJoin(set, ", "), RadPerSecToDegPerHour(freed.sigma)));
}

// A library effect that frees no drift coefficient: the configuration field that describes it
// (a misalignment prior, the latency, the random walk), or why none does.
void ApplyOtherEffect(Effect effect, const Finding& f, const std::string& name, GyroConfig* g,
                      const DiagnoseOptions& options, AppliedFindings& out) {
  switch (effect) {
    case Effect::kGyroMisalignment: {
      const double prior = ArcsecToRad(options.misalignment_sigma_arcsec);
      g->misalignment_sigma = std::max(g->misalignment_sigma, prior);
      out.applied.push_back(absl::StrFormat(
          "%s: gyros[%d].misalignmentSigmaArcsec = %.3g (the filter estimates the misalignment)",
          name, f.gyro, RadToArcsec(g->misalignment_sigma)));
      break;
    }
    case Effect::kStarTrackerLatency: {
      const Parameter* tau = FindParameter(f.parameters, "latencyMs");
      if (tau == nullptr) {
        out.not_applied.push_back(absl::StrCat(name, ": the report holds no latencyMs"));
        break;
      }
      out.config.star_tracker.latency = tau->value * 1e-3;
      out.applied.push_back(absl::StrFormat("%s: starTracker.latencyS = %.6g (fitted)", name,
                                            out.config.star_tracker.latency));
      break;
    }
    case Effect::kRandomWalkDrift: {
      const Parameter* q = FindParameter(f.parameters, "randomWalkDegHSqrtH");
      if (f.gyro > 0) {
        out.not_applied.push_back(absl::StrCat(
            name, ": the configuration holds one random-walk intensity for all gyros"));
      } else if (q == nullptr) {
        out.not_applied.push_back(absl::StrCat(name, ": the report holds no intensity"));
      } else {
        out.config.random_walk = DegPerHourSqrtHourToSi(q->value);
        out.applied.push_back(
            absl::StrFormat("%s: randomWalkDegHSqrtH = %.4g (fitted)", name, q->value));
      }
      break;
    }
    case Effect::kStarTrackerCycle:
      out.not_applied.push_back(absl::StrCat(
          name,
          ": the configuration holds no star-tracker mounting, nor a rotation of it in time"));
      break;
    case Effect::kStarTrackerMisalignment:
      out.not_applied.push_back(absl::StrCat(
          name,
          ": the configuration holds no star-tracker mounting; the service re-references "
          "a shifted star tracker online"));
      break;
    case Effect::kDriftStep:
      out.not_applied.push_back(
          absl::StrCat(name,
                       ": a change in time, not a constant of the configuration; the service "
                       "re-opens a gyro's drift at a drift change online"));
      break;
    default:
      out.not_applied.push_back(absl::StrCat(name, ": no configuration field describes it"));
      break;
  }
}

// One finding applied to out.config, or why it is not, as a sequence of decisions: its gyro
// configured, a drift that follows the sun (no field), a basis term (applied already), an
// `unexplained` finding (nothing to apply), an effect outside the library, the coefficients it
// frees, or the field of its effect.
void ApplyFinding(const Finding& f, const DiagnosisReport& report, const DiagnoseOptions& options,
                  AppliedFindings& out) {
  const std::string name = Name(f);
  GyroConfig* g = f.gyro > 0 ? FindGyroMutable(out.config, f.gyro) : nullptr;
  if (f.gyro > 0 && g == nullptr) {
    out.not_applied.push_back(absl::StrFormat("%s: gyro %d is not configured", name, f.gyro));
    return;
  }
  if (f.effect == kEffectBasisTerm && f.time.kind == kTimeFollowsSun) {
    out.not_applied.push_back(absl::StrCat(
        name,
        ": a drift that follows the sun through a thermal lag; the filter has no state for the "
        "lag, so no configuration field describes it (docs/discovery.md, \"A drift that follows "
        "the sun\")"));
    return;
  }
  if (f.effect == kEffectBasisTerm) {
    out.applied.push_back(BasisFindingLine(f, name));
    // A turning displacement that freed C1, C2 where the model held them (turning_displacement.h)
    // carries their values as rotor_displacement's parameters: its constant part.
    const std::optional<FreedCoefficients> freed =
        FreedDriftCoefficients(Effect::kRotorDisplacement, options);
    if (f.time.kind == kTimeTurning && g != nullptr && freed.has_value() &&
        HoldsFixedTermOf(f, EffectId(Effect::kRotorDisplacement))) {
      Finding constant = f;
      constant.effect = EffectId(Effect::kRotorDisplacement);
      ApplyFreedCoefficients(constant, name, *freed, *g, out);
    }
    return;
  }
  if (f.effect == kVerdictUnexplained) {
    // Beside findings (partly_explained): what they leave, applied or not.
    out.not_applied.push_back(absl::StrCat(
        name, ": ",
        report.verdict == kVerdictPartlyExplained
            ? "what the other findings leave unexplained (verdict partly_explained): "
            : "",
        "a mismatch no effect explains; nothing in the configuration describes it"));
    return;
  }
  // The readout group is not of the library: its findings are kEffectBasisTerm.
  const std::optional<Effect> effect = EffectFromId(f.effect);
  if (!effect.has_value() || *effect == Effect::kReadoutDistortion) {
    out.not_applied.push_back(absl::StrCat(
        name, ": not an effect of the library; nothing in the configuration describes it"));
    return;
  }
  if (const std::optional<FreedCoefficients> freed = FreedDriftCoefficients(*effect, options);
      freed.has_value() && g != nullptr) {
    ApplyFreedCoefficients(f, name, *freed, *g, out);
    return;
  }
  ApplyOtherEffect(*effect, f, name, g, options, out);
}

}  // namespace

AppliedFindings WithFindings(const SpacecraftConfig& config, const DiagnosisReport& report,
                             const DiagnoseOptions& options) {
  AppliedFindings out;
  out.config = WithBasisFindings(config, report);
  for (const Finding& f : report.findings) ApplyFinding(f, report, options, out);
  return out;
}

}  // namespace esg::estimator::discovery
