// The one text form of an instant in every output (docs/formats.md "Time"): RFC 3339 in UTC with
// `Z` and milliseconds, truncated, the year in 4 digits: "2019-03-01T00:00:00.000Z". Used by CLI
// tables and exports, the diagnosis report, alert, server, log and problem messages. The recording
// CSV, whose times must read back exactly, and the CCSDS AEM, which has a time format of its own,
// are data and write their own forms (formats/recording_csv.h, formats/aem.h).
#ifndef ESG_ESTIMATOR_UTC_TIME_H_
#define ESG_ESTIMATOR_UTC_TIME_H_

#include <string>

#include "absl/time/time.h"

namespace esg::estimator {

// absl::InfinitePast() and absl::InfiniteFuture() are written "infinite-past" and
// "infinite-future" (an unbounded end of an interval).
std::string FormatUtc(absl::Time time);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_UTC_TIME_H_
