// Writes the generated seeds of the fuzz targets into <out>/<target>/ (docs/fuzzing.md): a
// simulated flight of deploy/examples/rdk1.json as a recording CSV, as a user's export read
// through deploy/examples/columns_user_export.json, as telemetry frames in the protobuf wire
// form, as an AEM, and the session's server checkpoints at several points of the flight (before
// the first frame, before initialisation, converged) in every session version (1 to 10) and every
// server format (3 as written, 2 and 1 as read). Some frames carry housekeeping channels, and a
// configuration declares them. Usage: fuzz_make_seeds <out dir>. The
// hand-written seeds live beside them.
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <fstream>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/calibration_model.h"
#include "estimator/orbit.h"
#include "estimator/rotation.h"
#include "estimator/session.h"
#include "estimator/simulator.h"
#include "formats/aem.h"
#include "formats/oem.h"
#include "formats/recording_csv.h"
#include "google/protobuf/io/coded_stream.h"
#include "google/protobuf/io/zero_copy_stream_impl_lite.h"
#include "proto/convert.h"
#include "server/checkpoint_codec.h"
#include "tests/testing/checkpoint_versions.h"

namespace {

using namespace esg;

// A message's wire bytes with its map entries in key order: the same seed file on every run
// (the default serialization writes a map in its hash order).
std::string DeterministicBytes(const google::protobuf::MessageLite& message) {
  std::string out;
  {
    google::protobuf::io::StringOutputStream sink(&out);
    google::protobuf::io::CodedOutputStream coded(&sink);
    coded.SetSerializationDeterministic(true);
    message.SerializeToCodedStream(&coded);
  }
  return out;
}

void Write(const std::string& path, const std::string& content) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << content;
  if (!out) {
    std::fprintf(stderr, "cannot write %s\n", path.c_str());
    std::exit(1);
  }
}

std::string Num(double x) { return absl::StrFormat("%.17g", x); }

// The recording as the user export of deploy/examples/columns_user_export.json.
std::string UserExport(const estimator::Recording& recording) {
  std::vector<std::string> header = {"STR_STATUS", "STR_QX", "STR_QY",
                                     "STR_QZ",     "STR_QW", "UNIX_TIME"};
  for (int g = 1; g <= 4; ++g) {
    for (const char* s : {"AZ", "EL", "UX", "UY", "UZ"})
      header.push_back(absl::StrCat("ESG", g, "_", s));
  }
  std::string out = "# exported from the ground segment\n" + absl::StrJoin(header, ";") + "\n";
  for (const estimator::TelemetryFrame& frame : recording.frames) {
    std::vector<std::string> f;
    if (!frame.star_tracker.has_value()) {
      f = {"", "", "", "", ""};
    } else if (!frame.star_tracker->valid) {
      f = {"STALE", "", "", "", ""};
    } else {
      const estimator::ScalarFirst q = estimator::ToScalarFirst(frame.star_tracker->q_in_b);
      f = {"OK", Num(-q[1]), Num(-q[2]), Num(-q[3]), Num(q[0])};  // q_b_in, scalar last
    }
    const int64_t ns = absl::ToUnixNanos(frame.time);
    f.push_back(absl::StrFormat("%d.%09d", ns / 1000000000, ns % 1000000000));
    for (const auto& r : frame.gyros) {
      if (!r.has_value()) {
        for (int i = 0; i < 5; ++i) f.push_back("");
        continue;
      }
      const Eigen::Vector3d& h = r->h_k;
      f.push_back(Num(std::atan2(h.y(), h.x()) * 180.0 / M_PI));
      f.push_back(Num(std::asin(std::clamp(h.z(), -1.0, 1.0)) * 180.0 / M_PI));
      for (int i = 0; i < 3; ++i) f.push_back(r->u_k_mv ? Num((*r->u_k_mv)(i) / 1000.0) : "");
    }
    absl::StrAppend(&out, absl::StrJoin(f, ";"), "\n");
  }
  return out;
}

// The length of session checkpoint values in version 7's layout (tests/testing/
// checkpoint_versions.h AsVersion7) up to and including `version` <= 7 (estimator/
// session_checkpoint.cc): each version appends to the one before.
size_t VersionLength(const std::vector<double>& v, int version) {
  const size_t m = static_cast<size_t>(v.at(22));
  const size_t g = static_cast<size_t>(v.at(23 + m));
  const size_t n = static_cast<size_t>(v.at(23 + m + 1 + 30 * g));
  size_t pos = 23 + m + 1 + 30 * g + 1 + 2 * n * n;  // version 1
  if (version == 1) return pos;
  pos += 3;                                   // anchoring flags
  pos += 1 + static_cast<size_t>(v.at(pos));  // consistency monitor
  if (version == 2) return pos;
  pos += 1 + static_cast<size_t>(v.at(pos));  // widening
  pos += 1 + 3;                               // suspect gyro and time
  if (version == 3) return pos;
  pos += 1 + 3 + 1;                           // latency, rate, interval
  pos += 1 + static_cast<size_t>(v.at(pos));  // change detector
  if (version == 4) return pos;
  pos += 9 + 1;                               // mount correction
  pos += 1 + static_cast<size_t>(v.at(pos));  // mount monitor
  if (version == 5) return pos;
  for (size_t i = 0; i < g; ++i) {
    pos += 1 + static_cast<size_t>(v.at(pos));  // basis terms
    pos += 1 + 3;                               // held voltages
  }
  if (version == 6) return pos;
  return v.size();  // version 7: exclusions, reading-fault monitor, motion (the rest)
}

// Server format 1 ("ESGSRV01"): model, counters, alert tracks, session (no apply cursor).
std::string EncodeFormat1(const server::ServerCheckpoint& c) {
  std::string out = "ESGSRV01";
  auto i64 = [&](int64_t v) { out.append(reinterpret_cast<const char*>(&v), sizeof v); };
  auto str = [&](const std::string& s) {
    i64(static_cast<int64_t>(s.size()));
    out += s;
  };
  str(c.model);
  i64(c.frames_applied);
  i64(c.frames_apply_failed);
  i64(c.star_tracker_rejections);
  i64(0);  // alert tracks
  i64(c.session.has_value() ? 1 : 0);
  if (c.session.has_value()) {
    i64(c.session->version);
    i64(static_cast<int64_t>(c.session->values.size()));
    for (double v : c.session->values) out.append(reinterpret_cast<const char*>(&v), sizeof v);
  }
  return out;
}

// Server format 2 ("ESGSRV02"): format 3 without the last star-tracker time, the 8 bytes after
// the apply cursor (server/checkpoint_codec.cc).
std::string EncodeFormat2(const server::ServerCheckpoint& c) {
  std::string out = server::EncodeCheckpoint(c);
  out.replace(0, 8, "ESGSRV02");
  const size_t cursor_end = 8 + (8 + c.model.size()) + 8 + (8 + c.applied_station.size()) + 8 +
                            8 + (8 + c.quarantine_reason.size()) + 8;
  out.erase(cursor_end, 8);
  return out;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc != 2) {
    std::fprintf(stderr, "usage: %s <corpus dir>\n", argv[0]);
    return 2;
  }
  const std::string out = argv[1];
  absl::StatusOr<estimator::SpacecraftConfig> config =
      proto_convert::ReadConfigFile(ESG_SOURCE_DIR "/deploy/examples/rdk1.json");
  if (!config.ok()) {
    std::fprintf(stderr, "%s\n", config.status().ToString().c_str());
    return 1;
  }
  estimator::SimulationSpec spec;
  spec.config = *config;
  spec.duration = 3 * 3600.0;
  spec.seed = 7;
  spec.profile = *estimator::MakeNamedProfile("calibration", spec.duration, 7);
  absl::StatusOr<estimator::SimulationResult> sim = estimator::Simulate(spec);
  if (!sim.ok()) {
    std::fprintf(stderr, "%s\n", sim.status().ToString().c_str());
    return 1;
  }
  std::vector<estimator::TelemetryFrame>& frames = sim->recording.frames;
  for (int i = 0; i < 3; ++i) frames[i].star_tracker.reset();  // no star tracker yet
  frames[5].star_tracker->valid = false;                       // an invalid reading
  frames[6].gyros[3].reset();                                  // a gyro's reading missing
  frames[7].gyros[1]->u_k_mv.reset();                          // voltages not telemetered
  // Housekeeping channels (docs/formats.md "Channels"): a temperature every third frame, a
  // heater state in most, none in frame 8.
  for (int i = 0; i < 8; ++i) {
    if (i % 3 == 0) frames[i].channels.Set("T_gyro2", 290.0 + 0.25 * i);
    if (i != 4) frames[i].channels.Set("heater_1", i % 2);
  }

  // Recording CSV and the user's export, a few frames each.
  estimator::Recording small;
  small.metadata = sim->recording.metadata;
  small.frames.assign(frames.begin(), frames.begin() + 9);
  const std::string csv = storage::FormatRecordingCsv(small);
  Write(out + "/recording_csv/simulated.csv", csv);
  std::ifstream esg_mapping(ESG_SOURCE_DIR "/deploy/examples/columns_esg_recording.json");
  std::ifstream user_mapping(ESG_SOURCE_DIR "/deploy/examples/columns_user_export.json");
  const std::string esg_json((std::istreambuf_iterator<char>(esg_mapping)), {});
  const std::string user_json((std::istreambuf_iterator<char>(user_mapping)), {});
  Write(out + "/column_mapping/esg_recording.txt", esg_json + "\n%%\n" + csv);
  Write(out + "/column_mapping/user_export.txt", user_json + "\n%%\n" + UserExport(small));
  // The project's mapping with the channel columns mapped as well.
  std::string channels_json = esg_json;
  if (const size_t end = channels_json.rfind('}'); end != std::string::npos) {
    channels_json.insert(end,
                         ",\n  \"channels\": [\n"
                         "    {\"name\": \"T_gyro2\", \"column\": \"ch:T_gyro2\"},\n"
                         "    {\"name\": \"heater_1\", \"column\": \"ch:heater_1\"}]\n");
  }
  Write(out + "/column_mapping/esg_recording_channels.txt", channels_json + "\n%%\n" + csv);

  // Telemetry frames in the protobuf wire form.
  for (int i = 0; i < 9; ++i) {
    Write(absl::StrCat(out, "/telemetry_frame/frame", i, ".pb"),
          DeterministicBytes(proto_convert::FrameToProto(frames[i], "RDK-1", i + 1)));
  }

  // The configuration as ConfigToJson writes it.
  Write(out + "/config_json/rdk1_written.json", proto_convert::ConfigToJson(*config));
  estimator::SpacecraftConfig with_channels = *config;
  estimator::ChannelConfig temperature;
  temperature.name = "T_gyro2";
  temperature.unit = "K";
  temperature.valid_min = 250.0;
  temperature.valid_max = 350.0;
  temperature.max_age = absl::Minutes(10);
  estimator::ChannelConfig heater;
  heater.name = "heater_1";
  heater.unit = "1";
  heater.valid_max = 1.0;
  with_channels.channels = {temperature, heater};
  Write(out + "/config_json/rdk1_channels.json", proto_convert::ConfigToJson(with_channels));

  // An AEM of the true attitude: two segments, sigmas in the first.
  storage::AemHeader header;
  header.object_name = "RDK-1";
  header.object_id = "2019-001A";
  header.creation_date = absl::FromUnixSeconds(1551398400);
  header.comments = {"seed of the AEM fuzz target"};
  header.message_id = "SEED-1";
  std::vector<storage::AemBlock> blocks(2);
  blocks[0].interpolation_method = "LINEAR";
  blocks[0].interpolation_degree = 1;
  for (int i = 0; i < 6; ++i) {
    storage::AemSample s{sim->truth[i].time, sim->truth[i].q_in_b, std::nullopt};
    if (i < 3) s.sigma_arcsec = Eigen::Vector3d(1.5, 2.5, 12.0);
    blocks[i < 3 ? 0 : 1].samples.push_back(s);
  }
  absl::StatusOr<std::string> aem = storage::WriteAemBlocks(header, blocks);
  if (!aem.ok()) {
    std::fprintf(stderr, "%s\n", aem.status().ToString().c_str());
    return 1;
  }
  Write(out + "/aem/two_segments.aem", *aem);

  // An OEM of a circular 94.6 min orbit over the first two hours, states every 60 s.
  std::vector<estimator::OrbitState> states;
  for (int i = 0; i <= 120; ++i) {
    states.push_back(estimator::CircularOrbitState(estimator::DegToRad(51.6),
                                                   estimator::DegToRad(340.0), 94.6 * 60.0, 0.0,
                                                   absl::FromUnixSeconds(1551398400), 60.0 * i));
  }
  storage::OemHeader oem_header;
  oem_header.object_name = "RDK-1";
  oem_header.object_id = "2019-001A";
  oem_header.creation_date = absl::FromUnixSeconds(1551398400);
  oem_header.comments = {"seed of the OEM fuzz target"};
  absl::StatusOr<std::string> oem = storage::WriteOem(oem_header, states);
  if (!oem.ok()) {
    std::fprintf(stderr, "%s\n", oem.status().ToString().c_str());
    return 1;
  }
  Write(out + "/oem/circular.oem", *oem);

  // Server checkpoints along the flight, every session version.
  estimator::SessionOptions options;
  options.model = *estimator::ParseModel("10+11");
  absl::StatusOr<estimator::EstimationSession> session =
      estimator::EstimationSession::Create(*config, options);
  if (!session.ok()) {
    std::fprintf(stderr, "%s\n", session.status().ToString().c_str());
    return 1;
  }
  const std::vector<size_t> cuts = {0, 2, 4, 30, frames.size()};
  size_t applied = 0;
  for (size_t cut : cuts) {
    for (; applied < cut; ++applied) {
      if (!session->AddFrame(frames[applied]).ok()) {
        std::fprintf(stderr, "frame %zu not applied\n", applied);
        return 1;
      }
    }
    const estimator::SessionCheckpoint full = session->ExportCheckpoint();
    const std::vector<double> version7_layout = esg::testing::AsVersion7(full).values;
    const std::vector<double> version8_layout = esg::testing::AsVersion8(full).values;
    for (int version = 1; version <= 10; ++version) {
      server::ServerCheckpoint c;
      c.model = "10+11";
      c.applied_time = applied > 0 ? frames[applied - 1].time : absl::InfinitePast();
      c.applied_station = "default";
      c.applied_sequence = static_cast<int64_t>(applied);
      c.frames_applied = static_cast<int64_t>(applied);
      c.session = full;
      c.session->version = version;
      if (version <= 7) {
        c.session->values = version7_layout;
        c.session->values.resize(VersionLength(version7_layout, version));
      } else if (version <= 9) {
        // Version 9 without channel terms: version 8 and an empty channels' block.
        c.session->values = version8_layout;
        if (version == 9) c.session->values.push_back(0.0);
      }
      if (!estimator::EstimationSession::FromCheckpoint(*config, options, *c.session).ok()) {
        std::fprintf(stderr, "cut %zu version %d does not restore\n", cut, version);
        return 1;
      }
      if (cut == frames.size()) {
        c.alert_tracks.push_back({"FILTER_WIDENED", "filter", 3, 2, frames.back().time});
      }
      Write(absl::StrCat(out, "/checkpoint/frames", cut, "_v", version, ".bin"),
            server::EncodeCheckpoint(c));
      if (version == 5) {
        Write(absl::StrCat(out, "/checkpoint/format2_frames", cut, "_v5.bin"), EncodeFormat2(c));
      }
      if (version == 5 && cut == 4) {
        Write(out + "/checkpoint/format1_frames4_v5.bin", EncodeFormat1(c));
        c.quarantine_reason = "its checkpoint cannot be restored";
        c.rebuilding = true;
        c.session.reset();
        Write(out + "/checkpoint/quarantined_no_session.bin", server::EncodeCheckpoint(c));
      }
    }
  }
  std::printf("seeds written to %s\n", out.c_str());
  return 0;
}
