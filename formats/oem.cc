// CCSDS OEM (KVN) reader/validator and writer (docs/formats.md, "Orbit: CCSDS OEM").
#include "formats/oem.h"

#include <cmath>
#include <set>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "estimator/status_macros.h"
#include "formats/ccsds_kvn.h"

namespace esg::storage {
namespace {

using estimator::OrbitState;

const std::set<std::string>& HeaderKeywords() {
  static const auto* k = new std::set<std::string>{"CCSDS_OEM_VERS", "CREATION_DATE", "ORIGINATOR",
                                                   "MESSAGE_ID", "CLASSIFICATION"};
  return *k;
}

const std::set<std::string>& MetadataKeywords() {
  static const auto* k = new std::set<std::string>{
      "OBJECT_NAME", "OBJECT_ID",          "CENTER_NAME",       "REF_FRAME",
      "TIME_SYSTEM", "REF_FRAME_EPOCH",    "START_TIME",        "USEABLE_START_TIME",
      "STOP_TIME",   "USEABLE_STOP_TIME",  "INTERPOLATION",     "INTERPOLATION_DEGREE"};
  return *k;
}

// Inertial frames aligned with J2000 to 0.1 arcsec (the frame bias between EME2000 and the ICRS
// is 0.02 arcsec): what the sun's and the shadow's geometry need.
const std::set<std::string>& InertialFrames() {
  static const auto* k = new std::set<std::string>{"EME2000", "GCRF", "ICRF"};
  return *k;
}

absl::Status CheckMetadata(OemSegment& segment, int line) {
  const std::map<std::string, std::string>& m = segment.metadata;
  for (const char* k : {"OBJECT_NAME", "OBJECT_ID", "CENTER_NAME", "REF_FRAME", "TIME_SYSTEM",
                        "START_TIME", "STOP_TIME"}) {
    if (!m.count(k)) return KvnLineError(line, k, "required metadata keyword missing");
  }
  auto line_of = [&](const char* k) { return segment.metadata_lines.at(k); };
  if (m.at("CENTER_NAME") != "EARTH") {
    return KvnLineError(line_of("CENTER_NAME"), "CENTER_NAME",
                        absl::StrCat("'", absl::CHexEscape(m.at("CENTER_NAME")),
                                     "' is not read: the orbit must be about the Earth (EARTH)"));
  }
  if (!InertialFrames().count(m.at("REF_FRAME"))) {
    return KvnLineError(
        line_of("REF_FRAME"), "REF_FRAME",
        absl::StrCat("'", absl::CHexEscape(m.at("REF_FRAME")),
                     "' is not read: the states must be in an inertial frame aligned with J2000 "
                     "(EME2000, GCRF or ICRF); convert a rotating or of-date frame first"));
  }
  const std::string& time_system = m.at("TIME_SYSTEM");
  if (absl::Status s = CheckKvnTimeSystem(time_system); !s.ok()) {
    return KvnLineError(line_of("TIME_SYSTEM"), "TIME_SYSTEM", s.message());
  }
  auto epoch = [&](const char* k) -> absl::StatusOr<absl::Time> {
    absl::StatusOr<absl::Time> t = ParseKvnEpoch(m.at(k), time_system);
    if (!t.ok()) return KvnLineError(line_of(k), k, t.status().message());
    return t;
  };
  absl::StatusOr<absl::Time> start = epoch("START_TIME");
  if (!start.ok()) return start.status();
  absl::StatusOr<absl::Time> stop = epoch("STOP_TIME");
  if (!stop.ok()) return stop.status();
  if (*stop < *start) return KvnLineError(line_of("STOP_TIME"), "STOP_TIME", "before START_TIME");
  segment.start_time = *start;
  segment.stop_time = *stop;
  segment.useable_start = *start;
  segment.useable_stop = *stop;
  for (const char* k : {"USEABLE_START_TIME", "USEABLE_STOP_TIME"}) {
    if (!m.count(k)) continue;
    absl::StatusOr<absl::Time> t = epoch(k);
    if (!t.ok()) return t.status();
    if (*t < *start || *t > *stop) {
      return KvnLineError(line_of(k), k, "outside START_TIME..STOP_TIME");
    }
    (absl::StrContains(k, "START") ? segment.useable_start : segment.useable_stop) = *t;
  }
  if (segment.useable_stop < segment.useable_start) {
    return KvnLineError(line, "USEABLE_STOP_TIME", "before USEABLE_START_TIME");
  }
  if (m.count("REF_FRAME_EPOCH")) {
    if (absl::StatusOr<absl::Time> t = epoch("REF_FRAME_EPOCH"); !t.ok()) return t.status();
  }
  if (m.count("INTERPOLATION_DEGREE")) {
    int degree = 0;
    if (!ParseKvnDigits(m.at("INTERPOLATION_DEGREE"), &degree)) {
      return KvnLineError(line_of("INTERPOLATION_DEGREE"), "INTERPOLATION_DEGREE",
                          "not a non-negative integer");
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<OemFile> ParseOem(absl::string_view text) {
  // kHeader: before the first segment; kMeta: inside META_START..META_STOP; kData: the data
  // lines after META_STOP; kCovariance: inside COVARIANCE_START..STOP; kAfter: after
  // COVARIANCE_STOP (only another segment may follow).
  enum class Where { kHeader, kMeta, kData, kCovariance, kAfter };
  OemFile file;
  Where where = Where::kHeader;
  OemSegment segment;
  std::set<std::string> seen;
  int line_number = 0, meta_start_line = 0;
  bool first_keyword = true;
  int cov_row = 0;       // rows read of the current covariance matrix (0: expecting EPOCH)
  bool cov_epoch = false;

  auto finish_segment = [&](int line) -> absl::Status {
    if (segment.states.empty()) return KvnLineError(line, "data", "a segment needs data lines");
    if (cov_row != 0 && cov_row != 6) {
      return KvnLineError(line, "COVARIANCE", "a covariance matrix needs 6 rows");
    }
    file.segments.push_back(std::move(segment));
    segment = OemSegment();
    return absl::OkStatus();
  };

  for (absl::string_view raw : absl::StrSplit(text, '\n')) {
    ++line_number;
    const absl::string_view line = absl::StripAsciiWhitespace(raw);
    if (line.empty()) continue;
    if (absl::StartsWith(line, "COMMENT")) {
      if (where == Where::kData && !segment.states.empty()) {
        return KvnLineError(line_number, "COMMENT", "not allowed between data lines");
      }
      if (where == Where::kMeta) {
        segment.comments.emplace_back(absl::StripAsciiWhitespace(line.substr(7)));
      }
      continue;
    }
    if (line == "META_START") {
      if (first_keyword || where == Where::kMeta || where == Where::kCovariance) {
        return KvnLineError(line_number, "META_START", "unexpected here");
      }
      if (where == Where::kHeader) {
        for (const char* k : {"CREATION_DATE", "ORIGINATOR"}) {
          if (!file.header.count(k)) {
            return KvnLineError(line_number, k, "required header keyword missing");
          }
        }
      } else if (absl::Status s = finish_segment(line_number); !s.ok()) {
        return s;
      }
      where = Where::kMeta;
      meta_start_line = line_number;
      seen.clear();
      continue;
    }
    if (line == "META_STOP") {
      if (where != Where::kMeta) return KvnLineError(line_number, "META_STOP", "without META_START");
      if (absl::Status s = CheckMetadata(segment, line_number); !s.ok()) return s;
      where = Where::kData;
      continue;
    }
    if (line == "COVARIANCE_START") {
      if (where != Where::kData || segment.states.empty()) {
        return KvnLineError(line_number, "COVARIANCE_START", "not after a segment's data lines");
      }
      where = Where::kCovariance;
      cov_row = 0;
      cov_epoch = false;
      continue;
    }
    if (line == "COVARIANCE_STOP") {
      if (where != Where::kCovariance) {
        return KvnLineError(line_number, "COVARIANCE_STOP", "without COVARIANCE_START");
      }
      if (cov_row != 0 && cov_row != 6) {
        return KvnLineError(line_number, "COVARIANCE_STOP",
                            absl::StrCat("the matrix before it has ", cov_row, " of 6 rows"));
      }
      where = Where::kAfter;
      continue;
    }
    if (where == Where::kData || where == Where::kCovariance) {
      const bool keyword = absl::StrContains(line, '=');
      if (where == Where::kData && !keyword) {
        const std::vector<absl::string_view> f =
            absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty());
        if (f.size() != 7 && f.size() != 10) {
          return KvnLineError(line_number, "data",
                              absl::StrCat("expected an epoch and 6 numbers (X Y Z X_DOT Y_DOT "
                                           "Z_DOT, optionally 3 accelerations), got ",
                                           f.size(), " fields"));
        }
        absl::StatusOr<absl::Time> t =
            ParseKvnEpoch(f[0], segment.metadata.at("TIME_SYSTEM"));
        if (!t.ok()) return KvnLineError(line_number, "epoch", t.status().message());
        double v[9];
        for (size_t i = 1; i < f.size(); ++i) {
          if (!absl::SimpleAtod(f[i], &v[i - 1]) || !std::isfinite(v[i - 1])) {
            static const char* kNames[] = {"X", "Y", "Z", "X_DOT", "Y_DOT", "Z_DOT",
                                           "X_DDOT", "Y_DDOT", "Z_DDOT"};
            return KvnLineError(line_number, kNames[i - 1],
                                absl::StrCat("'", absl::CHexEscape(f[i]), "' is not a number"));
          }
        }
        if (!segment.states.empty() && *t <= segment.states.back().time) {
          return KvnLineError(line_number, "epoch",
                              absl::StrCat(f[0], " is not after the previous epoch"));
        }
        if (*t < segment.start_time || *t > segment.stop_time) {
          return KvnLineError(line_number, "epoch",
                              absl::StrCat(f[0], " is outside START_TIME..STOP_TIME"));
        }
        OrbitState s;
        s.time = *t;
        s.r_in_km = Eigen::Vector3d(v[0], v[1], v[2]);
        s.v_in_km_s = Eigen::Vector3d(v[3], v[4], v[5]);
        segment.states.push_back(s);
        continue;
      }
      if (where == Where::kData) {
        return KvnLineError(line_number, "data",
                            absl::StrCat("'", absl::CHexEscape(line.substr(0, 40)),
                                         "' is not a data line (epoch and 6 numbers)"));
      }
      // Covariance: EPOCH = t, COV_REF_FRAME = f (optional), then rows of 1 .. 6 numbers.
      if (keyword) {
        absl::StatusOr<KvnKeyValue> kv = SplitKvnLine(line, line_number);
        if (!kv.ok()) return kv.status();
        if (kv->key == "EPOCH") {
          if (cov_row != 0 && cov_row != 6) {
            return KvnLineError(line_number, "EPOCH",
                                absl::StrCat("the matrix before it has ", cov_row, " of 6 rows"));
          }
          absl::StatusOr<absl::Time> t =
              ParseKvnEpoch(kv->value, segment.metadata.at("TIME_SYSTEM"));
          if (!t.ok()) return KvnLineError(line_number, "EPOCH", t.status().message());
          cov_row = 0;
          cov_epoch = true;
          ++segment.covariance_blocks;
        } else if (kv->key == "COV_REF_FRAME") {
          if (!cov_epoch || cov_row != 0) {
            return KvnLineError(line_number, "COV_REF_FRAME", "only right after EPOCH");
          }
        } else {
          return KvnLineError(line_number, kv->key, "not a covariance keyword");
        }
        continue;
      }
      if (!cov_epoch || cov_row >= 6) {
        return KvnLineError(line_number, "covariance", "a row without its EPOCH");
      }
      const std::vector<absl::string_view> f =
          absl::StrSplit(line, absl::ByAnyChar(" \t"), absl::SkipEmpty());
      if (static_cast<int>(f.size()) != cov_row + 1) {
        return KvnLineError(line_number, "covariance",
                            absl::StrCat("row ", cov_row + 1, " of the lower triangle needs ",
                                         cov_row + 1, " numbers, got ", f.size()));
      }
      for (absl::string_view x : f) {
        double d = 0.0;
        if (!absl::SimpleAtod(x, &d) || !std::isfinite(d)) {
          return KvnLineError(line_number, "covariance",
                              absl::StrCat("'", absl::CHexEscape(x), "' is not a number"));
        }
      }
      if (++cov_row == 6) cov_epoch = false;
      continue;
    }
    absl::StatusOr<KvnKeyValue> kv = SplitKvnLine(line, line_number);
    if (!kv.ok()) return kv.status();
    const std::string& key = kv->key;
    const std::string& value = kv->value;
    if (first_keyword) {
      if (key != "CCSDS_OEM_VERS") {
        return KvnLineError(line_number, key, "the first keyword must be CCSDS_OEM_VERS");
      }
      if (value != "1.0" && value != "2.0" && value != "3.0") {
        return KvnLineError(line_number, key, absl::StrCat("unsupported version ", value));
      }
      file.version = value;
      first_keyword = false;
      seen.insert(key);
      continue;
    }
    if (where == Where::kAfter) {
      return KvnLineError(line_number, key, "after COVARIANCE_STOP only a segment may follow");
    }
    if (!seen.insert(key).second) return KvnLineError(line_number, key, "repeated");
    if (where == Where::kHeader) {
      if (!HeaderKeywords().count(key)) return KvnLineError(line_number, key, "not a header keyword");
      if (key == "CREATION_DATE") {
        if (absl::StatusOr<absl::Time> t = ParseCcsdsTime(value); !t.ok()) {
          return KvnLineError(line_number, key, t.status().message());
        }
      }
      file.header[key] = value;
      continue;
    }
    if (!MetadataKeywords().count(key)) {
      return KvnLineError(line_number, key, "not a metadata keyword");
    }
    segment.metadata[key] = value;
    segment.metadata_lines[key] = line_number;
  }
  if (first_keyword) return KvnLineError(line_number, "CCSDS_OEM_VERS", "missing");
  if (where == Where::kMeta) return KvnLineError(meta_start_line, "META_START", "no META_STOP");
  if (where == Where::kCovariance) return KvnLineError(line_number, "COVARIANCE_STOP", "missing");
  if (where == Where::kHeader) return KvnLineError(line_number, "META_START", "no segment");
  if (absl::Status s = finish_segment(line_number); !s.ok()) return s;
  return file;
}

namespace {

// The arcs of one delivery (its segments' useable spans, in file order) appended to `arcs`, and
// what the orbit's errors call each (`prefix` then "segment n (line m): ") to `names`.
absl::Status AppendOemArcs(absl::string_view text, absl::string_view spacecraft_id,
                           absl::string_view prefix, std::vector<estimator::OrbitArc>& arcs,
                           std::vector<std::string>& names) {
  absl::StatusOr<OemFile> file = ParseOem(text);
  if (!file.ok()) {
    return absl::Status(file.status().code(), absl::StrCat(prefix, file.status().message()));
  }
  for (size_t i = 0; i < file->segments.size(); ++i) {
    const OemSegment& segment = file->segments[i];
    const int line = segment.metadata_lines.at("OBJECT_NAME");
    const std::string& name = segment.metadata.at("OBJECT_NAME");
    const std::string& id = segment.metadata.at("OBJECT_ID");
    if (name != spacecraft_id && id != spacecraft_id) {
      const absl::Status error = KvnLineError(line, "OBJECT_NAME",
                          absl::StrCat("'", absl::CHexEscape(name), "' (OBJECT_ID '",
                                       absl::CHexEscape(id), "') is not spacecraft '",
                                       absl::CHexEscape(spacecraft_id),
                                       "': the orbit is of another spacecraft (OBJECT_NAME or "
                                       "OBJECT_ID must be the spacecraft id)"));
      return absl::Status(error.code(), absl::StrCat(prefix, error.message()));
    }
    estimator::OrbitArc arc;
    arc.states = segment.states;
    arc.from = std::max(segment.useable_start, segment.states.front().time);
    arc.to = std::min(segment.useable_stop, segment.states.back().time);
    if (arc.to < arc.from) {
      return absl::InvalidArgumentError(absl::StrCat(
          prefix, "segment ", i + 1, " (line ", line, "): its useable span holds no two states"));
    }
    arcs.push_back(std::move(arc));
    names.push_back(absl::StrCat(prefix, "segment ", i + 1, " (line ", line, "): "));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<estimator::Orbit> ParseOemOrbit(absl::string_view text,
                                               absl::string_view spacecraft_id) {
  std::vector<estimator::OrbitArc> arcs;
  std::vector<std::string> names;  // what the orbit's errors call each segment
  RETURN_IF_ERROR(AppendOemArcs(text, spacecraft_id, "", arcs, names));
  return estimator::Orbit::FromArcs(std::move(arcs), names);
}

absl::StatusOr<estimator::Orbit> OrbitFromDeliveries(const std::vector<std::string>& texts,
                                                     const std::vector<std::string>& names,
                                                     absl::string_view spacecraft_id) {
  std::vector<estimator::OrbitArc> arcs;
  std::vector<std::string> arc_names;
  for (size_t i = 0; i < texts.size(); ++i) {
    const std::string prefix = i < names.size() ? names[i] : absl::StrCat("delivery ", i + 1, ": ");
    RETURN_IF_ERROR(AppendOemArcs(texts[i], spacecraft_id, prefix, arcs, arc_names));
  }
  return estimator::Orbit::FromArcs(std::move(arcs), arc_names);
}

absl::StatusOr<std::string> WriteOem(const OemHeader& header,
                                     const std::vector<OrbitState>& states) {
  if (header.object_name.empty()) return absl::InvalidArgumentError("OBJECT_NAME: empty");
  if (header.object_id.empty()) return absl::InvalidArgumentError("OBJECT_ID: empty");
  if (header.originator.empty()) return absl::InvalidArgumentError("ORIGINATOR: empty");
  if (states.size() < 2) {
    return absl::InvalidArgumentError("states: an orbit needs at least 2 states");
  }
  for (size_t i = 0; i < states.size(); ++i) {
    if (!states[i].r_in_km.allFinite() || !states[i].v_in_km_s.allFinite()) {
      return absl::InvalidArgumentError(absl::StrCat("states[", i, "]: not finite"));
    }
    if (i > 0 && states[i].time <= states[i - 1].time) {
      return absl::InvalidArgumentError(absl::StrCat(
          "states[", i, "].time: ", FormatCcsdsTime(states[i].time), " is not after the previous"));
    }
  }
  std::string out;
  absl::StrAppend(&out, "CCSDS_OEM_VERS = 2.0\n");
  absl::StrAppend(&out, "CREATION_DATE = ", FormatCcsdsTime(header.creation_date), "\n");
  absl::StrAppend(&out, "ORIGINATOR = ", header.originator, "\n\n");
  absl::StrAppend(&out, "META_START\n");
  for (const std::string& comment : header.comments) absl::StrAppend(&out, "COMMENT ", comment, "\n");
  absl::StrAppend(&out, "OBJECT_NAME = ", header.object_name, "\n");
  absl::StrAppend(&out, "OBJECT_ID = ", header.object_id, "\n");
  absl::StrAppend(&out, "CENTER_NAME = EARTH\n");
  absl::StrAppend(&out, "REF_FRAME = EME2000\n");
  absl::StrAppend(&out, "TIME_SYSTEM = UTC\n");
  absl::StrAppend(&out, "START_TIME = ", FormatCcsdsTime(states.front().time), "\n");
  absl::StrAppend(&out, "STOP_TIME = ", FormatCcsdsTime(states.back().time), "\n");
  absl::StrAppend(&out, "INTERPOLATION = HERMITE\n");
  absl::StrAppend(&out, "INTERPOLATION_DEGREE = 3\n");
  absl::StrAppend(&out, "META_STOP\n\n");
  for (const OrbitState& s : states) {
    absl::StrAppend(&out, FormatCcsdsTime(s.time),
                    absl::StrFormat(" %.6f %.6f %.6f %.9f %.9f %.9f\n", s.r_in_km.x(), s.r_in_km.y(),
                                    s.r_in_km.z(), s.v_in_km_s.x(), s.v_in_km_s.y(),
                                    s.v_in_km_s.z()));
  }
  return out;
}

}  // namespace esg::storage
