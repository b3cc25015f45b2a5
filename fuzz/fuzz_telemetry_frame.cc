// Fuzz target: telemetry frame conversion and validation (proto_convert::FrameFromProto), on
// esg.v1.TelemetryFrame messages in the protobuf wire form as a station sends them.
// Property: a frame is refused with InvalidArgument "<field>: <reason>", or converted to a frame
// whose gyro ids are 1..4, spin axes unit and finite, voltages finite, a valid star-tracker
// quaternion unit and finite; FrameToProto then FrameFromProto gives the same frame bit for bit.
#include <cstddef>
#include <cstdint>
#include <string>

#include "esg/v1/telemetry.pb.h"
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
  v1::TelemetryFrame proto;
  if (!proto.ParseFromArray(data, static_cast<int>(size))) return 0;  // not a message at all
  absl::StatusOr<estimator::TelemetryFrame> frame = proto_convert::FrameFromProto(proto);
  if (!frame.ok()) {
    fuzz::CheckCleanError(frame.status(), absl::StatusCode::kInvalidArgument);
    ESG_FUZZ_CHECK(frame.status().message().find(": ") != absl::string_view::npos,
                   frame.status().ToString());
    return 0;
  }
  estimator::Recording one;
  one.frames.push_back(*frame);
  fuzz::CheckRecordingInvariants(one);
  const v1::TelemetryFrame again =
      proto_convert::FrameToProto(*frame, proto.spacecraft_id(), proto.sequence());
  absl::StatusOr<estimator::TelemetryFrame> back = proto_convert::FrameFromProto(again);
  ESG_FUZZ_CHECK(back.ok(), back.status().ToString());
  estimator::Recording other;
  other.frames.push_back(*back);
  ESG_FUZZ_CHECK(fuzz::SameFrames(one, other), again.DebugString());
  ESG_FUZZ_CHECK(again.spacecraft_id() == proto.spacecraft_id(), "spacecraft id kept");
  ESG_FUZZ_CHECK(again.sequence() == proto.sequence(), "sequence kept");
  return 0;
}
