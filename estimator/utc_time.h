// The one text form of an instant in every output (docs/formats.md "Time"): RFC 3339 in UTC with
// `Z` and milliseconds, truncated, the year in 4 digits: "2019-03-01T00:00:00.000Z". Used by CLI
// tables and exports, the diagnosis report, alert, server, log and problem messages. The recording
// CSV, whose times must read back exactly, and the CCSDS AEM, which has a time format of its own,
// are data and write their own forms (formats/recording_csv.h, formats/aem.h).
//
// And the one reader of an instant given as RFC 3339 text: every CLI time option, the recording
// CSV's time column, a column mapping's rfc3339 column and epoch, a planned attitude's times.
#ifndef ESG_ESTIMATOR_UTC_TIME_H_
#define ESG_ESTIMATOR_UTC_TIME_H_

#include <string>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"

namespace esg::estimator {

// absl::InfinitePast() and absl::InfiniteFuture() are written "infinite-past" and
// "infinite-future" (an unbounded end of an interval).
std::string FormatUtc(absl::Time time);

// The instant an RFC 3339 date-time names, to the nanosecond: `Z` or a numeric offset, any number
// of fractional digits ("2019-03-01T00:00:00Z", "2019-03-01T03:00:00.25+03:00"); blanks around
// it are ignored. `what` names where the text was given as the user knows it (an option
// "--from", a field "time.epoch"), or is empty when the caller names the place itself (a CSV
// problem names its line and column). Anything else is InvalidArgument, in one wording:
//   --from: 'yesterday' is not an RFC 3339 time such as 2019-03-01T00:00:00Z
// the text quoted with at most 40 characters, non-printable bytes escaped. "infinite-past" and
// "infinite-future", which FormatUtc writes for an open end, are refused: an open end is a time
// left out.
absl::StatusOr<absl::Time> ParseUtc(absl::string_view text, absl::string_view what);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_UTC_TIME_H_
