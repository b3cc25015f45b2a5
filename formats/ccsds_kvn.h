// CCSDS Keyword = Value Notation (KVN) pieces the message readers share (the AEM of aem.h, the OEM
// of oem.h; docs/formats.md): ASCII time codes, the time systems a reader accepts, and its
// errors, InvalidArgument "line <n>: <keyword or field>: <reason>".
#ifndef ESG_FORMATS_CCSDS_KVN_H_
#define ESG_FORMATS_CCSDS_KVN_H_

#include <string>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"

namespace esg::storage {

// CCSDS ASCII time code A ("YYYY-MM-DDThh:mm:ss[.d...]") or B ("YYYY-DDDThh:mm:ss[.d...]"), an
// optional trailing `Z`, UTC. InvalidArgument otherwise.
absl::StatusOr<absl::Time> ParseCcsdsTime(absl::string_view text);
// Time code A with microseconds, no `Z`.
std::string FormatCcsdsTime(absl::Time time);

// InvalidArgument "line <n>: <what>: <reason>".
absl::Status KvnLineError(int line, absl::string_view what, absl::string_view reason);

// A non-negative decimal of 1 to 9 digits (fits an int).
bool ParseKvnDigits(absl::string_view s, int* out);

// A TIME_SYSTEM value this project reads: UTC, or TAI (converted to UTC with ERFA's leap
// seconds). InvalidArgument with the reason for a value not in the CCSDS list ("unknown value
// X") or one of the list's others (SCLK, GPS, TT, ...: not converted).
absl::Status CheckKvnTimeSystem(absl::string_view value);

// An epoch of a section whose TIME_SYSTEM is `time_system` (UTC or TAI, checked before), as UTC.
// TAI's epochs are converted with the leap seconds of ERFA's table (the last one for years past
// it); second 60 is refused in TAI. InvalidArgument naming the text.
absl::StatusOr<absl::Time> ParseKvnEpoch(absl::string_view text, absl::string_view time_system);

// "KEYWORD = value" split and stripped; KvnLineError without `=` or with an empty value.
struct KvnKeyValue {
  std::string key;
  std::string value;
};
absl::StatusOr<KvnKeyValue> SplitKvnLine(absl::string_view line, int line_number);

}  // namespace esg::storage

#endif  // ESG_FORMATS_CCSDS_KVN_H_
