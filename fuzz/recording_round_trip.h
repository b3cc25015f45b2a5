// The property both CSV readers' fuzz targets check of a recording they accepted
// (docs/fuzzing.md): it satisfies the reader's rules (fuzz_util.h CheckRecordingInvariants), and
// the project's recording CSV writes it so that it reads back bit for bit.
#ifndef ESG_FUZZ_RECORDING_ROUND_TRIP_H_
#define ESG_FUZZ_RECORDING_ROUND_TRIP_H_

#include <string>

#include "absl/status/statusor.h"
#include "estimator/telemetry.h"
#include "formats/recording_csv.h"
#include "fuzz/fuzz_util.h"

namespace esg::fuzz {

struct WrittenRecording {
  std::string text;           // FormatRecordingCsv of the accepted recording
  estimator::Recording back;  // that text read back
};

// Checks `recording` and its write-then-read round trip; returns what was written and read back.
inline WrittenRecording CheckRecordingRoundTrip(const estimator::Recording& recording) {
  CheckRecordingInvariants(recording);
  WrittenRecording out;
  out.text = storage::FormatRecordingCsv(recording);
  absl::StatusOr<estimator::Recording> back = storage::ParseRecordingCsv(out.text);
  ESG_FUZZ_CHECK(back.ok(), back.status().ToString());
  ESG_FUZZ_CHECK(SameFrames(recording, *back), out.text);
  out.back = *std::move(back);
  return out;
}

}  // namespace esg::fuzz

#endif  // ESG_FUZZ_RECORDING_ROUND_TRIP_H_
