// `esg orbit upload|list` (UploadOrbit, ListOrbits; docs/cli.md "esg orbit"): the spacecraft's
// orbit deliveries on esgd, which its diagnoses take the sun's shadow from.
#include <cstdio>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/commands/commands.h"
#include "client/commands/server_common.h"
#include "client/esg_client.h"
#include "client/output_format.h"

namespace esg::client {
namespace {

struct OrbitOptions {
  std::string spacecraft_id;
  std::string oem_path;
  OutputFormat format = OutputFormat::kTable;
};

std::string DeliveryLine(const esg::v1::OrbitDelivery& d) {
  return absl::StrFormat("#%d  %s to %s  %d states  uploaded %s%s", d.id(), FormatUtc(d.from()),
                         FormatUtc(d.to()), d.states(), FormatUtc(d.upload_time()),
                         d.uploaded_by().empty() ? "" : absl::StrCat(" by ", d.uploaded_by()));
}

void PrintDeliveries(const std::vector<esg::v1::OrbitDelivery>& deliveries, OutputFormat format) {
  if (format == OutputFormat::kJson) {
    Json all = Json::array();
    for (const auto& d : deliveries) all.push_back(ProtoToJson(d));
    PrintJson(all);
    return;
  }
  if (format == OutputFormat::kCsv) {
    std::vector<Json> rows;
    for (const auto& d : deliveries) rows.push_back(ProtoToJson(d));
    PrintCsv(rows, ProtoCsvColumns(*esg::v1::OrbitDelivery::descriptor()));
    return;
  }
  for (const auto& d : deliveries) std::printf("%s\n", DeliveryLine(d).c_str());
}

int RunUpload(const OrbitOptions& o, const GlobalOptions& global) {
  constexpr char kVerb[] = "orbit upload";
  std::ifstream in(o.oem_path, std::ios::binary);
  if (!in) return ReportBadArgument(kVerb, absl::StrCat("--oem ", o.oem_path, ": cannot read"));
  std::ostringstream text;
  text << in.rdbuf();
  if (text.str().empty()) {
    return ReportBadArgument(kVerb, absl::StrCat("--oem ", o.oem_path, ": empty file"));
  }
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  esg::v1::UploadOrbitRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  request.set_oem(text.str());
  absl::StatusOr<esg::v1::OrbitDelivery> r = client->UploadOrbit(request);
  if (!r.ok()) return ReportRpcError(kVerb, r.status(), global);
  if (o.format == OutputFormat::kTable) {
    std::printf("stored orbit delivery %s\n", DeliveryLine(*r).c_str());
  } else {
    PrintDeliveries({*r}, o.format);
  }
  return kExitOk;
}

int RunList(const OrbitOptions& o, const GlobalOptions& global) {
  constexpr char kVerb[] = "orbit list";
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  esg::v1::ListOrbitsRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  absl::StatusOr<esg::v1::ListOrbitsResponse> r = client->ListOrbits(request);
  if (!r.ok()) return ReportRpcError(kVerb, r.status(), global);
  const std::vector<esg::v1::OrbitDelivery> deliveries(r->deliveries().begin(),
                                                       r->deliveries().end());
  PrintDeliveries(deliveries, o.format);
  if (o.format == OutputFormat::kTable) {
    std::printf("%zu orbit deliveries of %s (a later upload is used where they overlap)\n",
                deliveries.size(), o.spacecraft_id.c_str());
  }
  return kExitOk;
}

}  // namespace

void RegisterOrbit(CLI::App& app, GlobalOptions& global, int* exit_code) {
  CLI::App* cmd = app.add_subcommand(
      "orbit", "a spacecraft's orbit deliveries on esgd, for its diagnoses (UploadOrbit, ListOrbits)");
  cmd->require_subcommand(1);
  cmd->fallthrough();

  auto upload = std::make_shared<OrbitOptions>();
  CLI::App* upload_cmd = cmd->add_subcommand(
      "upload", "store a CCSDS OEM (KVN) of the spacecraft's orbit (write role)");
  upload_cmd->add_option("--spacecraft", upload->spacecraft_id, "spacecraft id")->required();
  upload_cmd->add_option("--oem", upload->oem_path, "the OEM file (docs/formats.md)")->required();
  AddFormatOption(upload_cmd, &upload->format);
  upload_cmd->callback([upload, &global, exit_code] { *exit_code = RunUpload(*upload, global); });

  auto list = std::make_shared<OrbitOptions>();
  CLI::App* list_cmd =
      cmd->add_subcommand("list", "the spacecraft's stored orbit deliveries, in upload order");
  list_cmd->add_option("--spacecraft", list->spacecraft_id, "spacecraft id")->required();
  AddFormatOption(list_cmd, &list->format);
  list_cmd->callback([list, &global, exit_code] { *exit_code = RunList(*list, global); });
}

}  // namespace esg::client
