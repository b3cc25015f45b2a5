// Fuzz target: the configuration JSON, its proto conversion and its validation
// (proto_convert::ParseConfigJson = protobuf's JSON parser, ConfigFromProto, ValidateConfig).
// Property: any text is refused with InvalidArgument, or gives a configuration that passes
// ValidateConfig and whose written JSON (ConfigToJson) reads back to a configuration written
// identically (the written text is a fixed point), through the proto form as well.
#include <cstddef>
#include <cstdint>
#include <string>

#include "estimator/spacecraft_config.h"
#include "fuzz/fuzz_util.h"
#include "google/protobuf/stubs/logging.h"
#include "proto/convert.h"

// Quiet protobuf's log lines (e.g. on invalid UTF-8 in a string field): the status says it.
extern "C" int LLVMFuzzerInitialize(int*, char***) {
  google::protobuf::SetLogHandler(nullptr);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace esg;
  absl::StatusOr<estimator::SpacecraftConfig> config =
      proto_convert::ParseConfigJson(fuzz::AsText(data, size));
  if (!config.ok()) {
    fuzz::CheckCleanError(config.status(), absl::StatusCode::kInvalidArgument);
    return 0;
  }
  const absl::Status valid = estimator::ValidateConfig(*config);
  ESG_FUZZ_CHECK(valid.ok(), valid.ToString());
  const std::string json = proto_convert::ConfigToJson(*config);
  ESG_FUZZ_CHECK(!json.empty(), "ConfigToJson printed nothing");
  absl::StatusOr<estimator::SpacecraftConfig> back = proto_convert::ParseConfigJson(json);
  ESG_FUZZ_CHECK(back.ok(), back.status().ToString() + "\n" + json);
  ESG_FUZZ_CHECK(proto_convert::ConfigToJson(*back) == json, json);
  absl::StatusOr<estimator::SpacecraftConfig> from_proto =
      proto_convert::ConfigFromProto(proto_convert::ConfigToProto(*back));
  ESG_FUZZ_CHECK(from_proto.ok(), from_proto.status().ToString());
  ESG_FUZZ_CHECK(proto_convert::ConfigToJson(*from_proto) == json, json);
  return 0;
}
