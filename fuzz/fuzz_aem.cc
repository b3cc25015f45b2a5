// Fuzz target: the CCSDS AEM reader (storage::ParseAem) and the planned attitude a prediction is
// given from it (server::SampledProfile, as `esg predict --planned` and the server use it).
// Property: a text is refused with InvalidArgument, or gives segments whose epochs strictly
// increase inside [START_TIME, STOP_TIME], with unit finite quaternions and finite sigmas; the
// planned profile of all samples is refused with InvalidArgument or gives unit finite attitudes;
// the project's AEM writer writes the segments (or refuses segments that overlap) so that the
// reader reads back the same samples (epochs to the written microsecond, quaternions normalised and
// up to sign).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "formats/aem.h"
#include "fuzz/fuzz_util.h"
#include "server/planned_profile.h"

namespace {

void CheckPlanned(const esg::storage::AemFile& file) {
  std::vector<esg::server::PlannedSample> planned;
  for (const esg::storage::AemSegment& segment : file.segments) {
    for (const esg::storage::AemSample& s : segment.samples) planned.push_back({s.epoch, s.q_in_b});
  }
  absl::StatusOr<esg::server::SampledProfile> profile =
      esg::server::SampledProfile::Create(std::move(planned));
  if (!profile.ok()) {
    esg::fuzz::CheckCleanError(profile.status(), absl::StatusCode::kInvalidArgument);
    return;
  }
  const double span = absl::ToDoubleSeconds(file.segments.back().samples.back().epoch -
                                            file.segments.front().samples.front().epoch);
  for (double t : {-1.0, 0.0, 0.5 * span, 0.999 * span, span, span + 1.0}) {
    if (!std::isfinite(t)) continue;
    const Eigen::Quaterniond q = profile->Attitude(t);
    ESG_FUZZ_CHECK(q.coeffs().allFinite() && esg::fuzz::IsUnit(q.norm()), "unit planned attitude");
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace esg;
  absl::StatusOr<storage::AemFile> file = storage::ParseAem(fuzz::AsAbslText(data, size));
  if (!file.ok()) {
    fuzz::CheckCleanError(file.status(), absl::StatusCode::kInvalidArgument);
    return 0;
  }
  ESG_FUZZ_CHECK(file->version == "1.0" || file->version == "2.0", file->version);
  ESG_FUZZ_CHECK(!file->segments.empty(), "at least one segment");
  std::vector<storage::AemBlock> blocks;
  for (const storage::AemSegment& segment : file->segments) {
    ESG_FUZZ_CHECK(!segment.samples.empty(), "a segment has samples");
    for (size_t i = 0; i < segment.samples.size(); ++i) {
      const storage::AemSample& s = segment.samples[i];
      if (i > 0) ESG_FUZZ_CHECK(segment.samples[i - 1].epoch < s.epoch, "epochs increase");
      ESG_FUZZ_CHECK(segment.start_time <= s.epoch && s.epoch <= segment.stop_time,
                     "epoch inside the segment's span");
      ESG_FUZZ_CHECK(s.q_in_b.coeffs().allFinite() && std::abs(s.q_in_b.norm() - 1) <= 1e-6,
                     "unit quaternion");
      if (s.sigma_arcsec.has_value()) ESG_FUZZ_CHECK(s.sigma_arcsec->allFinite(), "finite sigma");
    }
    storage::AemBlock block;
    block.samples = segment.samples;
    blocks.push_back(std::move(block));
  }
  CheckPlanned(*file);

  storage::AemHeader header;
  header.object_name = "FUZZ";
  header.object_id = "FUZZ";
  header.creation_date = absl::FromUnixSeconds(1551398400);
  absl::StatusOr<std::string> written = storage::WriteAemBlocks(header, blocks);
  if (!written.ok()) {
    // Segments may overlap in a file; the writer's blocks may not.
    fuzz::CheckCleanError(written.status(), absl::StatusCode::kInvalidArgument);
    ESG_FUZZ_CHECK(written.status().message().find("].samples[0].epoch") != absl::string_view::npos,
                   written.status().ToString());
    return 0;
  }
  absl::StatusOr<storage::AemFile> back = storage::ParseAem(*written);
  ESG_FUZZ_CHECK(back.ok(), back.status().ToString() + "\n" + *written);
  ESG_FUZZ_CHECK(back->segments.size() == file->segments.size(), *written);
  for (size_t b = 0; b < blocks.size(); ++b) {
    const std::vector<storage::AemSample>& x = file->segments[b].samples;
    const std::vector<storage::AemSample>& y = back->segments[b].samples;
    ESG_FUZZ_CHECK(x.size() == y.size(), *written);
    for (size_t i = 0; i < x.size(); ++i) {
      ESG_FUZZ_CHECK(absl::AbsDuration(x[i].epoch - y[i].epoch) < absl::Microseconds(1), *written);
      // The reader keeps a quaternion as written (unit within 1e-6); the writer normalises it.
      ESG_FUZZ_CHECK(std::abs(x[i].q_in_b.normalized().dot(y[i].q_in_b)) >= 1 - 1e-12, *written);
      ESG_FUZZ_CHECK(x[i].sigma_arcsec.has_value() == y[i].sigma_arcsec.has_value(), *written);
    }
  }
  return 0;
}
