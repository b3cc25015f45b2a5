#include "estimator/discovery/rate_coupling.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <optional>
#include <set>
#include <string>
#include <utility>

#include "Eigen/Core"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/basis_term.h"
#include "estimator/statistics.h"

namespace esg::estimator::discovery {

namespace {

// A finding that is one body-rate group of the basis: rate[i] along x, y and z. Its index i and
// the column of K it gives (values and sigmas, deg/h per deg/s, by case axis m); nullopt for any
// other finding.
struct RateGroup {
  int index = 0;
  Eigen::Vector3d value = Eigen::Vector3d::Zero();
  Eigen::Vector3d sigma = Eigen::Vector3d::Zero();
};
std::optional<RateGroup> RateGroupOf(const Finding& f) {
  if (f.effect != kEffectBasisTerm || f.basis_terms.size() != 3) return std::nullopt;
  RateGroup g;
  std::set<int> axes;
  for (const BasisTerm& t : f.basis_terms) {
    if (t.kind != BasisKind::kBodyRate) return std::nullopt;
    if (g.index == 0) g.index = t.index[0];
    if (t.index[0] != g.index || t.axis < 1 || t.axis > 3) return std::nullopt;
    const Parameter* p = FindParameter(f.parameters, absl::StrCat("basis[", BasisTermLabel(t), "]"));
    if (p == nullptr || !(p->sigma > 0.0)) return std::nullopt;
    g.value(t.axis - 1) = p->value;
    g.sigma(t.axis - 1) = p->sigma;
    axes.insert(t.axis);
  }
  if (axes.size() != 3) return std::nullopt;
  return g;
}

}  // namespace

void MergeIsotropicRateCoupling(std::vector<Finding>& findings) {
  std::set<int> gyros;
  for (const Finding& f : findings) gyros.insert(f.gyro);
  for (int gyro : gyros) {
    // Where gyro's three groups are, by body-rate axis i (one each).
    std::array<int, 3> at = {-1, -1, -1};
    std::array<RateGroup, 3> groups;
    bool complete = true;
    for (int j = 0; j < static_cast<int>(findings.size()); ++j) {
      if (findings[j].gyro != gyro) continue;
      const std::optional<RateGroup> g = RateGroupOf(findings[j]);
      if (!g.has_value()) continue;
      if (at[g->index - 1] >= 0) complete = false;  // two of one axis: not this form
      at[g->index - 1] = j;
      groups[g->index - 1] = *g;
    }
    for (int i : at) complete = complete && i >= 0;
    if (!complete) continue;
    // K = k I: k the inverse-variance mean of the diagonal, chi2 of K - k I on 8 dof.
    double weight = 0.0, sum = 0.0;
    for (int i = 0; i < 3; ++i) {
      const double w = 1.0 / (groups[i].sigma(i) * groups[i].sigma(i));
      weight += w;
      sum += w * groups[i].value(i);
    }
    const double k = sum / weight, k_sigma = 1.0 / std::sqrt(weight);
    double chi2 = 0.0;
    for (int i = 0; i < 3; ++i) {
      for (int m = 0; m < 3; ++m) {
        const double expected = m == i ? k : 0.0;
        chi2 += std::pow((groups[i].value(m) - expected) / groups[i].sigma(m), 2);
      }
    }
    const double p = ChiSquareSurvival(chi2, 8.0);
    std::string diagonal;
    for (int i = 0; i < 3; ++i) {
      absl::StrAppend(&diagonal, i == 0 ? "" : ", ",
                      absl::StrFormat("%.4f +- %.4f", groups[i].value(i), groups[i].sigma(i)));
    }
    const std::string test = absl::StrFormat(
        "the three body-rate terms' 3 x 3 gains against k I (k = %.4f +- %.4f deg/h per deg/s, "
        "the diagonal %s): chi2 = %.1f on 8 degrees of freedom, p = %.2g",
        k, k_sigma, diagonal, chi2, p);
    Finding& first = findings[*std::min_element(at.begin(), at.end())];
    if (!(p > kIsotropyP)) {
      first.evidence.notes.push_back(absl::StrCat(
          test, ": not one isotropic coupling (p below ", absl::StrFormat("%.2g", kIsotropyP),
          "), the three terms stand as found"));
      continue;
    }
    Finding merged = first;
    merged.parameters.clear();
    merged.basis_terms.clear();
    merged.evidence.evidence = merged.evidence.delta_deviance = 0.0;
    merged.evidence.parameters = 0;
    std::vector<std::string> parts;
    for (int i = 0; i < 3; ++i) {
      const Finding& f = findings[at[i]];
      merged.parameters.insert(merged.parameters.end(), f.parameters.begin(), f.parameters.end());
      merged.basis_terms.insert(merged.basis_terms.end(), f.basis_terms.begin(),
                                f.basis_terms.end());
      merged.evidence.evidence += f.evidence.evidence;
      merged.evidence.delta_deviance += f.evidence.delta_deviance;
      merged.evidence.parameters += f.evidence.parameters;
      merged.evidence.threshold = std::max(merged.evidence.threshold, f.evidence.threshold);
      parts.push_back(f.description);
    }
    merged.evidence.p_value = EvidenceBound(merged.evidence.evidence);
    merged.parameters.insert(merged.parameters.begin(),
                             {Parameter{"rateCouplingDegHPerDegS", k, k_sigma, "deg/h per deg/s"},
                              Parameter{"isotropyChi2", chi2, 0.0, "1"},
                              Parameter{"isotropyP", p, 0.0, "1"}});
    merged.description = absl::StrFormat(
        "gyro %d: an isotropic coupling of the drift to the body rate, dw = k w in case axes, k "
        "= %.4f +- %.4f deg/h per deg/s: the three body-rate terms found are one term (%s; K = "
        "k I not rejected)",
        gyro, k, k_sigma, test);
    merged.evidence.notes.push_back(absl::StrCat("one term from three groups of the basis: ",
                                                 absl::StrJoin(parts, "; ")));
    merged.explanation = ExplainFinding(merged);
    std::vector<Finding> out;
    for (int j = 0; j < static_cast<int>(findings.size()); ++j) {
      if (j == at[0] || j == at[1] || j == at[2]) {
        if (&findings[j] == &first) out.push_back(merged);
        continue;
      }
      out.push_back(std::move(findings[j]));
    }
    findings = std::move(out);
  }
}

}  // namespace esg::estimator::discovery
