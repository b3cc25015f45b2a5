#include "estimator/utc_time.h"

#include <string>

#include "absl/status/status.h"
#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"

namespace esg::estimator {

std::string FormatUtc(absl::Time time) {
  return absl::FormatTime("%E4Y-%m-%dT%H:%M:%E3SZ", time, absl::UTCTimeZone());
}

absl::StatusOr<absl::Time> ParseUtc(absl::string_view text, absl::string_view what) {
  absl::Time time;
  std::string error;  // absl's reason says no more than "Failed to parse input"
  if (absl::ParseTime(absl::RFC3339_full, text, &time, &error) && time != absl::InfinitePast() &&
      time != absl::InfiniteFuture()) {
    return time;
  }
  constexpr size_t kQuoted = 40;
  const std::string quoted =
      text.size() > kQuoted ? absl::StrCat(absl::CHexEscape(text.substr(0, kQuoted - 3)), "...")
                            : absl::CHexEscape(text);
  return absl::InvalidArgumentError(absl::StrCat(what, what.empty() ? "" : ": ", "'", quoted,
                                                 "' is not an RFC 3339 time such as "
                                                 "2019-03-01T00:00:00Z"));
}

}  // namespace esg::estimator
