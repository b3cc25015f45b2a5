// Fuzz target: the recording CSV reader (formats/recording_csv.h).
// Property: any text is either refused with InvalidArgument, or gives a recording that satisfies
// the reader's rules (times strictly increasing, unit spin axes and valid quaternions, finite
// values) and that FormatRecordingCsv writes so that it reads back bit for bit (write then read
// is the identity; the metadata as the writer documents writing them), the written text itself
// being a fixed point.
#include <cstddef>
#include <cstdint>
#include <map>
#include <string>

#include "absl/strings/ascii.h"
#include "formats/recording_csv.h"
#include "fuzz/fuzz_util.h"
#include "fuzz/recording_round_trip.h"

namespace {

// Metadata as FormatRecordingCsv documents writing them: the format always stated, line breaks
// inside keys and values written as spaces, ':' in keys as '_', trimmed; of keys that clean to
// the same key, the first in key order kept.
std::map<std::string, std::string> AsWritten(const std::map<std::string, std::string>& metadata) {
  auto clean = [](std::string s, bool is_key) {
    for (char& c : s) {
      if (c == '\n' || c == '\r') c = ' ';
      if (is_key && c == ':') c = '_';
    }
    return std::string(absl::StripAsciiWhitespace(s));
  };
  std::map<std::string, std::string> out;
  for (const auto& [key, value] : metadata) out.emplace(clean(key, true), clean(value, false));
  out.erase("");
  out["format"] = esg::storage::kRecordingCsvFormat;
  return out;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace esg;
  absl::StatusOr<estimator::Recording> recording =
      storage::ParseRecordingCsv(fuzz::AsText(data, size));
  if (!recording.ok()) {
    fuzz::CheckCleanError(recording.status(), absl::StatusCode::kInvalidArgument);
    return 0;
  }
  const fuzz::WrittenRecording written = fuzz::CheckRecordingRoundTrip(*recording);
  ESG_FUZZ_CHECK(AsWritten(recording->metadata) == written.back.metadata, written.text);
  ESG_FUZZ_CHECK(storage::FormatRecordingCsv(written.back) == written.text, written.text);
  return 0;
}
