#include "client/diagnosis_plots.h"

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_replace.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"

namespace esg::client {

namespace {

namespace disc = estimator::discovery;

// |difference| of a gyro is Rayleigh-distributed with scale sigma (ResidualPoint::sigma_arcsec)
// when the model is right: 90% of it lies between these multiples of sigma (the 5% and 95%
// quantiles, sqrt(-2 ln 0.95) and sqrt(-2 ln 0.05)).
constexpr double kBandLow = 0.3203;
constexpr double kBandHigh = 2.4477;

// Colours: before red, after blue, the band green; held-out spans grey, the mismatch red hatching.
constexpr char kBefore[] = "#cc3333";
constexpr char kAfter[] = "#3366cc";
constexpr char kBand[] = "#66bb66";
constexpr char kHeldOut[] = "#bbbbbb";
constexpr char kMismatch[] = "#dd3333";
constexpr char kInterval[] = "#ffe0a0";

// A gnuplot single-quoted string.
std::string Quote(absl::string_view text) {
  return absl::StrCat("'", absl::StrReplaceAll(text, {{"'", "''"}}), "'");
}

absl::Status WriteText(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  out.close();
  if (!out) return absl::UnknownError(absl::StrCat("cannot write ", path.string()));
  return absl::OkStatus();
}

// What the plots share: the report, the length of the time axis and the title's start.
struct Context {
  const disc::DiagnosisReport* r = nullptr;
  double length_hours = 1.0;
  std::string start;  // "(start 2019-03-01T00:00:00Z)"

  double Hours(absl::Time t) const { return disc::HoursSince(t, r->first_frame_time); }
};

Context MakeContext(const disc::DiagnosisReport& r) {
  Context c;
  c.r = &r;
  double end = 0.0;
  for (const auto& s : r.regimes) end = std::max(end, disc::HoursSince(s.end, r.first_frame_time));
  for (const auto& p : r.residuals_before) end = std::max(end, p.hours);
  for (const auto& p : r.held_out_before) end = std::max(end, p.hours);
  c.length_hours = end > 0 ? end : 1.0;
  c.start = absl::StrCat("(start ", estimator::FormatUtc(r.first_frame_time), ")");
  return c;
}

// The preamble of one PNG: terminal, output, grid, the time axis.
std::string BeginPng(const Context& c, const std::string& png, int width, int height) {
  return absl::StrFormat(
      "reset\nset terminal pngcairo noenhanced size %d,%d font ',10'\nset encoding utf8\n"
      "set output '%s'\nset grid\nset key outside below center horizontal maxrows 1 samplen 2\n"
      "set xlabel 'hours from the start'\nset xrange [0:%.5f]\n",
      width, height, png, c.length_hours);
}
constexpr char kEndPng[] = "unset multiplot\nset output\n";

// Shaded spans behind a panel: the held-out spans and the mismatch of the configured model.
// Appends their legend entries (keyentry) to `key` when drawn, the mismatch's gyro named unless
// `name_gyro` is false (a panel of that gyro).
std::string Spans(const Context& c, bool held_out, bool mismatch, std::vector<std::string>& key,
                  bool name_gyro = true) {
  std::string gp = "unset object\n";
  int object = 1;
  auto rect = [&](double a, double b, const char* colour, const char* style) {
    absl::StrAppend(&gp, absl::StrFormat("set object %d rect from %.5f, graph 0 to %.5f, graph 1 "
                                         "fc rgb '%s' fs %s noborder behind\n",
                                         object++, a, b, colour, style));
  };
  // The hatching first: a pattern paints its background, so a held-out span goes over it.
  const disc::Mismatch& m = c.r->mismatch;
  if (mismatch && m.span >= 0) {
    rect(c.Hours(m.start), c.Hours(m.end), kMismatch, "transparent pattern 4");
    key.push_back(absl::StrFormat(
        "keyentry with boxes fs transparent pattern 4 fc rgb '%s' title %s", kMismatch,
        Quote(absl::StrCat("largest mismatch",
                           m.gyro > 0 && name_gyro ? absl::StrCat(" (gyro ", m.gyro, ")") : ""))));
  }
  if (held_out && !c.r->before.gaps.empty()) {
    for (const auto& g : c.r->before.gaps)
      rect(c.Hours(g.start), c.Hours(g.end), kHeldOut, "transparent solid 0.5");
    key.push_back(
        absl::StrFormat("keyentry with boxes fs transparent solid 0.5 fc rgb '%s' title 'held out "
                        "(star tracker withheld)'",
                        kHeldOut));
  }
  return gp;
}

std::string Plot(const std::vector<std::string>& series) {
  // Nothing to draw: an empty frame (gnuplot stops the script at a plot with no defined point).
  if (series.empty()) return "set yrange [1:10]\nplot NaN notitle\n";
  return absl::StrCat("plot ", absl::StrJoin(series, ", \\\n     "), "\n");
}

// Residual data: one index block per running gyro (the report's order), columns hours,
// |difference| [arcsec], predicted sigma [arcsec]; a blank line where the series pauses (held-out
// spans, star-tracker outages), so that the band is not drawn across the pause.
struct ResidualData {
  std::string text;
  std::map<int, int> points;                       // gyro id -> points
  std::map<int, std::pair<double, double>> range;  // gyro id -> positive min, max [arcsec]
};

ResidualData MakeResidualData(const std::vector<int>& gyros,
                              const std::vector<disc::ResidualPoint>& v) {
  ResidualData d;
  for (int id : gyros) {
    std::vector<const disc::ResidualPoint*> mine;
    for (const auto& p : v)
      if (p.gyro == id) mine.push_back(&p);
    std::vector<double> steps;
    for (size_t k = 1; k < mine.size(); ++k) steps.push_back(mine[k]->hours - mine[k - 1]->hours);
    double pause = 1e300;
    if (!steps.empty()) {
      std::nth_element(steps.begin(), steps.begin() + steps.size() / 2, steps.end());
      pause = 5.0 * steps[steps.size() / 2];
    }
    absl::StrAppend(&d.text, "# gyro ", id,
                    ": hours, |star-tracker difference| arcsec, "
                    "predicted 1-sigma of a component arcsec\n");
    std::vector<double> values;
    double hi = 0.0, lo_band = 1e300;
    for (size_t k = 0; k < mine.size(); ++k) {
      const disc::ResidualPoint& p = *mine[k];
      if (k > 0 && p.hours - mine[k - 1]->hours > pause) d.text += "\n";
      absl::StrAppend(
          &d.text, absl::StrFormat("%.5f %.3f %.3f\n", p.hours, p.residual_arcsec, p.sigma_arcsec));
      if (p.residual_arcsec > 0) values.push_back(p.residual_arcsec);
      hi = std::max({hi, p.residual_arcsec, kBandHigh * p.sigma_arcsec});
      if (p.sigma_arcsec > 0) lo_band = std::min(lo_band, kBandLow * p.sigma_arcsec);
    }
    d.text += "\n\n";
    d.points[id] = static_cast<int>(mine.size());
    if (!values.empty()) {
      // The 1% quantile, not the minimum: a Rayleigh variable comes arbitrarily close to 0.
      std::nth_element(values.begin(), values.begin() + values.size() / 100, values.end());
      d.range[id] = {std::min(values[values.size() / 100], lo_band), hi};
    }
  }
  return d;
}

// A log y range covering both series of a gyro.
std::string ResidualYRange(const ResidualData& a, const ResidualData& b, int id) {
  double lo = 1e300, hi = 0.0;
  for (const ResidualData* d : {&a, &b}) {
    auto it = d->range.find(id);
    if (it == d->range.end()) continue;
    lo = std::min(lo, it->second.first);
    hi = std::max(hi, it->second.second);
  }
  if (!(hi > 0) || !(lo < hi)) return "set autoscale y\n";
  return absl::StrFormat("set yrange [%.4g:%.4g]\n", lo / 1.5, hi * 1.5);
}

// The band and the points of one gyro (`index` into `file`), as plot series.
void ResidualSeries(const std::string& file, int index, const char* colour, const std::string& what,
                    bool band, std::vector<std::string>& series) {
  // Before: open circles, after: dots, so that where they coincide both show.
  const bool open = colour == kBefore;
  if (band) {
    series.push_back(absl::StrFormat(
        "'%s' index %d using 1:(%g*$3):(%g*$3) with filledcurves fs transparent solid 0.35 "
        "noborder lc rgb '%s' title '90%% band (model right)'",
        file, index, kBandLow, kBandHigh, kBand));
  }
  series.push_back(
      absl::StrFormat("'%s' index %d using 1:2 with points pt %d ps %.2f lc rgb '%s' title %s",
                      file, index, open ? 6 : 7, open ? 0.6 : 0.4, colour, Quote(what)));
}

std::string ResidualsScript(const Context& c, const ResidualData& before,
                            const ResidualData& after) {
  const disc::DiagnosisReport& r = *c.r;
  const int rows = std::max<int>(1, r.gyros.size());
  std::string gp = BeginPng(c, "residuals.png", 1400, 100 + 300 * rows);
  absl::StrAppend(
      &gp,
      absl::StrFormat("set multiplot layout %d,2 title %s\n", rows,
                      Quote(absl::StrCat("Star-tracker residual of each gyro, before (left) and "
                                         "after (right) adding the findings ",
                                         c.start))),
      "set logscale y\nset ylabel '|difference|, arcsec'\n");
  for (size_t k = 0; k < r.gyros.size(); ++k) {
    const int id = r.gyros[k];
    for (bool is_before : {true, false}) {
      absl::StrAppend(&gp, ResidualYRange(before, after, id));
      const ResidualData& d = is_before ? before : after;
      const disc::FitSummary& fit = is_before ? r.before : r.after;
      std::vector<std::string> series;
      const bool mismatch = is_before && (r.mismatch.gyro == 0 || r.mismatch.gyro == id);
      std::vector<std::string> key;
      absl::StrAppend(&gp, Spans(c, false, mismatch, key, /*name_gyro=*/false));
      absl::StrAppend(
          &gp, "set title ",
          Quote(absl::StrFormat("gyro %d %s: %s", id, is_before ? "before" : "after", fit.model)),
          "\n");
      if (d.points.at(id) > 0) {
        ResidualSeries(is_before ? "residuals_before.dat" : "residuals_after.dat",
                       static_cast<int>(k), is_before ? kBefore : kAfter, "|difference|", true,
                       series);
        series.insert(series.end(), key.begin(), key.end());
        absl::StrAppend(&gp, "unset label 1\n");
      } else {
        absl::StrAppend(&gp,
                        "set label 1 'no star-tracker difference formed' at graph 0.4, "
                        "graph 0.5\n");
      }
      absl::StrAppend(&gp, Plot(series));
    }
  }
  absl::StrAppend(&gp, kEndPng);
  return gp;
}

std::string HeldOutData(const std::vector<disc::HeldOutPoint>& v) {
  std::string text = "# hours, attitude error against the withheld star tracker, arcmin\n";
  int gap = -1;
  for (const auto& p : v) {
    if (p.gap != gap && gap >= 0) text += "\n\n";
    gap = p.gap;
    absl::StrAppend(
        &text, absl::StrFormat("%.5f %.4f\n", p.hours,
                               estimator::ArcsecToRad(p.error_arcsec) / estimator::kRadPerArcmin));
  }
  return text;
}

std::string HeldOutScript(const Context& c) {
  const disc::DiagnosisReport& r = *c.r;
  std::string gp = BeginPng(c, "held_out.png", 1200, 600);
  std::vector<std::string> key;
  absl::StrAppend(&gp, Spans(c, true, false, key), "set title ",
                  Quote(absl::StrCat("Attitude error where the star tracker was withheld and the "
                                     "model predicted alone ",
                                     c.start)),
                  "\nset ylabel 'attitude error, arcmin'\n");
  std::vector<std::string> series;
  if (!r.held_out_before.empty()) {
    series.push_back(
        absl::StrFormat("'held_out_before.dat' using 1:2 with lines lw 2 lc rgb '%s' title "
                        "'before: %s (drift rate %.4f deg/h)'",
                        kBefore, absl::StrReplaceAll(r.before.model, {{"'", "''"}}),
                        r.before.gap_drift_rate_deg_h));
  }
  if (!r.held_out_after.empty()) {
    series.push_back(absl::StrFormat(
        "'held_out_after.dat' using 1:2 with lines lw 2 lc rgb '%s' title "
        "'after: %s (drift rate %.4f deg/h)'",
        kAfter, absl::StrReplaceAll(r.after.model, {{"'", "''"}}), r.after.gap_drift_rate_deg_h));
  }
  if (series.empty()) {
    absl::StrAppend(&gp,
                    "set label 1 'no held-out span in this recording' at graph 0.35, graph "
                    "0.5\nset yrange [0:1]\n");
  } else {
    absl::StrAppend(&gp, "set yrange [0:*]\n");
    series.insert(series.end(), key.begin(), key.end());
  }
  absl::StrAppend(&gp, Plot(series), "set output\n");
  return gp;
}

// Regime colours, in disc::Regime order.
constexpr const char* kRegimeColour[] = {"#1b9e77", "#d95f02", "#7570b3", "#e7298a"};

std::string RegimesData(const Context& c) {
  std::string text = "# hours, body rate deg/s, colour (0xRRGGBB) of the regime\n";
  for (const auto& s : c.r->regimes) {
    const double rate = estimator::RadToDeg(s.mean_rate);
    const long colour = std::strtol(kRegimeColour[static_cast<int>(s.regime)] + 1, nullptr, 16);
    absl::StrAppend(&text, absl::StrFormat("%.5f %.6f %d\n%.5f %.6f %d\n\n", c.Hours(s.start), rate,
                                           colour, c.Hours(s.end), rate, colour));
  }
  return text;
}

std::string RegimesScript(const Context& c) {
  const disc::DiagnosisReport& r = *c.r;
  std::string gp = BeginPng(c, "regimes.png", 1200, 500);
  std::vector<std::string> key;
  absl::StrAppend(&gp, Spans(c, true, true, key), "set title ",
                  Quote(absl::StrCat("Attitude regimes found from the body rate ", c.start)),
                  "\nset ylabel 'body rate, deg/s'\nset yrange [0:*]\nset offsets 0, 0, graph "
                  "0.1, 0\n");
  std::vector<std::string> series;
  if (!r.regimes.empty()) {
    series.push_back("'regimes.dat' using 1:2:3 with lines lw 4 lc rgb variable notitle");
    bool present[4] = {false, false, false, false};
    for (const auto& s : r.regimes) present[static_cast<int>(s.regime)] = true;
    for (int k = 0; k < 4; ++k) {
      if (!present[k]) continue;
      series.push_back(
          absl::StrFormat("keyentry with lines lw 4 lc rgb '%s' title %s", kRegimeColour[k],
                          Quote(absl::StrReplaceAll(disc::RegimeName(static_cast<disc::Regime>(k)),
                                                    {{"_", " "}}))));
    }
    series.insert(series.end(), key.begin(), key.end());
  }
  absl::StrAppend(&gp, Plot(series), "set output\n");
  return gp;
}

// A vertical dashed line at `hours` (with its legend entry `title`, empty: none).
std::string VerticalLine(double hours, const std::string& title, std::vector<std::string>& key) {
  if (!title.empty())
    key.push_back(
        absl::StrCat("keyentry with lines dt 2 lw 2 lc rgb 'black' title ", Quote(title)));
  return absl::StrFormat(
      "set arrow from %.5f, graph 0 to %.5f, graph 1 nohead dt 2 lw 2 lc rgb 'black' front\n",
      hours, hours);
}

std::string IntervalObject(double a, double b, std::vector<std::string>& key,
                           const std::string& title) {
  key.push_back(absl::StrFormat("keyentry with boxes fs solid 1.0 fc rgb '%s' title %s", kInterval,
                                Quote(title)));
  return absl::StrFormat(
      "unset object\nset object 1 rect from %.5f, graph 0 to %.5f, graph 1 fc "
      "rgb '%s' fs solid 1.0 noborder behind\n",
      a, b, kInterval);
}

std::string OnsetScript(const Context& c, const disc::Finding& f, int gyro_index,
                        const ResidualData& before, const ResidualData& after) {
  const disc::TimeBehaviour& t = f.time;
  std::string gp = BeginPng(c, "onset.png", 1200, 1200);
  const std::string onset_title = absl::StrFormat("onset %.3f h (95%%: %.3f-%.3f h)", t.onset_hours,
                                                  t.onset_lower_hours, t.onset_upper_hours);
  const std::string interval_title = "95% onset interval (within 3.84 of the best)";
  absl::StrAppend(&gp,
                  absl::StrFormat("set multiplot layout 3,1 title %s\n",
                                  Quote(absl::StrFormat("%s in gyro %d: when it started %s",
                                                        t.kind == "step"          ? "Drift step"
                                                        : t.kind == "transient" ? "Transient"
                                                                                : "Coefficient step",
                                                        f.gyro, c.start))),
                  "");
  double top = 0.0;
  for (const auto& [h, v] : t.onset_profile) top = std::max(top, v);
  // 1: the likelihood over every onset searched.
  {
    std::vector<std::string> key;
    absl::StrAppend(&gp,
                    IntervalObject(t.onset_lower_hours, t.onset_upper_hours, key, interval_title));
    absl::StrAppend(&gp, VerticalLine(t.onset_hours, onset_title, key));
    absl::StrAppend(&gp, "set title 'Likelihood over the onset, every onset searched'\n",
                    "set ylabel '-2 log L above the best'\n",
                    absl::StrFormat("set yrange [0:%.4g]\n", std::max(10.0, 1.05 * top)));
    std::vector<std::string> series = {
        "'onset_profile.dat' using 1:2 with linespoints pt 7 ps 0.6 lw 1.5 lc rgb '#333333' "
        "title '-2 log L of a step at that onset'"};
    series.insert(series.end(), key.begin(), key.end());
    absl::StrAppend(&gp, Plot(series));
  }
  // 2: the same near the onset, where the interval is read off.
  const double width = std::max(t.onset_upper_hours - t.onset_lower_hours, 0.02 * c.length_hours);
  // Zoomed to the onsets around the best up to the first beyond kZoomLevel on either side.
  constexpr double kZoomLevel = 40.0;
  double z0 = 0.0, z1 = c.length_hours;
  for (const auto& [h, v] : t.onset_profile) {
    if (v > kZoomLevel && h < t.onset_hours) z0 = std::max(z0, h);
    if (v > kZoomLevel && h > t.onset_hours) z1 = std::min(z1, h);
  }
  const double pad = 0.1 * (z1 - z0);
  z0 = std::max(0.0, z0 - pad);
  z1 = std::min(c.length_hours, z1 + pad);
  {
    double zoom_top = 0.0;
    for (const auto& [h, v] : t.onset_profile)
      if (h >= z0 && h <= z1) zoom_top = std::max(zoom_top, v);
    std::vector<std::string> key;
    absl::StrAppend(&gp, "unset arrow\n",
                    IntervalObject(t.onset_lower_hours, t.onset_upper_hours, key, interval_title));
    absl::StrAppend(&gp, VerticalLine(t.onset_hours, "", key));
    absl::StrAppend(
        &gp, absl::StrFormat("set xrange [%.5f:%.5f]\n", z0, z1),
        absl::StrFormat("set yrange [0:%.4g]\n", std::clamp(1.1 * zoom_top, 10.0, kZoomLevel)),
        "set title 'The same near the onset'\n",
        "set arrow from graph 0, first 3.841 to graph 1, first 3.841 nohead lc rgb '#aa6600'\n");
    key.push_back("keyentry with lines lc rgb '#aa6600' title '3.84: chi-square(1) 95%'");
    std::vector<std::string> series = {
        "'onset_profile.dat' using 1:2 with linespoints pt 7 ps 0.6 lw 1.5 lc rgb '#333333' "
        "notitle"};
    series.insert(series.end(), key.begin(), key.end());
    absl::StrAppend(&gp, Plot(series));
  }
  // 3: the fitted step against the data: the gyro's residual around the onset.
  {
    const double w = std::max(0.1 * c.length_hours, 4.0 * width);
    std::vector<std::string> key;
    absl::StrAppend(&gp, "unset arrow\n",
                    IntervalObject(t.onset_lower_hours, t.onset_upper_hours, key, interval_title));
    key.clear();  // drawn, but named in the panels above
    absl::StrAppend(&gp, VerticalLine(t.onset_hours, "onset", key));
    absl::StrAppend(
        &gp,
        absl::StrFormat("set xrange [%.5f:%.5f]\n", std::max(0.0, t.onset_hours - w),
                        std::min(c.length_hours, t.onset_hours + w)),
        ResidualYRange(before, after, f.gyro), "set logscale y\n",
        "set ylabel '|difference|, arcsec'\n",
        absl::StrFormat("set title 'Gyro %d star-tracker residual around the onset: without the "
                        "step (before) and with it (after)'\n",
                        f.gyro));
    std::vector<std::string> series;
    if (after.points.at(f.gyro) > 0)
      ResidualSeries("residuals_after.dat", gyro_index, kAfter, "with the step (after)", true,
                     series);
    if (before.points.at(f.gyro) > 0) {
      ResidualSeries("residuals_before.dat", gyro_index, kBefore, "without it (before)", false,
                     series);
    }
    series.insert(series.end(), key.begin(), key.end());
    absl::StrAppend(&gp, Plot(series));
  }
  absl::StrAppend(&gp, kEndPng);
  return gp;
}

std::string TrendData(const disc::DisplacementTrend& t) {
  std::string text = "# hours, displacement implied by the offset voltages x y z (case axes), um\n";
  for (const auto& s : t.samples) {
    absl::StrAppend(&text, absl::StrFormat("%.5f %.5f %.5f %.5f\n", s.hours, s.displacement_um[0],
                                           s.displacement_um[1], s.displacement_um[2]));
  }
  return text;
}

std::string TrendScript(const Context& c, const disc::Finding& f) {
  const disc::DisplacementTrend& t = f.displacement_trend;
  std::string gp = BeginPng(c, "trend.png", 1200, 900);
  absl::StrAppend(
      &gp, absl::StrFormat("set multiplot layout 3,1 title %s\n",
                           Quote(absl::StrFormat("Gyro %d: rotor displacement implied by the "
                                                 "suspension offset voltages, eq. (3) %s",
                                                 f.gyro, c.start))));
  const char* axis[] = {"x", "y", "z"};
  const char* colour[] = {"#1b9e77", "#d95f02", "#7570b3"};
  for (int i = 0; i < 3; ++i) {
    absl::StrAppend(
        &gp, absl::StrFormat("set title 'case axis %s'\nset ylabel 'displacement, µm'\n", axis[i]));
    absl::StrAppend(
        &gp,
        Plot({absl::StrFormat(
                  "'trend.dat' using 1:%d with points pt 7 ps 0.5 lc rgb '%s' title "
                  "'from the voltages (mean over %.2f h bins)'",
                  i + 2, colour[i],
                  t.samples.size() > 1
                      ? (t.samples.back().hours - t.samples.front().hours) / (t.samples.size() - 1)
                      : 0.0),
              absl::StrFormat("%.6g + %.6g*x with lines lw 2 lc rgb 'black' title 'robust line: "
                              "%+.2g µm/h, %+.3f µm over the recording'",
                              t.intercept_um[i], t.rate_um_h[i], t.rate_um_h[i],
                              t.rate_um_h[i] * c.length_hours)}));
  }
  absl::StrAppend(&gp, kEndPng);
  return gp;
}

// The open-ended stage's residual drift: one index block per gyro, columns hours, before x y z,
// after x y z, sigma [deg/h].
std::string ResidualDriftData(const std::vector<int>& gyros,
                              const std::vector<disc::ResidualDriftPoint>& v) {
  std::string text =
      "# per gyro block: hours, residual drift before x y z, after x y z, 1-sigma (deg/h, case "
      "axes)\n";
  for (int id : gyros) {
    absl::StrAppend(&text, absl::StrFormat("# gyro %d\n", id));
    for (const auto& p : v) {
      if (p.gyro != id) continue;
      absl::StrAppend(&text, absl::StrFormat("%.5f %.6f %.6f %.6f %.6f %.6f %.6f %.6f\n", p.hours,
                                             p.before_deg_h[0], p.before_deg_h[1],
                                             p.before_deg_h[2], p.after_deg_h[0],
                                             p.after_deg_h[1], p.after_deg_h[2], p.sigma_deg_h));
    }
    absl::StrAppend(&text, "\n\n");
  }
  return text;
}

std::string ResidualDriftScript(const Context& c, const std::vector<int>& gyros) {
  std::string gp = BeginPng(c, "residual_drift.png", 1200, 300 * static_cast<int>(gyros.size()) + 100);
  absl::StrAppend(&gp, absl::StrFormat(
                           "set multiplot layout %d,1 title %s\n", static_cast<int>(gyros.size()),
                           Quote(absl::StrCat("Residual drift the model leaves, smoothed, case "
                                              "axes ",
                                              c.start))));
  const char* axis[] = {"x", "y", "z"};
  const char* colour[] = {"#1b9e77", "#d95f02", "#7570b3"};
  for (size_t g = 0; g < gyros.size(); ++g) {
    absl::StrAppend(&gp, absl::StrFormat("set title 'gyro %d'\nset ylabel 'drift, deg/h'\n",
                                         gyros[g]));
    std::vector<std::string> series = {absl::StrFormat(
        "'residual_drift.dat' index %d using 1:(-2*$8):(2*$8) with filledcurves fc rgb '#cccccc' "
        "fs transparent solid 0.5 title '±2 sigma after'",
        static_cast<int>(g))};
    for (int i = 0; i < 3; ++i) {
      series.push_back(absl::StrFormat(
          "'residual_drift.dat' index %d using 1:%d with lines dt 2 lc rgb '%s' title '%s before'",
          static_cast<int>(g), i + 2, colour[i], axis[i]));
      series.push_back(absl::StrFormat(
          "'residual_drift.dat' index %d using 1:%d with lines lw 2 lc rgb '%s' title '%s after'",
          static_cast<int>(g), i + 5, colour[i], axis[i]));
    }
    absl::StrAppend(&gp, Plot(series));
  }
  absl::StrAppend(&gp, kEndPng);
  return gp;
}

}  // namespace

absl::StatusOr<std::vector<DiagnosisPlot>> WriteDiagnosisPlots(const disc::DiagnosisReport& r,
                                                               const std::filesystem::path& dir) {
  const Context c = MakeContext(r);
  std::vector<DiagnosisPlot> plots;
  const ResidualData before = MakeResidualData(r.gyros, r.residuals_before);
  const ResidualData after = MakeResidualData(r.gyros, r.residuals_after);
  for (const auto& [name, text] :
       {std::pair<const char*, const std::string*>{"residuals_before.dat", &before.text},
        {"residuals_after.dat", &after.text}}) {
    if (absl::Status s = WriteText(dir / name, *text); !s.ok()) return s;
  }
  if (absl::Status s = WriteText(dir / "held_out_before.dat", HeldOutData(r.held_out_before));
      !s.ok())
    return s;
  if (absl::Status s = WriteText(dir / "held_out_after.dat", HeldOutData(r.held_out_after));
      !s.ok())
    return s;
  if (absl::Status s = WriteText(dir / "regimes.dat", RegimesData(c)); !s.ok()) return s;

  std::string gp = absl::StrCat(
      "# Plots of the diagnosis report (esg diagnose --out): run "
      "`gnuplot plots.gp` in this directory.\n",
      ResidualsScript(c, before, after));
  plots.push_back(
      {"residuals.png", "residuals before and after",
       "Each gyro's star-tracker residual with the configured model (left) and with the findings "
       "added (right), against the green band that holds 90% of it if the model is right: "
       "points above the band are what the model leaves out (red hatching: where the configured "
       "model disagrees most)."});
  absl::StrAppend(&gp, HeldOutScript(c));
  plots.push_back({"held_out.png", "held-out attitude error",
                   "The attitude error where the star tracker was withheld and the model "
                   "predicted alone: a model that captures the physics keeps the blue (after) "
                   "line flat and below the red (before) one."});
  absl::StrAppend(&gp, RegimesScript(c));
  plots.push_back(
      {"regimes.png", "attitude regimes",
       "The attitude regimes found from the body rate, the held-out spans (grey) and "
       "the configured model's largest mismatch (red hatching): look at which regime the "
       "mismatch sits in."});

  for (const disc::Finding& f : r.findings) {
    // A drift step's onset, a coefficient step's or a transient's (the same search).
    if ((f.time.kind != "step" && f.time.kind != "coefficient_step" &&
         f.time.kind != "transient") ||
        f.time.onset_profile.empty()) {
      continue;
    }
    const auto it = std::find(r.gyros.begin(), r.gyros.end(), f.gyro);
    if (it == r.gyros.end()) continue;
    std::string profile = "# onset hours, -2 log L above the best\n";
    for (const auto& [h, v] : f.time.onset_profile)
      absl::StrAppend(&profile, absl::StrFormat("%.5f %.3f\n", h, v));
    if (absl::Status s = WriteText(dir / "onset_profile.dat", profile); !s.ok()) return s;
    absl::StrAppend(&gp, OnsetScript(c, f, static_cast<int>(it - r.gyros.begin()), before, after));
    plots.push_back(
        {"onset.png", absl::StrCat(f.time.kind == "step" ? "drift step" : f.time.kind == "transient" ? "transient" : "coefficient step", " onset"),
         absl::StrFormat(
             "When gyro %d's drift stepped: -2 log L against the onset is zero at the best "
             "onset and the 95%% interval (shaded) is where it stays below 3.84; at the bottom "
             "the gyro's residual without the step (red) leaves the band from the onset on, "
             "with it (blue) it stays in.",
             f.gyro)});
    break;  // the first drift step
  }
  for (const disc::Finding& f : r.findings) {
    if (f.displacement_trend.samples.empty()) continue;
    if (absl::Status s = WriteText(dir / "trend.dat", TrendData(f.displacement_trend)); !s.ok())
      return s;
    absl::StrAppend(&gp, TrendScript(c, f));
    plots.push_back(
        {"trend.png", "rotor displacement over time",
         absl::StrFormat("Gyro %d's rotor displacement implied by its suspension offset voltages, "
                         "per case axis, with the robust line fitted to it: a sloping line means "
                         "the displacement changed during the recording and the fitted C1, C2 "
                         "are its mean.",
                         f.gyro)});
    break;  // the first rotor displacement
  }
  if (!r.residual_drift.empty()) {
    if (absl::Status s =
            WriteText(dir / "residual_drift.dat", ResidualDriftData(r.gyros, r.residual_drift));
        !s.ok())
      return s;
    absl::StrAppend(&gp, ResidualDriftScript(c, r.gyros));
    plots.push_back(
        {"residual_drift.png", "residual drift (open-ended stage)",
         "Each gyro's drift the model leaves, smoothed over the recording (fixed-interval "
         "smoother), per case axis, with the configured model and the library's findings "
         "(dashed) and with the basis terms found (solid), against the grey band of twice its "
         "1-sigma: a term that explains the physics brings the solid lines into the band."});
  }
  if (absl::Status s = WriteText(dir / "plots.gp", gp); !s.ok()) return s;
  return plots;
}

bool RunGnuplot(const std::filesystem::path& dir) {
  const std::string command =
      absl::StrCat("cd '", dir.string(), "' && gnuplot plots.gp > gnuplot.log 2>&1");
  return std::system(command.c_str()) == 0;
}

}  // namespace esg::client
