// Fuzz target: the CCSDS OEM reader (storage::ParseOem) and the orbit made from it
// (storage::ParseOemOrbit, estimator::Orbit). Property: a text is refused with InvalidArgument,
// or gives segments whose states strictly increase in time inside [START_TIME, STOP_TIME] with
// finite numbers; its orbit (for the first segment's OBJECT_NAME) is refused with
// InvalidArgument, or interpolates finite states at its arcs' ends and middles, reports gaps
// inside the span asked, and refuses a time outside its arcs with OutOfRange; the project's OEM
// writer writes a segment's states (2 or more) so that the reader reads back the same times (to
// the written microsecond) and positions and velocities to the written decimals.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "formats/oem.h"
#include "fuzz/fuzz_util.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace esg;
  absl::StatusOr<storage::OemFile> file = storage::ParseOem(fuzz::AsAbslText(data, size));
  if (!file.ok()) {
    fuzz::CheckCleanError(file.status(), absl::StatusCode::kInvalidArgument);
    return 0;
  }
  ESG_FUZZ_CHECK(file->version == "1.0" || file->version == "2.0" || file->version == "3.0",
                 file->version);
  ESG_FUZZ_CHECK(!file->segments.empty(), "at least one segment");
  for (const storage::OemSegment& segment : file->segments) {
    ESG_FUZZ_CHECK(!segment.states.empty(), "a segment has states");
    for (size_t i = 0; i < segment.states.size(); ++i) {
      const estimator::OrbitState& s = segment.states[i];
      if (i > 0) ESG_FUZZ_CHECK(segment.states[i - 1].time < s.time, "times increase");
      ESG_FUZZ_CHECK(segment.start_time <= s.time && s.time <= segment.stop_time,
                     "time inside the segment's span");
      ESG_FUZZ_CHECK(s.r_in_km.allFinite() && s.v_in_km_s.allFinite(), "finite state");
    }
  }

  const std::string& name = file->segments.front().metadata.at("OBJECT_NAME");
  absl::StatusOr<estimator::Orbit> orbit =
      storage::ParseOemOrbit(fuzz::AsAbslText(data, size), name);
  if (!orbit.ok()) {
    fuzz::CheckCleanError(orbit.status(), absl::StatusCode::kInvalidArgument);
  } else {
    for (const estimator::OrbitArc& arc : orbit->arcs()) {
      for (absl::Time t : {arc.from, arc.from + (arc.to - arc.from) / 2, arc.to}) {
        absl::StatusOr<estimator::OrbitState> s = orbit->StateAt(t);
        ESG_FUZZ_CHECK(s.ok(), s.status().ToString());
        ESG_FUZZ_CHECK(s->r_in_km.allFinite() && s->v_in_km_s.allFinite(), "finite interpolation");
      }
      const absl::Time before = arc.from - absl::Seconds(1);
      for (const estimator::TimeInterval& gap : orbit->Gaps(before, arc.to)) {
        ESG_FUZZ_CHECK(before <= gap.from && gap.from <= gap.to && gap.to <= arc.to, "gap inside");
      }
    }
    const absl::Time far = orbit->arcs().front().from - absl::Hours(24 * 365 * 100);
    absl::StatusOr<estimator::OrbitState> outside = orbit->StateAt(far);
    bool covered = false;
    for (const estimator::OrbitArc& arc : orbit->arcs()) covered |= arc.from <= far && far <= arc.to;
    if (!covered) fuzz::CheckCleanError(outside.status(), absl::StatusCode::kOutOfRange);
  }
  // The service's stored deliveries (storage::OrbitFromDeliveries): the same text delivered twice
  // gives an orbit exactly when one delivery does (the later replaces the earlier where they
  // overlap), with the same arcs' span; a refusal names the delivery.
  const std::string text(fuzz::AsAbslText(data, size));
  absl::StatusOr<estimator::Orbit> twice =
      storage::OrbitFromDeliveries({text, text}, {"first: ", "second: "}, name);
  ESG_FUZZ_CHECK(twice.ok() == orbit.ok(), twice.status().ToString());
  if (!twice.ok()) {
    fuzz::CheckCleanError(twice.status(), absl::StatusCode::kInvalidArgument);
    ESG_FUZZ_CHECK(absl::StartsWith(twice.status().message(), "first: ") ||
                       absl::StartsWith(twice.status().message(), "second: "),
                   twice.status().ToString());
  } else {
    ESG_FUZZ_CHECK(twice->Gaps(orbit->arcs().front().from, orbit->arcs().back().to).size() <=
                       orbit->Gaps(orbit->arcs().front().from, orbit->arcs().back().to).size(),
                   "two copies cover what one does");
  }

  for (const storage::OemSegment& segment : file->segments) {
    if (segment.states.size() < 2) continue;
    storage::OemHeader header;
    header.object_name = "FUZZ";
    header.object_id = "FUZZ";
    header.creation_date = absl::FromUnixSeconds(1551398400);
    absl::StatusOr<std::string> written = storage::WriteOem(header, segment.states);
    if (!written.ok()) {
      // Times may be closer than the written microsecond: the writer checks its own order only.
      fuzz::CheckCleanError(written.status(), absl::StatusCode::kInvalidArgument);
      continue;
    }
    absl::StatusOr<storage::OemFile> back = storage::ParseOem(*written);
    if (!back.ok()) {
      // Two states less than a microsecond apart print as the same epoch, which the reader
      // refuses as not increasing; nothing else may be refused.
      ESG_FUZZ_CHECK(back.status().message().find("is not after the previous epoch") !=
                         absl::string_view::npos,
                     back.status().ToString() + "\n" + *written);
      continue;
    }
    ESG_FUZZ_CHECK(back->segments.size() == 1 &&
                       back->segments[0].states.size() == segment.states.size(),
                   *written);
    for (size_t i = 0; i < segment.states.size(); ++i) {
      const estimator::OrbitState& x = segment.states[i];
      const estimator::OrbitState& y = back->segments[0].states[i];
      ESG_FUZZ_CHECK(absl::AbsDuration(x.time - y.time) < absl::Microseconds(1), *written);
      for (int k = 0; k < 3; ++k) {
        ESG_FUZZ_CHECK(std::abs(x.r_in_km[k] - y.r_in_km[k]) <= 1e-6 + 1e-15 * std::abs(x.r_in_km[k]),
                       *written);
        ESG_FUZZ_CHECK(
            std::abs(x.v_in_km_s[k] - y.v_in_km_s[k]) <= 1e-9 + 1e-15 * std::abs(x.v_in_km_s[k]),
            *written);
      }
    }
  }
  return 0;
}
