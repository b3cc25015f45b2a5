// `esg estimates --spacecraft ID [--from T] [--to T] [--format table|json|csv | --csv | --json]`:
// the per-step estimates stored by the service (GetEstimateHistory, every page followed;
// docs/service.md "Per-step estimates"): per measurement step the session state, the attitude
// q_in_b (scalar first, q0 >= 0) with its 1-sigma about the body axes [arcsec], the output pair,
// whether the star tracker was applied with the largest normalised innovation of eq. (14), the
// attitude error estimate of the step's star-tracker update (the correction it applied, about the
// body axes) with its 1-sigma [arcsec], and the star-tracker innovations of each gyro (z2..z5 of
// eq. (13), in the gyro's basis) with their 1-sigma [arcsec].
// Output: a table, or with --format csv (short form --csv) one row per step with every value
// (columns in CsvHeader; the attitude error empty at a step without a star-tracker update, the
// innovations by gyro id 1..4, empty where none was formed), or with --format json (--json) the
// EstimateHistoryResponse in the proto JSON mapping.
// Exit codes: 0 success, 2 bad arguments, 1 server failure.
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "client/commands/commands.h"
#include "client/commands/server_common.h"
#include "client/output_format.h"
#include "proto/convert.h"

namespace esg::client {
namespace {

constexpr char kVerb[] = "estimates";
constexpr int kMaxGyroId = 4;

struct EstimatesOptions {
  std::string spacecraft_id;
  std::string from;
  std::string to;
  bool csv = false;  // short form of --format csv
  OutputFormat format = OutputFormat::kTable;
};

std::vector<std::string> CsvHeader() {
  std::vector<std::string> header = {"time_utc",
                                     "state",
                                     "attitude_valid",
                                     "q0",
                                     "q1",
                                     "q2",
                                     "q3",
                                     "sigma_x_arcsec",
                                     "sigma_y_arcsec",
                                     "sigma_z_arcsec",
                                     "reference_gyro",
                                     "second_gyro",
                                     "star_tracker_used",
                                     "star_tracker_test_ratio",
                                     "last_star_tracker_time_utc",
                                     "attitude_error_x_arcsec",
                                     "attitude_error_y_arcsec",
                                     "attitude_error_z_arcsec",
                                     "attitude_error_sigma_x_arcsec",
                                     "attitude_error_sigma_y_arcsec",
                                     "attitude_error_sigma_z_arcsec"};
  for (int id = 1; id <= kMaxGyroId; ++id) {
    for (const char* column :
         {"innovation_1_arcsec", "innovation_2_arcsec", "sigma_1_arcsec", "sigma_2_arcsec"}) {
      header.push_back(absl::StrCat("g", id, "_", column));
    }
  }
  header.push_back("attitude_invalid_reason");
  header.push_back("compute_time_utc");
  return header;
}

double At(const google::protobuf::RepeatedField<double>& v, int i) {
  return i < v.size() ? v[i] : 0.0;
}

// Every value with 17 significant digits: a row reads back the doubles the service sent.
std::string CsvRecord(const esg::v1::EstimateRecord& e) {
  std::vector<std::string> cells = {FormatUtc(e.measurement_time(), e.has_measurement_time()),
                                    StateName(e.state()), e.has_attitude() ? "true" : "false"};
  const esg::v1::AttitudeSample& a = e.attitude();
  for (int i = 0; i < 4; ++i) {
    cells.push_back(e.has_attitude() ? absl::StrFormat("%.17g", At(a.q_in_b(), i)) : "");
  }
  for (int i = 0; i < 3; ++i) {
    cells.push_back(e.has_attitude() ? absl::StrFormat("%.17g", At(a.sigma_arcsec(), i)) : "");
  }
  for (int i = 0; i < 2; ++i) {
    cells.push_back(i < e.output_pair_size() ? absl::StrCat(e.output_pair(i)) : "");
  }
  cells.push_back(e.star_tracker_used() ? "true" : "false");
  cells.push_back(absl::StrFormat("%.17g", e.star_tracker_test_ratio()));
  cells.push_back(e.has_last_star_tracker_time() ? FormatUtc(e.last_star_tracker_time()) : "");
  const bool has_error = e.attitude_error_b_arcsec_size() == 3;
  for (const auto* values : {&e.attitude_error_b_arcsec(), &e.attitude_error_sigma_b_arcsec()}) {
    for (int i = 0; i < 3; ++i) {
      cells.push_back(has_error ? absl::StrFormat("%.17g", At(*values, i)) : "");
    }
  }
  for (int id = 1; id <= kMaxGyroId; ++id) {
    const esg::v1::GyroInnovation* found = nullptr;
    for (const esg::v1::GyroInnovation& g : e.star_tracker_innovations()) {
      if (g.gyro_id() == id) found = &g;
    }
    for (int i = 0; i < 2; ++i) {
      cells.push_back(found ? absl::StrFormat("%.17g", At(found->innovation_arcsec(), i)) : "");
    }
    for (int i = 0; i < 2; ++i) {
      cells.push_back(found ? absl::StrFormat("%.17g", At(found->sigma_arcsec(), i)) : "");
    }
  }
  cells.push_back(e.attitude_invalid_reason());
  cells.push_back(FormatUtc(e.compute_time(), e.has_compute_time()));
  return CsvLine(cells);
}

void PrintTable(const esg::v1::EstimateHistoryResponse& history) {
  std::printf("%-24s %-12s %-44s %-26s %-5s %-3s %7s  %-26s %-26s %s\n", "time_utc", "state",
              "q_in_b (q0, q1, q2, q3)", "1-sigma x,y,z [arcsec]", "pair", "st", "ratio",
              "att. error x,y,z [arcsec]", "its 1-sigma x,y,z [arcsec]",
              "innovations [arcsec] gyro: z1 z2");
  for (const esg::v1::EstimateRecord& e : history.estimates()) {
    std::string attitude = "-";
    std::string sigma = e.attitude_invalid_reason();
    std::string pair = "-";
    if (e.has_attitude()) {
      const esg::v1::AttitudeSample& a = e.attitude();
      attitude = absl::StrFormat("%+.8f %+.8f %+.8f %+.8f", At(a.q_in_b(), 0), At(a.q_in_b(), 1),
                                 At(a.q_in_b(), 2), At(a.q_in_b(), 3));
      sigma = absl::StrFormat("%7.2f %7.2f %7.2f", At(a.sigma_arcsec(), 0), At(a.sigma_arcsec(), 1),
                              At(a.sigma_arcsec(), 2));
      pair = absl::StrJoin(e.output_pair(), ",");
    }
    std::string error = "-", error_sigma = "-";
    if (e.attitude_error_b_arcsec_size() == 3) {
      const auto& v = e.attitude_error_b_arcsec();
      const auto& s = e.attitude_error_sigma_b_arcsec();
      error = absl::StrFormat("%+7.2f %+7.2f %+7.2f", At(v, 0), At(v, 1), At(v, 2));
      error_sigma = absl::StrFormat("%7.2f %7.2f %7.2f", At(s, 0), At(s, 1), At(s, 2));
    }
    std::string innovations;
    for (const esg::v1::GyroInnovation& g : e.star_tracker_innovations()) {
      absl::StrAppend(&innovations, innovations.empty() ? "" : "  ",
                      absl::StrFormat("%d: %+.2f %+.2f", g.gyro_id(), At(g.innovation_arcsec(), 0),
                                      At(g.innovation_arcsec(), 1)));
    }
    std::printf("%-24s %-12s %-44s %-26s %-5s %-3s %7.3f  %-26s %-26s %s\n",
                FormatUtc(e.measurement_time(), e.has_measurement_time()).c_str(),
                StateName(e.state()).c_str(), attitude.c_str(), sigma.c_str(), pair.c_str(),
                e.star_tracker_used() ? "yes" : "no", e.star_tracker_test_ratio(), error.c_str(),
                error_sigma.c_str(), innovations.c_str());
  }
  std::printf("%d estimates (q_in_b scalar first; --csv adds the innovations' 1-sigma)\n",
              history.estimates_size());
}

int RunEstimates(const EstimatesOptions& o, const GlobalOptions& global) {
  const std::optional<OutputFormat> format = FormatWithCsvFlag(kVerb, o.csv, o.format);
  if (!format) return kExitBadArguments;
  esg::v1::EstimateHistoryRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  esg::v1::EstimateHistoryResponse history;
  if (int code = FetchHistory(kVerb, global, o.from, o.to, request, &EsgClient::GetEstimateHistory,
                              &history);
      code != kExitOk) {
    return code;
  }

  if (*format == OutputFormat::kCsv) {
    std::string text = CsvLine(CsvHeader()) + "\n";
    for (const esg::v1::EstimateRecord& e : history.estimates()) {
      absl::StrAppend(&text, CsvRecord(e), "\n");
    }
    std::fputs(text.c_str(), stdout);
  } else if (*format == OutputFormat::kJson) {
    PrintJson(ProtoToJson(history));
  } else {
    PrintTable(history);
  }
  return kExitOk;
}

}  // namespace

void RegisterEstimates(CLI::App& app, GlobalOptions& global, int* exit_code) {
  auto options = std::make_shared<EstimatesOptions>();
  CLI::App* cmd = app.add_subcommand(
      kVerb,
      "stored per-step estimates of a spacecraft: attitude with its 1-sigma, output pair, "
      "attitude error estimate of each star-tracker update with its 1-sigma, star-tracker "
      "innovations per gyro (GetEstimateHistory)");
  cmd->add_option("--spacecraft", options->spacecraft_id, "spacecraft id")->required();
  cmd->add_option("--from", options->from, "first measurement time, RFC 3339 UTC");
  cmd->add_option("--to", options->to, "last measurement time, RFC 3339 UTC (inclusive)");
  AddFormatOption(cmd, &options->format);
  cmd->add_flag("--csv", options->csv,
                "short form of --format csv: one row per step with every value and 1-sigma");
  cmd->callback([options, &global, exit_code] { *exit_code = RunEstimates(*options, global); });
}

}  // namespace esg::client
