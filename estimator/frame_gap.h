// The largest time step between consecutive telemetry frames of a spacecraft, one limit for the
// service's ingest (server/ingest.cc, docs/service.md "Ingest contract": refused with
// OUT_OF_RANGE, field `time`) and for the offline runs over a recording (`esg calibrate`,
// `esg gap`, `esg diagnose`: the row is refused before any filtering, docs/formats.md
// "Validation"). The filter integrates across a gap at the configured rate (8 Hz: 4.8 million
// steps per week), so a wrong time tag years ahead would keep it busy for hours.
#ifndef ESG_ESTIMATOR_FRAME_GAP_H_
#define ESG_ESTIMATOR_FRAME_GAP_H_

#include "absl/time/time.h"

namespace esg::estimator {

inline constexpr absl::Duration kMaxFrameGap = absl::Hours(24 * 7);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_FRAME_GAP_H_
