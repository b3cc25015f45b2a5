#include "estimator/discovery/consistency.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <map>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/statistics.h"
#include "estimator/utc_time.h"

namespace esg::estimator::discovery {

namespace {

constexpr int kConsistencyTests = 3;  // held-out NEES, in-sample NIS, whiteness
constexpr int kMinWhitenessSeries = 10;

ConsistencyTest ChiSquareTest(const std::string& name, double statistic, int dof, double level) {
  ConsistencyTest t;
  t.name = name;
  t.statistic = statistic;
  t.dof = dof;
  t.bound = ChiSquareQuantile(level, dof);
  t.p_value = ChiSquareSurvival(statistic, dof);
  t.passed = statistic <= t.bound;
  return t;
}

// 1 - excess_after / excess_before in [0, 1]; -1 without an excess before.
double ShareExplained(double excess_before, double excess_after) {
  if (!(excess_before > 0.0)) return -1.0;
  return std::clamp(1.0 - excess_after / excess_before, 0.0, 1.0);
}

std::string Percent(double share) {
  return share < 0 ? std::string("none to explain") : absl::StrFormat("%.0f%%", 100.0 * share);
}

}  // namespace

ConsistencyTest WhitenessTest(const ModelRun& run, double level) {
  std::map<int, std::array<std::vector<double>, 2>> series;  // gyro id -> normalised differences
  for (const StepRecord& r : run.steps) {
    if (!r.accepted || r.withheld) continue;
    for (const GyroInnovation& g : r.innovations) {
      for (int i = 0; i < 2; ++i) {
        if (g.sigma(i) > 0) series[g.id][i].push_back(g.z(i) / g.sigma(i));
      }
    }
  }
  double q = 0.0;
  int count = 0;
  for (const auto& [id, both] : series) {
    for (const std::vector<double>& u : both) {
      if (static_cast<int>(u.size()) < kMinWhitenessSeries) continue;
      const double r1 = Lag1Autocorrelation(u);
      q += static_cast<double>(u.size()) * r1 * r1;
      ++count;
    }
  }
  if (count == 0) return ConsistencyTest{"whiteness", 0.0, 0, 0.0, 1.0, true};
  return ChiSquareTest("whiteness", q, count, level);
}

ModelConsistency CheckConsistency(const ModelRun& run, const ProfiledDeviance& before,
                                  const ProfiledDeviance& after,
                                  const HeldOutResult& held_out_before,
                                  const HeldOutResult& held_out_after, double alpha) {
  ModelConsistency c;
  c.checked = true;
  c.level = 1.0 - alpha / kConsistencyTests;
  if (held_out_after.dof > 0) {
    c.tests.push_back(
        ChiSquareTest("held-out NEES", held_out_after.nees, held_out_after.dof, c.level));
    c.held_out_explained = ShareExplained(held_out_before.nees - held_out_before.dof,
                                          held_out_after.nees - held_out_after.dof);
  }
  if (after.components > 0) {
    // The diagnosis profiles a common noise scale (a mis-stated star-tracker noise is no
    // effect): the NIS fails only beyond the noise misfit `unexplained` reports, location.h.
    ConsistencyTest nis = ChiSquareTest("in-sample NIS", after.dispersion * after.components,
                                        after.components, c.level);
    nis.materiality = kMaterialDispersion;
    nis.passed = nis.passed || after.dispersion <= kMaterialDispersion;
    c.tests.push_back(nis);
    c.in_sample_explained =
        ShareExplained(before.dispersion * before.components - before.components,
                       after.dispersion * after.components - after.components);
  }
  if (ConsistencyTest w = WhitenessTest(run, c.level); w.dof > 0) c.tests.push_back(w);
  for (const ConsistencyTest& t : c.tests) c.passed = c.passed && t.passed;
  return c;
}

Unexplained RemainingAfterFindings(const ModelConsistency& consistency,
                                   const HeldOutResult& held_out, const Mismatch& remaining) {
  Unexplained out;
  std::vector<std::string> failed;
  bool held_out_failed = false;
  double p = 1.0;
  for (const ConsistencyTest& t : consistency.tests) {
    if (t.passed) continue;
    failed.push_back(absl::StrFormat("%s %.1f on %d dof above its bound %.1f (p = %.2g)", t.name,
                                     t.statistic, t.dof, t.bound, t.p_value));
    held_out_failed = held_out_failed || t.name == "held-out NEES";
    p = std::min(p, t.p_value);
  }
  Mismatch where = remaining;
  if (held_out_failed) {
    if (const Mismatch held = HeldOutMismatch(held_out); held.found) where = held;
  } else {
    where.found = true;
    if (where.source.empty()) where.source = "in-sample residuals";
  }
  out.where = where;
  Finding& u = out.finding;
  u.effect = kVerdictUnexplained;
  u.gyro = where.gyro;
  u.explanation = absl::StrFormat(
      "after adding the findings the model still fails its consistency tests (%s): a mismatch "
      "no candidate effect explains remains %s%s, %s to %s (%s span)",
      absl::StrJoin(failed, "; "),
      where.gyro > 0 ? absl::StrCat("in gyro ", where.gyro) : std::string("in all gyros"),
      where.source.empty() ? "" : absl::StrCat(" (", where.source, ")"), FormatUtc(where.start),
      FormatUtc(where.end), where.regime);
  u.evidence.held_out_nees_after = held_out.nees;
  u.evidence.held_out_dof = held_out.dof;
  u.evidence.p_value = p;
  return out;
}

std::string PartlyExplainedSummary(const ModelConsistency& consistency, const FitSummary& before,
                                   const FitSummary& after,
                                   const std::vector<const Finding*>& remains) {
  std::string text = absl::StrFormat(
      "the findings explain %s of the in-sample excess (star-tracker NIS per component %.2f -> "
      "%.2f)",
      Percent(consistency.in_sample_explained), before.dispersion, after.dispersion);
  if (after.held_out_dof > 0) {
    absl::StrAppend(&text, absl::StrFormat(" and %s of the held-out excess (NEES %.1f -> %.1f on "
                                           "%d dof; gap drift %.4f -> %.4f deg/h)",
                                           Percent(consistency.held_out_explained),
                                           before.held_out_nees, after.held_out_nees,
                                           after.held_out_dof, before.gap_drift_rate_deg_h,
                                           after.gap_drift_rate_deg_h));
  }
  std::vector<std::string> failed;
  for (const ConsistencyTest& t : consistency.tests) {
    if (!t.passed) {
      failed.push_back(absl::StrFormat("%s %.1f > %.1f on %d dof", t.name, t.statistic, t.bound,
                                       t.dof));
    }
  }
  if (!failed.empty()) {
    absl::StrAppend(&text, "; the model with them fails ", absl::StrJoin(failed, ", "),
                    absl::StrFormat(" (chi-square %.4g quantiles)", consistency.level));
  }
  std::vector<std::string> where;
  for (const Finding* f : remains) {
    where.push_back(f->gyro > 0 ? absl::StrCat("gyro ", f->gyro) : std::string("all gyros"));
  }
  if (!where.empty()) {
    absl::StrAppend(&text, "; what remains is unexplained, in ", absl::StrJoin(where, ", "),
                    " (the unexplained findings say where and when)");
  }
  return text;
}

}  // namespace esg::estimator::discovery
