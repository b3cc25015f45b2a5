// Where a failing model-consistency test's mismatch sits (mismatch_location.h).
#include "estimator/mismatch_location.h"

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/statistics.h"

namespace esg::estimator {

bool Implicated(const ReadingFaultMonitor::Misfit& m) {
  return m.dof > 0 && m.chi2 > ChiSquareQuantile(1.0 - kMismatchLocationAlpha, m.dof);
}

MismatchLocation LocateMismatch(const std::vector<TrackMisfit>& gyros) {
  MismatchLocation m;
  m.evidence = gyros;
  int tracked = 0, pairs = 0;
  bool pair_implicated = false;
  for (const TrackMisfit& g : gyros) {
    if (g.star_tracker.has_value()) {
      ++tracked;
      if (Implicated(*g.star_tracker)) m.gyro_ids.push_back(g.gyro_id);
    }
    if (g.pair.has_value()) {
      ++pairs;
      pair_implicated = pair_implicated || Implicated(*g.pair);
    }
  }
  using Where = MismatchLocation::Where;
  const int implicated = static_cast<int>(m.gyro_ids.size());
  if (tracked < 2 || implicated == 0) {
    m.where = Where::kNotLocated;
  } else if (implicated == tracked) {
    m.where = pairs < tracked     ? Where::kCommon
              : pair_implicated ? Where::kAllGyros
                                : Where::kStarTracker;
  } else {
    m.where = implicated == 1 ? Where::kGyro : Where::kGyros;
  }
  return m;
}

std::string MismatchLocation::Subsystem() const {
  switch (where) {
    case Where::kGyro:
      return absl::StrFormat("model:gyro_%d", gyro_ids[0]);
    case Where::kGyros:
      return absl::StrFormat("model:gyros_%d_%d", gyro_ids[0], gyro_ids[1]);
    case Where::kStarTracker:
      return "model:star_tracker";
    case Where::kAllGyros:
      return "model:all_gyros";
    case Where::kCommon:
      return "model:common";
    case Where::kNotLocated:
      break;
  }
  return "model";
}

namespace {
// "gyro 2 61.2/40 (pair 38.0/40)": misfit over degrees of freedom, '*' when implicated.
std::string Evidence(const TrackMisfit& g) {
  auto one = [](const ReadingFaultMonitor::Misfit& m) {
    return absl::StrFormat("%.1f/%d%s", m.chi2, m.dof, Implicated(m) ? "*" : "");
  };
  std::string s = absl::StrFormat("gyro %d %s", g.gyro_id,
                                  g.star_tracker.has_value() ? one(*g.star_tracker) : "no track");
  if (g.pair.has_value()) absl::StrAppend(&s, " (pair ", one(*g.pair), ")");
  return s;
}
}  // namespace

std::string MismatchLocation::Describe() const {
  std::vector<std::string> parts;
  for (const TrackMisfit& g : evidence) parts.push_back(Evidence(g));
  const std::string evidence_words = absl::StrFormat(
      "each gyro's track against its model, star-tracker rebuild (pair rebuild), chi-square over "
      "degrees of freedom, * beyond the %g level: %s",
      kMismatchLocationAlpha, parts.empty() ? "no gyro tracked" : absl::StrJoin(parts, ", "));
  std::string where_words;
  switch (where) {
    case Where::kGyro:
      where_words = absl::StrFormat("gyro %d: a drift of its own that the model lacks", gyro_ids[0]);
      break;
    case Where::kGyros:
      where_words = absl::StrFormat("gyros %d and %d", gyro_ids[0], gyro_ids[1]);
      break;
    case Where::kStarTracker:
      where_words =
          "the star tracker's side: every gyro misfits against the star tracker while the gyros "
          "agree with one another";
      break;
    case Where::kAllGyros:
      where_words =
          "all gyros: every gyro misfits against the star tracker and the gyros disagree with "
          "one another too";
      break;
    case Where::kCommon:
      where_words = "common to all gyros or the star tracker's side (fewer than three gyros run: "
                    "no pair rebuild tells them apart)";
      break;
    case Where::kNotLocated:
      return absl::StrCat("not located: the tracks of the last steps do not show it; ",
                          evidence_words);
  }
  return absl::StrCat("located: ", where_words, "; ", evidence_words);
}

}  // namespace esg::estimator
