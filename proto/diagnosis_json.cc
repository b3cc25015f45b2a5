#include "proto/diagnosis_json.h"

#include <cmath>

#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "google/protobuf/util/json_util.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"
#include "proto/convert.h"

namespace esg::proto_convert {

namespace {

using estimator::discovery::CandidateScore;
using estimator::discovery::DiagnosisReport;
using estimator::discovery::Evidence;
using estimator::discovery::Finding;
using estimator::discovery::FitSummary;
using estimator::discovery::GapSummary;
using estimator::discovery::Mismatch;
using estimator::discovery::Parameter;
using estimator::FormatUtc;
using json = nlohmann::ordered_json;

// JSON has no infinities or NaN: they become null.
json Number(double x) { return std::isfinite(x) ? json(x) : json(nullptr); }

json ParameterJson(const Parameter& p) {
  json j{{"name", p.name}, {"value", Number(p.value)}};
  if (p.sigma > 0) j["sigma"] = Number(p.sigma);
  j["unit"] = p.unit;
  return j;
}

json EvidenceJson(const Evidence& e) {
  json j{{"deltaDeviance", Number(e.delta_deviance)},
         {"penalty", Number(e.penalty)},
         {"evidence", Number(e.evidence)},
         {"parameters", e.parameters},
         {"pValue", Number(e.p_value)},
         {"threshold", Number(e.threshold)},
         {"round", e.round}};
  if (e.held_out_dof > 0) {
    j["heldOutNeesBefore"] = Number(e.held_out_nees_before);
    j["heldOutNeesAfter"] = Number(e.held_out_nees_after);
    j["heldOutDevianceBefore"] = Number(e.held_out_deviance_before);
    j["heldOutDevianceAfter"] = Number(e.held_out_deviance_after);
    j["heldOutDof"] = e.held_out_dof;
  }
  j["notes"] = e.notes;
  return j;
}

// How the finding behaves in time (report.h TimeBehaviour); the onset and its interval for a
// step, of the drift or of drift coefficients, and for a transient from an onset.
json TimeBehaviourJson(const estimator::discovery::TimeBehaviour& t) {
  json j{{"kind", t.kind}};
  if (t.kind == "step" || t.kind == "coefficient_step" || t.kind == "transient") {
    j["onset"] = FormatUtc(t.onset);
    j["onsetHours"] = Number(t.onset_hours);
    j["onsetLower"] = FormatUtc(t.onset_lower);
    j["onsetUpper"] = FormatUtc(t.onset_upper);
    j["onsetLowerHours"] = Number(t.onset_lower_hours);
    j["onsetUpperHours"] = Number(t.onset_upper_hours);
    j["onsetsSearched"] = t.onsets_searched;
    json profile = json::array();
    for (const auto& [hours, value] : t.onset_profile)
      profile.push_back(json::array({Number(hours), Number(value)}));
    j["onsetProfile"] = profile;
  }
  return j;
}

// A rotor displacement's suspension-voltage trend: the line per case axis, and with
// `include_series` the binned displacement it was fitted to ([hours, x, y, z] in um).
json DisplacementTrendJson(const estimator::discovery::DisplacementTrend& t, bool include_series) {
  json j{{"interceptUm", t.intercept_um}, {"rateUmPerH", t.rate_um_h}};
  if (include_series) {
    json samples = json::array();
    for (const auto& s : t.samples) {
      samples.push_back(json::array({s.hours, Number(s.displacement_um[0]),
                                     Number(s.displacement_um[1]), Number(s.displacement_um[2])}));
    }
    j["samples"] = samples;
  }
  return j;
}

json FindingJson(const Finding& f, bool include_series) {
  json j{{"effect", f.effect}};
  if (f.gyro > 0) j["gyro"] = f.gyro;
  json params = json::array();
  for (const Parameter& p : f.parameters) params.push_back(ParameterJson(p));
  j["parameters"] = params;
  j["explanation"] = f.explanation;
  if (!f.description.empty()) j["description"] = f.description;
  if (f.effect == estimator::discovery::kEffectBasisTerm) {
    // The model terms as the configuration holds them (gyros[].basisTerms of this gyro), and a
    // readout distortion (gyros[].readoutDistortion, row-major).
    json terms = json::array();
    for (const estimator::BasisTerm& t : f.basis_terms) {
      terms.push_back(json::parse(BasisTermToJson(t), nullptr, /*allow_exceptions=*/false));
    }
    j["modelTerms"] = terms;
    if (!f.readout_distortion.isZero(0.0)) {
      json d = json::array();
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) d.push_back(f.readout_distortion(r, c));
      }
      j["readoutDistortion"] = d;
    }
  }
  j["evidence"] = EvidenceJson(f.evidence);
  if (f.effect != "unexplained") j["timeBehaviour"] = TimeBehaviourJson(f.time);
  if (!f.displacement_trend.samples.empty())
    j["displacementTrend"] = DisplacementTrendJson(f.displacement_trend, include_series);
  return j;
}

json MismatchJson(const Mismatch& m, absl::Time t0) {
  json j{{"found", m.found}};
  if (m.gyro > 0) j["gyro"] = m.gyro;
  if (m.span >= 0 || m.found) {
    j["start"] = FormatUtc(m.start);
    j["end"] = FormatUtc(m.end);
    j["startHours"] = absl::ToDoubleHours(m.start - t0);
    j["endHours"] = absl::ToDoubleHours(m.end - t0);
    j["regime"] = m.regime;
  }
  j["sizeArcsec"] = Number(m.size_arcsec);
  j["expectedArcsec"] = Number(m.expected_arcsec);
  j["excess"] = Number(m.excess_deviance);
  j["pValue"] = Number(m.p_value);
  if (m.axis > 0) j["axis"] = m.axis;
  j["lag1Autocorrelation"] = Number(m.lag1_autocorrelation);
  j["whitenessPValue"] = Number(m.whiteness_p_value);
  j["trendPerHour"] = Number(m.trend_per_hour);
  j["source"] = m.source;
  return j;
}

json GapJson(const GapSummary& g, absl::Time t0) {
  json rates = json::array();
  for (const auto& [id, rate] : g.gyro_drift_rate_deg_h)
    rates.push_back(json{{"gyro", id}, {"driftRateDegH", Number(rate)}});
  return json{{"regime", g.regime},
              {"start", FormatUtc(g.start)},
              {"end", FormatUtc(g.end)},
              {"startHours", absl::ToDoubleHours(g.start - t0)},
              {"endHours", absl::ToDoubleHours(g.end - t0)},
              {"driftRateDegH", Number(g.drift_rate_deg_h)},
              {"finalErrorArcsec", Number(g.final_error_arcsec)},
              {"nees", Number(g.nees)},
              {"dof", g.dof},
              {"gyros", rates}};
}

json FitJson(const FitSummary& f, absl::Time t0) {
  json gaps = json::array();
  for (const GapSummary& g : f.gaps) gaps.push_back(GapJson(g, t0));
  return json{{"model", f.model},
              {"residualRmsArcsec", Number(f.residual_rms_arcsec)},
              {"gapDriftRateDegH", Number(f.gap_drift_rate_deg_h)},
              {"deviance", Number(f.deviance)},
              {"dispersion", Number(f.dispersion)},
              {"heldOutNees", Number(f.held_out_nees)},
              {"heldOutDeviance", Number(f.held_out_deviance)},
              {"heldOutDof", f.held_out_dof},
              {"gaps", gaps}};
}

json CandidateJson(const CandidateScore& c) {
  json j{{"effect", c.effect}};
  if (c.gyro > 0) j["gyro"] = c.gyro;
  j["round"] = c.round;
  j["parameters"] = c.parameters;
  j["deltaDeviance"] = Number(c.delta_deviance);
  j["penalty"] = Number(c.penalty);
  j["score"] = Number(c.score);
  j["pValue"] = Number(c.p_value);
  j["significant"] = c.significant;
  j["homogeneous"] = c.homogeneous;
  j["selected"] = c.selected;
  j["timeBehaviour"] = c.time_behaviour;
  if (c.onset_hours >= 0) j["onsetHours"] = Number(c.onset_hours);
  if (!c.not_fitted.empty()) j["notFitted"] = c.not_fitted;
  return j;
}

// The consistency tests of the model with the findings (report.h ModelConsistency); the shares
// explained are null when the user's model showed no excess.
json ConsistencyJson(const estimator::discovery::ModelConsistency& c) {
  json tests = json::array();
  for (const estimator::discovery::ConsistencyTest& t : c.tests) {
    json j{{"name", t.name},         {"statistic", Number(t.statistic)},
           {"dof", t.dof},           {"bound", Number(t.bound)},
           {"pValue", Number(t.p_value)}};
    if (t.materiality > 0) j["materiality"] = Number(t.materiality);
    j["passed"] = t.passed;
    tests.push_back(j);
  }
  auto share = [](double x) { return x < 0 ? json(nullptr) : Number(x); };
  return json{{"passed", c.passed},
              {"level", Number(c.level)},
              {"tests", tests},
              {"inSampleExplained", share(c.in_sample_explained)},
              {"heldOutExplained", share(c.held_out_explained)},
              {"summary", c.summary}};
}

}  // namespace

json DiagnosisJsonValue(const DiagnosisReport& r, bool include_series) {
  const absl::Time t0 = r.first_frame_time;
  json findings = json::array();
  for (const Finding& f : r.findings) findings.push_back(FindingJson(f, include_series));
  json regimes = json::array();
  for (const auto& s : r.regimes) {
    json j{{"regime", estimator::discovery::RegimeName(s.regime)},
           {"start", FormatUtc(s.start)},
           {"end", FormatUtc(s.end)},
           {"startHours", absl::ToDoubleHours(s.start - t0)},
           {"endHours", absl::ToDoubleHours(s.end - t0)},
           {"rateDegS", Number(estimator::RadToDeg(s.mean_rate))}};
    if (!s.axis_b.isZero()) j["axisBody"] = json::array({s.axis_b.x(), s.axis_b.y(), s.axis_b.z()});
    regimes.push_back(j);
  }
  json candidates = json::array();
  for (const CandidateScore& c : r.candidates) candidates.push_back(CandidateJson(c));
  json doc{{"verdict", r.verdict},
           {"findings", findings},
           {"mismatch", MismatchJson(r.mismatch, t0)},
           {"fit", json{{"before", FitJson(r.before, t0)}, {"after", FitJson(r.after, t0)}}},
           {"regimes", regimes},
           {"candidates", candidates},
           {"gyros", r.gyros},
           {"firstFrame", FormatUtc(t0)},
           {"frames", r.frames},
           {"filterRuns", r.filter_runs}};
  if (r.consistency.checked) doc["consistency"] = ConsistencyJson(r.consistency);
  if (!r.orbit.empty()) doc["orbit"] = r.orbit;
  if (include_series) {
    auto residuals = [](const std::vector<estimator::discovery::ResidualPoint>& v) {
      json a = json::array();
      for (const auto& p : v) {
        a.push_back(
            json::array({p.hours, p.gyro, Number(p.residual_arcsec), Number(p.sigma_arcsec)}));
      }
      return a;
    };
    auto held = [](const std::vector<estimator::discovery::HeldOutPoint>& v) {
      json a = json::array();
      for (const auto& p : v) a.push_back(json::array({p.hours, p.gap, p.error_arcsec}));
      return a;
    };
    // The open-ended stage's residual drift: [hours, gyro, before x, y, z, after x, y, z, sigma]
    // in deg/h, case axes.
    json drift = json::array();
    for (const auto& p : r.residual_drift) {
      drift.push_back(json::array({p.hours, p.gyro, Number(p.before_deg_h[0]),
                                   Number(p.before_deg_h[1]), Number(p.before_deg_h[2]),
                                   Number(p.after_deg_h[0]), Number(p.after_deg_h[1]),
                                   Number(p.after_deg_h[2]), Number(p.sigma_deg_h)}));
    }
    doc["series"] = json{{"residualsBefore", residuals(r.residuals_before)},
                         {"residualsAfter", residuals(r.residuals_after)},
                         {"heldOutBefore", held(r.held_out_before)},
                         {"heldOutAfter", held(r.held_out_after)},
                         {"residualDrift", drift}};
  }
  return doc;
}

std::string DiagnosisToJson(const DiagnosisReport& report, bool include_series) {
  return DiagnosisJsonValue(report, include_series).dump(2);
}

absl::StatusOr<DiagnosisReport> DiagnosisFindingsFromJson(std::string_view text) {
  const json doc = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (doc.is_discarded() || !doc.is_object()) {
    return absl::InvalidArgumentError("report_json: not a JSON object");
  }
  DiagnosisReport report;
  if (!doc.contains("verdict") || !doc["verdict"].is_string()) {
    return absl::InvalidArgumentError("report_json.verdict: missing");
  }
  report.verdict = doc["verdict"].get<std::string>();
  if (!doc.contains("findings")) return report;
  if (!doc["findings"].is_array()) {
    return absl::InvalidArgumentError("report_json.findings: not an array");
  }
  int i = 0;
  for (const json& jf : doc["findings"]) {
    const std::string field = absl::StrCat("report_json.findings[", i++, "]");
    if (!jf.is_object() || !jf.contains("effect") || !jf["effect"].is_string()) {
      return absl::InvalidArgumentError(absl::StrCat(field, ".effect: missing"));
    }
    Finding f;
    f.effect = jf["effect"].get<std::string>();
    if (jf.contains("gyro") && jf["gyro"].is_number_integer()) f.gyro = jf["gyro"].get<int>();
    if (jf.contains("parameters") && jf["parameters"].is_array()) {
      for (const json& jp : jf["parameters"]) {
        if (!jp.is_object() || !jp.contains("name") || !jp["name"].is_string() ||
            !jp.contains("value") || !jp["value"].is_number()) {
          continue;  // a value JSON could not hold (null) is not applied
        }
        Parameter p;
        p.name = jp["name"].get<std::string>();
        p.value = jp["value"].get<double>();
        if (jp.contains("sigma") && jp["sigma"].is_number()) p.sigma = jp["sigma"].get<double>();
        if (jp.contains("unit") && jp["unit"].is_string()) p.unit = jp["unit"].get<std::string>();
        f.parameters.push_back(std::move(p));
      }
    }
    if (jf.contains("modelTerms") && jf["modelTerms"].is_array()) {
      int k = 0;
      for (const json& jt : jf["modelTerms"]) {
        const std::string term_field = absl::StrCat(field, ".modelTerms[", k++, "]");
        esg::v1::BasisTerm proto;
        if (!google::protobuf::util::JsonStringToMessage(jt.dump(), &proto).ok()) {
          return absl::InvalidArgumentError(absl::StrCat(term_field, ": not a basis term"));
        }
        absl::StatusOr<estimator::BasisTerm> term = BasisTermFromProto(proto, term_field);
        if (!term.ok()) return term.status();
        f.basis_terms.push_back(*term);
      }
    }
    if (jf.contains("readoutDistortion")) {
      const json& d = jf["readoutDistortion"];
      if (!d.is_array() || d.size() != 9) {
        return absl::InvalidArgumentError(
            absl::StrCat(field, ".readoutDistortion: expected 9 numbers (row-major)"));
      }
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) {
          if (!d[3 * r + c].is_number()) {
            return absl::InvalidArgumentError(
                absl::StrCat(field, ".readoutDistortion: expected 9 numbers (row-major)"));
          }
          f.readout_distortion(r, c) = d[3 * r + c].get<double>();
        }
      }
    }
    report.findings.push_back(std::move(f));
  }
  return report;
}

}  // namespace esg::proto_convert
