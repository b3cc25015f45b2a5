// Fuzz target: the column-mapping reader (formats/column_mapping.h), the mapping JSON and a CSV
// export read through it. Input: the mapping JSON, optionally followed by a line "%%" and the CSV
// text (without that line only the mapping is read).
// Property: a mapping is refused with InvalidArgument or satisfies the mapping rules (a
// delimiter usable between numbers, gyro ids 1..4 once each, 2 or 3 spin-axis columns, 0 or 3
// voltage columns, positive units); a CSV is refused with InvalidArgument or gives a recording that
// satisfies the recording rules and that the project's recording CSV writes and reads back bit for
// bit (so a user's export and `esg export telemetry` hold the same data).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <set>
#include <string>
#include <string_view>

#include "absl/strings/ascii.h"
#include "formats/column_mapping.h"
#include "fuzz/fuzz_util.h"
#include "fuzz/recording_round_trip.h"

namespace {

void CheckMapping(const esg::storage::ColumnMapping& m) {
  using esg::estimator::kMaxGyros;
  ESG_FUZZ_CHECK(!absl::ascii_isalnum(m.delimiter) && m.delimiter != ' ' &&
                     std::string_view(".+-\"#").find(m.delimiter) == std::string_view::npos,
                 "a delimiter usable between numbers");
  std::set<int> ids;
  for (const esg::storage::GyroMapping& g : m.gyros) {
    ESG_FUZZ_CHECK(g.id >= 1 && g.id <= kMaxGyros, "gyro id in 1..4");
    ESG_FUZZ_CHECK(ids.insert(g.id).second, "gyro id once");
    ESG_FUZZ_CHECK(g.spin_axis_columns.size() == (g.spin_axis_angles ? 2u : 3u),
                   "spin-axis columns");
    ESG_FUZZ_CHECK(g.voltage_columns.empty() || g.voltage_columns.size() == 3, "voltage columns");
    ESG_FUZZ_CHECK(std::isfinite(g.angle_unit_rad) && g.angle_unit_rad > 0, "angle unit");
    ESG_FUZZ_CHECK(std::isfinite(g.voltage_unit_mv) && g.voltage_unit_mv > 0, "voltage unit");
  }
  ESG_FUZZ_CHECK(m.time.unit > absl::ZeroDuration() && m.time.unit < absl::InfiniteDuration(),
                 "time unit");
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace esg;
  const std::string_view input = fuzz::AsText(data, size);
  constexpr std::string_view kSeparator = "\n%%\n";
  const size_t cut = input.find(kSeparator);
  const std::string_view json = input.substr(0, cut);
  absl::StatusOr<storage::ColumnMapping> mapping = storage::ParseColumnMapping(json);
  if (!mapping.ok()) {
    fuzz::CheckCleanError(mapping.status(), absl::StatusCode::kInvalidArgument);
    return 0;
  }
  CheckMapping(*mapping);
  if (cut == std::string_view::npos) return 0;
  const std::string_view csv = input.substr(cut + kSeparator.size());
  absl::StatusOr<estimator::Recording> recording = storage::ParseMappedRecordingCsv(csv, *mapping);
  if (!recording.ok()) {
    fuzz::CheckCleanError(recording.status(), absl::StatusCode::kInvalidArgument);
    return 0;
  }
  fuzz::CheckRecordingRoundTrip(*recording);
  return 0;
}
