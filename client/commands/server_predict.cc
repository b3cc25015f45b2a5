// `esg predict --spacecraft ID [--from T] [--to T] [--step S] [--planned FILE] [--aem FILE]
// [--format table|json|csv]`: the attitude esgd predicts (PredictAttitudeStream, docs/service.md
// "PredictAttitude", "PredictAttitudeStream"; the table and the AEM are written as the chunks
// come): per epoch q_in_b (scalar first), its 1-sigma about the body axes x, y, z [arcsec],
// where it comes from ("recorded": the archived gyro readings, up to the last archived frame,
// applied by the filter or not; after it "planned": the --planned attitude, or "inertial hold":
// the attitude held inertially fixed; proto/attitude_source_words.h, the proto names in
// --format json and csv) and the predicted spin axes h_in of the gyros used. The table marks the
// switch of source with a line; the table and stderr state the assumption; --aem also writes
// the returned CCSDS AEM (KVN, docs/formats.md) to FILE.
//
// --planned FILE: a CCSDS AEM (KVN, version 1.0 or 2.0, quaternions; every segment's data lines,
// the file's first keyword CCSDS_AEM_VERS; each segment's OBJECT_NAME or OBJECT_ID the
// --spacecraft, TIME_SYSTEM UTC or TAI) or a CSV with the header `time,q0,q1,q2,q3`: RFC 3339
// UTC time and q_in_b scalar first (body to inertial, Hamilton), one line per sample in
// increasing time.
// Defaults, as an operator asks "where will it point": --from now (the client's clock), --to 6 h
// after --from, --step 60 s.
// Exit codes: 0 success, 2 bad arguments or an unreadable --planned file, 1 server or file
// failure (e.g. FAILED_PRECONDITION when the session's output is not available, OUT_OF_RANGE
// when --to is beyond the prediction horizon).
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "absl/time/clock.h"
#include "client/commands/commands.h"
#include "client/commands/server_common.h"
#include "client/output_format.h"
#include "estimator/rotation.h"
#include "estimator/utc_time.h"
#include "formats/aem.h"
#include "formats/csv_lines.h"
#include "proto/attitude_source_words.h"
#include "proto/convert.h"

namespace esg::client {
namespace {

constexpr char kVerb[] = "predict";
constexpr absl::Duration kDefaultSpan = absl::Hours(6);
constexpr double kDefaultStepS = 60.0;

struct PredictOptions {
  std::string spacecraft_id;
  std::string from;
  std::string to;
  double step_s = kDefaultStepS;
  std::string planned_path;
  std::string aem_path;
  OutputFormat format = OutputFormat::kTable;
};

// The planned attitude of `path` (AEM or CSV, see the file comment) for `spacecraft_id` as
// request samples; InvalidArgument "--planned PATH: line N: ..." otherwise (an AEM of another
// spacecraft or in a time system other than UTC or TAI included: storage::ParseAemPlan).
absl::StatusOr<std::vector<esg::v1::AttitudeSample>> ReadPlanned(const std::string& path,
                                                                 const std::string& spacecraft_id) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("--planned ", path, ": cannot read"));
  std::stringstream buffer;
  buffer << in.rdbuf();
  const std::string text = buffer.str();
  std::vector<esg::v1::AttitudeSample> out;
  auto add = [&out](absl::Time t, const Eigen::Quaterniond& q_in_b) {
    esg::v1::AttitudeSample s;
    *s.mutable_time() = proto_convert::TimeToProto(t);
    for (double v : estimator::ToScalarFirst(q_in_b)) s.add_q_in_b(v);
    out.push_back(std::move(s));
  };
  const absl::string_view start = absl::StripLeadingAsciiWhitespace(text);
  if (absl::StartsWith(start, "CCSDS_AEM_VERS")) {
    absl::StatusOr<std::vector<storage::AemSample>> plan =
        storage::ParseAemPlan(text, spacecraft_id);
    if (!plan.ok()) {
      return absl::InvalidArgumentError(
          absl::StrCat("--planned ", path, ": ", plan.status().message()));
    }
    for (const storage::AemSample& s : *plan) add(s.epoch, s.q_in_b);
    return out;
  }
  // The line reader of the recording CSVs (formats/csv_lines.h): lines numbered as an editor
  // numbers them, blank ones skipped, a byte order mark dropped.
  storage::CsvLines lines(text);
  int line_number = 0;
  absl::string_view raw;
  bool header = true;
  while (lines.Next(&line_number, &raw)) {
    const absl::string_view line = absl::StripAsciiWhitespace(raw);
    const std::vector<std::string> f = absl::StrSplit(line, ',');
    auto error = [&](const std::string& what) {
      return absl::InvalidArgumentError(
          absl::StrCat("--planned ", path, ": line ", line_number, ": ", what));
    };
    if (f.size() != 5) {
      return error(
          absl::StrCat("expected 5 columns time,q0,q1,q2,q3 (CSV) or an AEM starting "
                       "with CCSDS_AEM_VERS, got ",
                       f.size()));
    }
    if (header) {
      header = false;
      std::vector<std::string> names;
      for (const std::string& name : f) {
        names.push_back(absl::AsciiStrToLower(absl::StripAsciiWhitespace(name)));
      }
      if (names != std::vector<std::string>{"time", "q0", "q1", "q2", "q3"}) {
        return error("the header must be time,q0,q1,q2,q3 (q_in_b scalar first)");
      }
      continue;
    }
    const absl::StatusOr<absl::Time> t = estimator::ParseUtc(f[0], "time");
    if (!t.ok()) return error(std::string(t.status().message()));
    estimator::ScalarFirst q;
    for (int i = 0; i < 4; ++i) {
      if (!absl::SimpleAtod(absl::StripAsciiWhitespace(f[i + 1]), &q[i]) || !std::isfinite(q[i])) {
        return error(absl::StrCat("q", i, " '", f[i + 1], "': not a number"));
      }
    }
    add(*t, estimator::QuaternionFromScalarFirst(q));
  }
  if (out.empty()) {
    return absl::InvalidArgumentError(absl::StrCat("--planned ", path, ": no samples"));
  }
  return out;
}

int RunPredict(const PredictOptions& o, const GlobalOptions& global) {
  const std::optional<absl::Time> from =
      o.from.empty() ? absl::Now() : TimeOption(kVerb, "--from", o.from);
  if (!from) return kExitBadArguments;
  const std::optional<absl::Time> to =
      o.to.empty() ? *from + kDefaultSpan : TimeOption(kVerb, "--to", o.to);
  if (!to) return kExitBadArguments;
  if (*to < *from) {
    return ReportBadArgument(kVerb,
                             "--to " + FormatUtc(*to) + ": before --from " + FormatUtc(*from));
  }
  if (!(o.step_s > 0.0) || !std::isfinite(o.step_s)) {
    return ReportBadArgument(kVerb, "--step " + std::to_string(o.step_s) + ": must be > 0 seconds");
  }
  esg::v1::PredictRequest request;
  if (!o.planned_path.empty()) {
    absl::StatusOr<std::vector<esg::v1::AttitudeSample>> planned =
        ReadPlanned(o.planned_path, o.spacecraft_id);
    if (!planned.ok()) return ReportBadArgument(kVerb, std::string(planned.status().message()));
    for (esg::v1::AttitudeSample& s : *planned) *request.add_planned_attitude() = std::move(s);
  }
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;

  request.set_spacecraft_id(o.spacecraft_id);
  *request.mutable_from() = proto_convert::TimeToProto(*from);
  *request.mutable_to() = proto_convert::TimeToProto(*to);
  request.set_step_s(o.step_s);
  request.set_aem(!o.aem_path.empty());

  // PredictAttitudeStream: the table is printed and the AEM written chunk by chunk, as the
  // server computes them; --format json and csv gather the chunks into the PredictResponse the
  // unary PredictAttitude returns (docs/cli.md).
  std::ofstream aem;
  if (!o.aem_path.empty()) {
    aem.open(o.aem_path, std::ios::binary | std::ios::trunc);
    if (!aem) {
      std::fprintf(stderr, "esg %s: --aem %s: cannot write\n", kVerb, o.aem_path.c_str());
      return kExitFailure;
    }
  }
  const bool table = o.format == OutputFormat::kTable;
  esg::v1::PredictResponse response;  // json and csv: the chunks gathered
  response.set_attitude_source(esg::v1::ATTITUDE_SOURCE_RECORDED);
  std::vector<std::string> assumption;
  std::vector<esg::v1::AttitudeSource> sources;  // json and csv: each sample's
  esg::v1::AttitudeSource previous = esg::v1::ATTITUDE_SOURCE_UNSPECIFIED;
  std::string last_archived;
  int count = 0;
  auto stream = client->PredictAttitudeStream(request);
  esg::v1::PredictChunk chunk;
  while (stream->Read(&chunk)) {
    if (count == 0 && chunk.has_last_archived_time()) {
      last_archived = FormatUtc(chunk.last_archived_time(), true);
      response.set_recorded_samples(chunk.recorded_samples());
      *response.mutable_last_applied_time() = chunk.last_applied_time();
      *response.mutable_last_archived_time() = chunk.last_archived_time();
    }
    if (!chunk.assumption().empty()) assumption.push_back(chunk.assumption());
    if (aem.is_open()) aem << chunk.aem_text();
    response.set_attitude_source(chunk.attitude_source());
    if (!table) {
      for (esg::v1::AttitudeSample& s : *chunk.mutable_samples()) {
        *response.add_samples() = std::move(s);
        sources.push_back(chunk.attitude_source());
      }
      count += chunk.samples_size();
      continue;
    }
    if (count == 0) {
      std::printf("%-24s %12s %12s %12s %12s %9s %9s %9s  %-13s %s\n", "time_utc", "q0", "q1", "q2",
                  "q3", "sig_x\"", "sig_y\"", "sig_z\"", "source", "spin axes h_in");
    }
    if (previous != esg::v1::ATTITUDE_SOURCE_UNSPECIFIED && chunk.attitude_source() != previous) {
      // The switch of source at the last archived frame: the 1-sigma carries on from the row
      // above (docs/physics.md "The prediction's envelope").
      std::printf(
          "---- %s, the last archived frame: %s above, %s below; the 1-sigma carries on "
          "----\n",
          last_archived.c_str(), std::string(proto_convert::AttitudeSourceWords(previous)).c_str(),
          std::string(proto_convert::AttitudeSourceWords(chunk.attitude_source())).c_str());
    }
    previous = chunk.attitude_source();
    const std::string words(proto_convert::AttitudeSourceWords(chunk.attitude_source()));
    for (const esg::v1::AttitudeSample& s : chunk.samples()) {
      std::printf("%-24s", FormatUtc(s.time(), s.has_time()).c_str());
      for (int i = 0; i < 4; ++i) std::printf(" %+12.9f", i < s.q_in_b_size() ? s.q_in_b(i) : 0.0);
      for (int i = 0; i < 3; ++i) {
        std::printf(" %9.2f", i < s.sigma_arcsec_size() ? s.sigma_arcsec(i) : 0.0);
      }
      std::printf("  %-13s", words.c_str());
      for (const esg::v1::GyroAxis& axis : s.spin_axes()) {
        std::printf(" g%d[", axis.gyro_id());
        for (int i = 0; i < axis.h_in_size(); ++i) {
          std::printf("%s%+.6f", i ? " " : "", axis.h_in(i));
        }
        std::printf("]");
      }
      std::printf("\n");
    }
    count += chunk.samples_size();
  }
  const absl::Status finished = stream->Finish();
  if (aem.is_open()) aem.close();
  if (!finished.ok()) {
    if (!o.aem_path.empty()) std::remove(o.aem_path.c_str());  // no partial AEM left behind
    return ReportRpcError(kVerb, finished, global);
  }
  if (!o.aem_path.empty() && !aem) {
    std::fprintf(stderr, "esg %s: --aem %s: cannot write\n", kVerb, o.aem_path.c_str());
    return kExitFailure;
  }
  response.set_assumption(absl::StrJoin(assumption, "; "));
  if (o.format == OutputFormat::kJson) {
    Json doc = ProtoToJson(response);
    if (!o.aem_path.empty()) doc["aemFile"] = o.aem_path;
    PrintJson(doc);
    return kExitOk;
  }
  if (o.format == OutputFormat::kCsv) {
    std::vector<Json> rows;
    for (int i = 0; i < response.samples_size(); ++i) {
      const esg::v1::AttitudeSample& s = response.samples(i);
      Json row;
      row["time"] = FormatUtc(s.time(), s.has_time());
      for (int k = 0; k < 4; ++k)
        row[absl::StrCat("q", k)] = k < s.q_in_b_size() ? s.q_in_b(k) : 0.0;
      const char* axes[] = {"sigmaXArcsec", "sigmaYArcsec", "sigmaZArcsec"};
      for (int k = 0; k < 3; ++k) {
        row[axes[k]] = k < s.sigma_arcsec_size() ? s.sigma_arcsec(k) : 0.0;
      }
      row["attitudeSource"] = esg::v1::AttitudeSource_Name(sources[i]);
      rows.push_back(std::move(row));
    }
    PrintCsv(rows, {"time", "q0", "q1", "q2", "q3", "sigmaXArcsec", "sigmaYArcsec", "sigmaZArcsec",
                    "attitudeSource"});
    std::fprintf(stderr, "esg %s: %s\n", kVerb, response.assumption().c_str());
    return kExitOk;
  }
  std::printf("%d samples", count);
  if (!o.aem_path.empty()) std::printf("; AEM written to %s", o.aem_path.c_str());
  // The service states the assumption with the sources in words, as the table names them.
  std::printf("\nassumption: %s\n", response.assumption().c_str());
  return kExitOk;
}

}  // namespace

void RegisterPredict(CLI::App& app, GlobalOptions& global, int* exit_code) {
  auto options = std::make_shared<PredictOptions>();
  CLI::App* cmd = app.add_subcommand(
      kVerb,
      "attitude with its 1-sigma over an interval (PredictAttitudeStream): recorded gyro readings "
      "up to the last archived frame, then the --planned attitude or, without one, an inertial "
      "hold");
  cmd->add_option("--spacecraft", options->spacecraft_id, "spacecraft id")->required();
  cmd->add_option("--from", options->from, "first epoch, RFC 3339 UTC (default: now)");
  cmd->add_option("--to", options->to, "last epoch, RFC 3339 UTC (default: 6 h after --from)");
  cmd->add_option("--step", options->step_s, "step between epochs [s] (default: 60)");
  cmd->add_option("--planned", options->planned_path,
                  "planned attitude after the last archived frame: a CCSDS AEM (KVN) or a CSV "
                  "with the header time,q0,q1,q2,q3 (RFC 3339 UTC, q_in_b scalar first)");
  cmd->add_option("--aem", options->aem_path,
                  "also write the prediction as a CCSDS AEM (KVN) file");
  AddFormatOption(cmd, &options->format);
  cmd->callback([options, &global, exit_code] { *exit_code = RunPredict(*options, global); });
}

}  // namespace esg::client
