// CCSDS AEM (KVN, ADM v2) writer and reader/validator (docs/formats.md, "Attitude product").
#include "formats/aem.h"

#include <cmath>
#include <cstdlib>
#include <map>
#include <set>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_split.h"
#include "absl/time/civil_time.h"

namespace esg::storage {
namespace {

constexpr double kUnitTolerance = 1e-6;

const std::set<std::string>& HeaderKeywords() {
  static const auto* k = new std::set<std::string>{"CCSDS_AEM_VERS", "CREATION_DATE", "ORIGINATOR",
                                                   "MESSAGE_ID", "CLASSIFICATION"};
  return *k;
}

const std::set<std::string>& MetadataKeywords() {
  static const auto* k = new std::set<std::string>{
      "OBJECT_NAME",        "OBJECT_ID",        "CENTER_NAME",          "REF_FRAME_A",
      "REF_FRAME_B",        "ATTITUDE_DIR",     "TIME_SYSTEM",          "START_TIME",
      "USEABLE_START_TIME", "USEABLE_STOP_TIME", "STOP_TIME",           "ATTITUDE_TYPE",
      "QUATERNION_TYPE",    "EULER_ROT_SEQ",    "ANGVEL_FRAME",         "RATE_FRAME",
      "INTERPOLATION_METHOD", "INTERPOLATION_DEGREE"};
  return *k;
}

bool IsSpacecraftBodyFrame(absl::string_view frame) {
  if (!absl::StartsWith(frame, "SC_BODY_")) return false;
  int n = 0;
  return ParseKvnDigits(frame.substr(8), &n);
}

}  // namespace

absl::StatusOr<std::string> WriteAem(const AemHeader& header,
                                     const std::vector<AemSample>& samples) {
  if (samples.empty()) return absl::InvalidArgumentError("samples: an AEM needs at least one");
  AemBlock block;
  block.samples = samples;
  absl::StatusOr<std::string> out = WriteAemBlocks(header, {std::move(block)});
  if (out.ok()) return out;
  // One block: name the samples as the caller knows them.
  std::string message(out.status().message());
  if (absl::StartsWith(message, "blocks[0].")) message = message.substr(10);
  return absl::Status(out.status().code(), message);
}

absl::StatusOr<std::string> WriteAemBlocks(const AemHeader& header,
                                           const std::vector<AemBlock>& blocks) {
  if (header.object_name.empty()) return absl::InvalidArgumentError("OBJECT_NAME: empty");
  if (header.object_id.empty()) return absl::InvalidArgumentError("OBJECT_ID: empty");
  if (header.originator.empty()) return absl::InvalidArgumentError("ORIGINATOR: empty");
  if (blocks.empty()) return absl::InvalidArgumentError("blocks: an AEM needs at least one");
  for (size_t b = 0; b < blocks.size(); ++b) {
    const std::vector<AemSample>& samples = blocks[b].samples;
    if (samples.empty()) {
      return absl::InvalidArgumentError(
          absl::StrCat("blocks[", b, "].samples: a segment needs at least one"));
    }
    if (b > 0 && samples.front().epoch <= blocks[b - 1].samples.back().epoch) {
      return absl::InvalidArgumentError(absl::StrCat(
          "blocks[", b, "].samples[0].epoch: ", FormatCcsdsTime(samples.front().epoch),
          " is not after the previous block's last epoch"));
    }
    for (size_t i = 0; i < samples.size(); ++i) {
      const double n = samples[i].q_in_b.norm();
      if (!std::isfinite(n) || std::abs(n - 1.0) > kUnitTolerance) {
        return absl::InvalidArgumentError(
            absl::StrCat("blocks[", b, "].samples[", i, "].q_in_b: norm ", n, " is not 1"));
      }
      if (i > 0 && samples[i].epoch <= samples[i - 1].epoch) {
        return absl::InvalidArgumentError(absl::StrCat("blocks[", b, "].samples[", i, "].epoch: ",
                                                       FormatCcsdsTime(samples[i].epoch),
                                                       " is not after the previous epoch"));
      }
      if (samples[i].sigma_arcsec.has_value() && !samples[i].sigma_arcsec->allFinite()) {
        return absl::InvalidArgumentError(
            absl::StrCat("blocks[", b, "].samples[", i, "].sigma_arcsec: not finite"));
      }
    }
  }
  std::string out;
  absl::StrAppend(&out, "CCSDS_AEM_VERS = 2.0\n");
  absl::StrAppend(&out, "CREATION_DATE = ", FormatCcsdsTime(header.creation_date), "\n");
  absl::StrAppend(&out, "ORIGINATOR = ", header.originator, "\n");
  if (!header.message_id.empty()) absl::StrAppend(&out, "MESSAGE_ID = ", header.message_id, "\n");
  for (const AemBlock& block : blocks) {
    const std::vector<AemSample>& samples = block.samples;
    absl::StrAppend(&out, "\nMETA_START\n");
    for (const std::string& comment : header.comments) {
      absl::StrAppend(&out, "COMMENT ", comment, "\n");
    }
    for (const std::string& comment : block.comments) {
      absl::StrAppend(&out, "COMMENT ", comment, "\n");
    }
    absl::StrAppend(&out, "OBJECT_NAME = ", header.object_name, "\n");
    absl::StrAppend(&out, "OBJECT_ID = ", header.object_id, "\n");
    absl::StrAppend(&out, "REF_FRAME_A = EME2000\n");
    absl::StrAppend(&out, "REF_FRAME_B = SC_BODY_1\n");
    absl::StrAppend(&out, "TIME_SYSTEM = UTC\n");
    absl::StrAppend(&out, "START_TIME = ", FormatCcsdsTime(samples.front().epoch), "\n");
    absl::StrAppend(&out, "STOP_TIME = ", FormatCcsdsTime(samples.back().epoch), "\n");
    absl::StrAppend(&out, "ATTITUDE_TYPE = QUATERNION\n");
    if (!block.interpolation_method.empty()) {
      absl::StrAppend(&out, "INTERPOLATION_METHOD = ", block.interpolation_method, "\n");
      if (block.interpolation_degree > 0) {
        absl::StrAppend(&out, "INTERPOLATION_DEGREE = ", block.interpolation_degree, "\n");
      }
    }
    absl::StrAppend(&out, "META_STOP\n\n");
    absl::StrAppend(&out, "DATA_START\n");
    for (const AemSample& s : samples) {
      if (!s.sigma_arcsec.has_value()) continue;
      absl::StrAppend(&out, "COMMENT SIGMA_ARCSEC ", FormatCcsdsTime(s.epoch),
                      absl::StrFormat(" %.3f %.3f %.3f\n", (*s.sigma_arcsec)(0),
                                      (*s.sigma_arcsec)(1), (*s.sigma_arcsec)(2)));
    }
    for (const AemSample& s : samples) {
      Eigen::Quaterniond q = s.q_in_b.normalized();
      if (q.w() < 0) q.coeffs() = -q.coeffs();  // sign canonical at the output edge (QC >= 0)
      absl::StrAppend(&out, FormatCcsdsTime(s.epoch),
                      absl::StrFormat(" %.15f %.15f %.15f %.15f\n", q.x(), q.y(), q.z(), q.w()));
    }
    absl::StrAppend(&out, "DATA_STOP\n");
  }
  return out;
}

absl::StatusOr<AemFile> ParseAem(absl::string_view text) {
  enum class Where { kHeader, kMeta, kBetween, kData };
  AemFile file;
  Where where = Where::kHeader;
  AemSegment segment;
  std::set<std::string> seen;  // keywords of the current section
  std::map<absl::Time, Eigen::Vector3d> sigmas;  // SIGMA_ARCSEC comments of the data section
  int line_number = 0;
  int meta_start_line = 0;
  bool first_keyword = true;

  auto finish_metadata = [&](int line) -> absl::Status {
    const std::map<std::string, std::string>& m = segment.metadata;
    std::vector<std::string> required = {"OBJECT_NAME", "OBJECT_ID",  "REF_FRAME_A",
                                         "REF_FRAME_B", "TIME_SYSTEM", "START_TIME",
                                         "STOP_TIME",   "ATTITUDE_TYPE"};
    const bool v1 = file.version == "1.0";
    if (v1) required.push_back("ATTITUDE_DIR");
    for (const std::string& k : required) {
      if (!m.count(k)) return KvnLineError(line, k, "required metadata keyword missing");
    }
    if (v1) {
      const std::string& dir = m.at("ATTITUDE_DIR");
      if (dir != "A2B" && dir != "B2A") return KvnLineError(line, "ATTITUDE_DIR", "must be A2B or B2A");
    } else {
      for (const char* k : {"ATTITUDE_DIR", "QUATERNION_TYPE"}) {
        if (m.count(k)) return KvnLineError(line, k, "not allowed in ADM version 2.0");
      }
    }
    const bool a_body = IsSpacecraftBodyFrame(m.at("REF_FRAME_A"));
    const bool b_body = IsSpacecraftBodyFrame(m.at("REF_FRAME_B"));
    if (a_body == b_body) {
      return KvnLineError(line, "REF_FRAME_A/REF_FRAME_B",
                       absl::StrCat("exactly one must be a spacecraft body frame (SC_BODY_n), got ",
                                    m.at("REF_FRAME_A"), " and ", m.at("REF_FRAME_B")));
    }
    const std::string& time_system = m.at("TIME_SYSTEM");
    if (absl::Status s = CheckKvnTimeSystem(time_system); !s.ok()) {
      return KvnLineError(segment.metadata_lines.at("TIME_SYSTEM"), "TIME_SYSTEM", s.message());
    }
    if (m.at("ATTITUDE_TYPE") != "QUATERNION") {
      return KvnLineError(line, "ATTITUDE_TYPE",
                       absl::StrCat(m.at("ATTITUDE_TYPE"), " is not supported by this reader"));
    }
    if (v1) {
      auto it = m.find("QUATERNION_TYPE");
      if (it == m.end()) {
        return KvnLineError(line, "QUATERNION_TYPE", "required for quaternions in version 1.0");
      }
      if (it->second != "FIRST" && it->second != "LAST") {
        return KvnLineError(line, "QUATERNION_TYPE", "must be FIRST or LAST");
      }
    }
    auto start = ParseKvnEpoch(m.at("START_TIME"), time_system);
    if (!start.ok()) return KvnLineError(line, "START_TIME", start.status().message());
    auto stop = ParseKvnEpoch(m.at("STOP_TIME"), time_system);
    if (!stop.ok()) return KvnLineError(line, "STOP_TIME", stop.status().message());
    if (*stop < *start) return KvnLineError(line, "STOP_TIME", "before START_TIME");
    segment.start_time = *start;
    segment.stop_time = *stop;
    for (const char* k : {"USEABLE_START_TIME", "USEABLE_STOP_TIME"}) {
      auto it = m.find(k);
      if (it == m.end()) continue;
      auto t = ParseKvnEpoch(it->second, time_system);
      if (!t.ok()) return KvnLineError(line, k, t.status().message());
      if (*t < *start || *t > *stop) return KvnLineError(line, k, "outside START_TIME..STOP_TIME");
    }
    return absl::OkStatus();
  };

  for (absl::string_view raw : absl::StrSplit(text, '\n')) {
    ++line_number;
    const absl::string_view line = absl::StripAsciiWhitespace(raw);
    if (line.empty()) continue;
    if (absl::StartsWith(line, "COMMENT")) {
      if (where == Where::kData && !segment.samples.empty()) {
        return KvnLineError(line_number, "COMMENT", "not allowed between data lines");
      }
      const absl::string_view text = absl::StripAsciiWhitespace(line.substr(7));
      if (where == Where::kMeta) segment.comments.emplace_back(text);
      if (where == Where::kData && absl::StartsWith(text, "SIGMA_ARCSEC")) {
        const std::vector<absl::string_view> f =
            absl::StrSplit(text, absl::ByAnyChar(" \t"), absl::SkipEmpty());
        if (f.size() != 5) {
          return KvnLineError(line_number, "SIGMA_ARCSEC",
                           absl::StrCat("expected an epoch and 3 values, got ", f.size() - 1,
                                        " fields"));
        }
        auto epoch = ParseKvnEpoch(f[1], segment.metadata.at("TIME_SYSTEM"));
        if (!epoch.ok()) return KvnLineError(line_number, "SIGMA_ARCSEC", epoch.status().message());
        Eigen::Vector3d sigma;
        for (int i = 0; i < 3; ++i) {
          if (!absl::SimpleAtod(f[i + 2], &sigma[i]) || !std::isfinite(sigma[i])) {
            return KvnLineError(line_number, "SIGMA_ARCSEC",
                             absl::StrCat("'", f[i + 2], "' is not a number"));
          }
        }
        sigmas[*epoch] = sigma;
      }
      continue;
    }
    if (where == Where::kData) {
      if (line == "DATA_STOP") {
        if (segment.samples.empty()) return KvnLineError(line_number, "DATA_STOP", "no data lines");
        for (AemSample& s : segment.samples) {
          auto it = sigmas.find(s.epoch);
          if (it != sigmas.end()) s.sigma_arcsec = it->second;
        }
        sigmas.clear();
        file.segments.push_back(std::move(segment));
        segment = AemSegment();
        where = Where::kHeader;  // another segment may follow (META_START)
        seen.clear();
        continue;
      }
      const std::vector<absl::string_view> f =
          absl::StrSplit(line, absl::ByAnyChar(" \t,"), absl::SkipEmpty());
      if (f.size() != 5) {
        return KvnLineError(line_number, "data",
                         absl::StrCat("expected an epoch and 4 quaternion components, got ",
                                      f.size(), " fields"));
      }
      auto epoch = ParseKvnEpoch(f[0], segment.metadata.at("TIME_SYSTEM"));
      if (!epoch.ok()) return KvnLineError(line_number, "epoch", epoch.status().message());
      double v[4];
      for (int i = 0; i < 4; ++i) {
        if (!absl::SimpleAtod(f[i + 1], &v[i]) || !std::isfinite(v[i])) {
          return KvnLineError(line_number, "quaternion", absl::StrCat("'", f[i + 1], "' is not a number"));
        }
      }
      if (!segment.samples.empty() && *epoch <= segment.samples.back().epoch) {
        return KvnLineError(line_number, "epoch",
                         absl::StrCat(f[0], " is not after the previous epoch"));
      }
      if (*epoch < segment.start_time || *epoch > segment.stop_time) {
        return KvnLineError(line_number, "epoch",
                         absl::StrCat(f[0], " is outside START_TIME..STOP_TIME"));
      }
      const bool scalar_first = file.version == "1.0" &&
                                segment.metadata.at("QUATERNION_TYPE") == "FIRST";
      Eigen::Quaterniond q = scalar_first ? Eigen::Quaterniond(v[0], v[1], v[2], v[3])
                                          : Eigen::Quaterniond(v[3], v[0], v[1], v[2]);
      if (std::abs(q.norm() - 1.0) > kUnitTolerance) {
        return KvnLineError(line_number, "quaternion", absl::StrCat("norm ", q.norm(), " is not 1"));
      }
      // Rotation from frame A to frame B; q_in_b when A is inertial (B2A in version 1 swaps).
      bool a_inertial = !IsSpacecraftBodyFrame(segment.metadata.at("REF_FRAME_A"));
      if (file.version == "1.0" && segment.metadata.at("ATTITUDE_DIR") == "B2A") {
        a_inertial = !a_inertial;
      }
      segment.samples.push_back({*epoch, a_inertial ? q : q.conjugate()});
      continue;
    }
    if (line == "META_START") {
      if (where != Where::kHeader || first_keyword) {
        return KvnLineError(line_number, "META_START", "unexpected here");
      }
      if (file.segments.empty()) {
        for (const char* k : {"CREATION_DATE", "ORIGINATOR"}) {
          if (!file.header.count(k)) return KvnLineError(line_number, k, "required header keyword missing");
        }
      }
      where = Where::kMeta;
      meta_start_line = line_number;
      seen.clear();
      continue;
    }
    if (line == "META_STOP") {
      if (where != Where::kMeta) return KvnLineError(line_number, "META_STOP", "without META_START");
      if (absl::Status s = finish_metadata(line_number); !s.ok()) return s;
      where = Where::kBetween;
      continue;
    }
    if (line == "DATA_START") {
      if (where != Where::kBetween) return KvnLineError(line_number, "DATA_START", "not after META_STOP");
      where = Where::kData;
      continue;
    }
    absl::StatusOr<KvnKeyValue> kv = SplitKvnLine(line, line_number);
    if (!kv.ok()) return kv.status();
    const std::string& key = kv->key;
    const std::string& value = kv->value;
    if (first_keyword) {
      if (key != "CCSDS_AEM_VERS") {
        return KvnLineError(line_number, key, "the first keyword must be CCSDS_AEM_VERS");
      }
      if (value != "1.0" && value != "2.0") {
        return KvnLineError(line_number, key, absl::StrCat("unsupported version ", value));
      }
      file.version = value;
      first_keyword = false;
      seen.insert(key);
      continue;
    }
    if (!seen.insert(key).second) return KvnLineError(line_number, key, "repeated");
    if (where == Where::kHeader) {
      if (!file.segments.empty() || !HeaderKeywords().count(key)) {
        return KvnLineError(line_number, key, "not a header keyword");
      }
      if (key == "CREATION_DATE") {
        if (auto t = ParseCcsdsTime(value); !t.ok()) {
          return KvnLineError(line_number, key, t.status().message());
        }
      }
      file.header[key] = value;
    } else if (where == Where::kMeta) {
      if (!MetadataKeywords().count(key)) {
        return KvnLineError(line_number, key, "not a metadata keyword");
      }
      segment.metadata[key] = value;
      segment.metadata_lines[key] = line_number;
    } else {
      return KvnLineError(line_number, key, "unexpected between META_STOP and DATA_START");
    }
  }
  if (first_keyword) return KvnLineError(line_number, "CCSDS_AEM_VERS", "missing");
  if (where == Where::kMeta) return KvnLineError(meta_start_line, "META_START", "no META_STOP");
  if (where == Where::kBetween) return KvnLineError(line_number, "DATA_START", "missing");
  if (where == Where::kData) return KvnLineError(line_number, "DATA_STOP", "missing");
  if (file.segments.empty()) return KvnLineError(line_number, "META_START", "no segment");
  return file;
}

absl::StatusOr<std::vector<AemSample>> ParseAemPlan(absl::string_view text,
                                                    absl::string_view spacecraft_id) {
  absl::StatusOr<AemFile> file = ParseAem(text);
  if (!file.ok()) return file.status();
  std::vector<AemSample> samples;
  for (const AemSegment& segment : file->segments) {
    const std::string& name = segment.metadata.at("OBJECT_NAME");
    const std::string& id = segment.metadata.at("OBJECT_ID");
    if (name != spacecraft_id && id != spacecraft_id) {
      return KvnLineError(segment.metadata_lines.at("OBJECT_NAME"), "OBJECT_NAME",
                       absl::StrCat("'", absl::CHexEscape(name), "' (OBJECT_ID '",
                                    absl::CHexEscape(id), "') is not spacecraft '",
                                    absl::CHexEscape(spacecraft_id),
                                    "': the plan is of another spacecraft (OBJECT_NAME or "
                                    "OBJECT_ID must be the spacecraft id)"));
    }
    samples.insert(samples.end(), segment.samples.begin(), segment.samples.end());
  }
  return samples;
}

}  // namespace esg::storage
