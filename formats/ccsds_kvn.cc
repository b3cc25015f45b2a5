// CCSDS Keyword = Value Notation shared by the message readers (docs/formats.md, "Attitude
// product" and "Orbit"): ASCII time codes, the time systems read, line errors.
#include "formats/ccsds_kvn.h"

#include <cmath>
#include <cstdint>
#include <set>
#include <string>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/time/civil_time.h"
#include "erfa.h"

namespace esg::storage {
namespace {

const std::set<std::string>& TimeSystems() {
  static const auto* k = new std::set<std::string>{
      "GMST", "GPS", "MET", "MRT", "SCLK", "TAI", "TCB", "TDB", "TCG", "TT", "UT1", "UTC"};
  return *k;
}

// A TAI calendar reading (parsed by ParseCcsdsTime as if it were UTC: `label`) as the UTC
// instant, with the leap seconds of ERFA's table (eraTaiutc; liberfa's table ends with the leap
// second of 2016-12-31, and ERFA calls years more than 5 after its release "dubious": they are
// converted with the last TAI-UTC, 37 s). An instant inside an inserted leap second comes out as
// the UTC text 23:59:60.x would (ParseCcsdsTime), i.e. x after the next midnight: absl::Time has
// no leap seconds (docs/formats.md, "Time"). Whole seconds go through ERFA, the fraction is added
// exactly, so microseconds survive.
absl::StatusOr<absl::Time> TaiToUtc(absl::Time label) {
  const absl::TimeZone utc = absl::UTCTimeZone();
  const absl::CivilSecond tai = absl::ToCivilSecond(label, utc);
  const absl::Duration fraction = label - absl::FromCivil(tai, utc);
  if (tai.year() < 1960) return absl::InvalidArgumentError("TAI before 1960 has no UTC");
  double tai1 = 0.0, tai2 = 0.0;
  if (eraDtf2d("TAI", static_cast<int>(tai.year()), tai.month(), tai.day(), tai.hour(),
               tai.minute(), tai.second(), &tai1, &tai2) < 0) {
    return absl::InvalidArgumentError("not a TAI date and time");
  }
  double utc1 = 0.0, utc2 = 0.0;
  if (eraTaiutc(tai1, tai2, &utc1, &utc2) < 0) {
    return absl::InvalidArgumentError("TAI outside ERFA's TAI-UTC table");
  }
  int year = 0, month = 0, day = 0;
  int hmsf[4] = {0, 0, 0, 0};
  if (eraD2dtf("UTC", 9, utc1, utc2, &year, &month, &day, hmsf) < 0) {
    return absl::InvalidArgumentError("TAI outside ERFA's TAI-UTC table");
  }
  return absl::FromCivil(absl::CivilSecond(year, month, day, hmsf[0], hmsf[1], 0), utc) +
         absl::Seconds(hmsf[2]) + absl::Nanoseconds(hmsf[3]) + fraction;
}

}  // namespace

absl::Status KvnLineError(int line, absl::string_view what, absl::string_view reason) {
  return absl::InvalidArgumentError(absl::StrCat("line ", line, ": ", what, ": ", reason));
}

bool ParseKvnDigits(absl::string_view s, int* out) {
  if (s.empty() || s.size() > 9) return false;
  int v = 0;
  for (char c : s) {
    if (c < '0' || c > '9') return false;
    v = v * 10 + (c - '0');
  }
  *out = v;
  return true;
}

absl::Status CheckKvnTimeSystem(absl::string_view value) {
  if (!TimeSystems().count(std::string(value))) {
    return absl::InvalidArgumentError(absl::StrCat("unknown value ", value));
  }
  if (value != "UTC" && value != "TAI") {
    // Every instant of the project is UTC; a spacecraft clock (SCLK) or mission time (MET, MRT)
    // needs a correlation the file does not carry, and the other scales are not converted.
    return absl::InvalidArgumentError(
        absl::StrCat(value,
                     " is not read: the epochs must be UTC, or TAI (converted to "
                     "UTC with the leap seconds); convert the file to UTC first"));
  }
  return absl::OkStatus();
}

absl::StatusOr<absl::Time> ParseKvnEpoch(absl::string_view text, absl::string_view time_system) {
  absl::StatusOr<absl::Time> t = ParseCcsdsTime(text);
  if (!t.ok() || time_system != "TAI") return t;
  // Second 60 exists only in UTC: ParseCcsdsTime reads it as the next minute's second 0.
  const absl::string_view s = absl::StripAsciiWhitespace(text);
  const size_t colon = s.rfind(':');
  if (colon != absl::string_view::npos && absl::StartsWith(s.substr(colon + 1), "60")) {
    return absl::InvalidArgumentError(
        absl::StrCat("'", text, "' has second 60, which only UTC has (TIME_SYSTEM = TAI)"));
  }
  absl::StatusOr<absl::Time> utc = TaiToUtc(*t);
  if (!utc.ok()) {
    return absl::InvalidArgumentError(absl::StrCat("'", text, "': ", utc.status().message()));
  }
  return utc;
}

absl::StatusOr<absl::Time> ParseCcsdsTime(absl::string_view text) {
  absl::string_view s = absl::StripAsciiWhitespace(text);
  if (!s.empty() && s.back() == 'Z') s.remove_suffix(1);
  const size_t t_pos = s.find('T');
  auto bad = [&](absl::string_view why) {
    return absl::InvalidArgumentError(
        absl::StrCat("'", text, "' is not a CCSDS ASCII time (", why, ")"));
  };
  if (t_pos == absl::string_view::npos) return bad("no 'T'");
  const absl::string_view date = s.substr(0, t_pos);
  const absl::string_view clock = s.substr(t_pos + 1);
  const std::vector<absl::string_view> d = absl::StrSplit(date, '-');
  int year = 0, month = 0, day = 0, doy = 0;
  absl::CivilDay civil_day;
  if (d.size() == 3 && d[0].size() == 4 && d[1].size() == 2 && d[2].size() == 2 &&
      ParseKvnDigits(d[0], &year) && ParseKvnDigits(d[1], &month) && ParseKvnDigits(d[2], &day)) {
    civil_day = absl::CivilDay(year, month, day);
    if (civil_day.month() != month || civil_day.day() != day || month < 1 || day < 1) {
      return bad("invalid date");
    }
  } else if (d.size() == 2 && d[0].size() == 4 && d[1].size() == 3 && ParseKvnDigits(d[0], &year) &&
             ParseKvnDigits(d[1], &doy)) {
    civil_day = absl::CivilDay(year, 1, 1) + (doy - 1);
    if (doy < 1 || civil_day.year() != year) return bad("invalid day of year");
  } else {
    return bad("date is neither YYYY-MM-DD nor YYYY-DDD");
  }
  const std::vector<absl::string_view> c = absl::StrSplit(clock, ':');
  int hour = 0, minute = 0;
  if (c.size() != 3 || c[0].size() != 2 || c[1].size() != 2 || !ParseKvnDigits(c[0], &hour) ||
      !ParseKvnDigits(c[1], &minute) || hour > 23 || minute > 59) {
    return bad("time of day is not hh:mm:ss");
  }
  absl::string_view sec_text = c[2];
  const size_t dot = sec_text.find('.');
  int sec = 0;
  if (!ParseKvnDigits(sec_text.substr(0, dot), &sec) || sec_text.substr(0, dot).size() != 2 ||
      sec > 60) {
    return bad("seconds");
  }
  absl::Duration fraction = absl::ZeroDuration();
  if (dot != absl::string_view::npos) {
    const absl::string_view frac = sec_text.substr(dot + 1);
    if (frac.empty() || frac.size() > 18) return bad("fraction of a second");
    int64_t digits = 0;
    for (char ch : frac) {
      if (ch < '0' || ch > '9') return bad("fraction of a second");
      digits = digits * 10 + (ch - '0');
    }
    fraction = absl::Nanoseconds(static_cast<double>(digits) * std::pow(10.0, 9.0 - frac.size()));
  }
  const absl::CivilSecond cs(civil_day.year(), civil_day.month(), civil_day.day(), hour, minute,
                             0);
  return absl::FromCivil(cs, absl::UTCTimeZone()) + absl::Seconds(sec) + fraction;
}

std::string FormatCcsdsTime(absl::Time time) {
  return absl::FormatTime("%Y-%m-%dT%H:%M:%E6S", time, absl::UTCTimeZone());
}

absl::StatusOr<KvnKeyValue> SplitKvnLine(absl::string_view line, int line_number) {
  const size_t eq = line.find('=');
  if (eq == absl::string_view::npos) {
    return KvnLineError(line_number, "line", absl::StrCat("'", line, "' is not `KEYWORD = value`"));
  }
  KvnKeyValue kv;
  kv.key = std::string(absl::StripAsciiWhitespace(line.substr(0, eq)));
  kv.value = std::string(absl::StripAsciiWhitespace(line.substr(eq + 1)));
  if (kv.value.empty()) return KvnLineError(line_number, kv.key, "empty value");
  return kv;
}

}  // namespace esg::storage
