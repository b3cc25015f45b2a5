// CsvProblems: the problems found while reading a CSV recording, collected row by row and
// reported together in one InvalidArgument (at most kMaxReportedProblems listed, then a count),
// so that a user fixes a file in one pass. Used by the project's own CSV reader
// (recording_csv.cc) and by the column-mapping reader (column_mapping.cc).
#ifndef ESG_FORMATS_CSV_PROBLEMS_H_
#define ESG_FORMATS_CSV_PROBLEMS_H_

#include <algorithm>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "estimator/utc_time.h"
#include "formats/recording_csv.h"

namespace esg::storage {

// The problem of a row `time` more than `limit` after the previous row (RecordingReadOptions).
inline std::string RowGapProblem(absl::Time time, absl::Time previous_time, int previous_line,
                                 absl::Duration limit) {
  absl::Duration rest;
  const int64_t days = absl::IDivDuration(limit, absl::Hours(24), &rest);
  const std::string limit_text = days < 1 || rest != absl::ZeroDuration()
                                     ? absl::FormatDuration(limit)
                                     : absl::StrFormat("%d day%s", days, days == 1 ? "" : "s");
  return absl::StrFormat(
      "%s is more than %s after the previous row (line %d, %s): the filter would run across the "
      "whole gap, and esgd refuses such a frame too; split the recording there or correct the "
      "time",
      estimator::FormatUtc(time), limit_text, previous_line, estimator::FormatUtc(previous_time));
}

class CsvProblems {
 public:
  // `reader` opens the message ("recording CSV"); `where_prefix` goes before a non-empty place
  // ("column " when the place is a column name, "" when it is already phrased).
  CsvProblems(std::string reader, std::string where_prefix)
      : reader_(std::move(reader)), where_prefix_(std::move(where_prefix)) {}

  // A problem on `line`; `where` is empty when it concerns the whole line.
  void Add(int line, std::string where, std::string reason) {
    problems_.push_back({line, std::move(where), std::move(reason)});
  }
  bool empty() const { return problems_.empty(); }
  size_t size() const { return problems_.size(); }

  absl::Status ToStatus() const {
    std::string message = absl::StrFormat("%s: %d problem%s", reader_, problems_.size(),
                                          problems_.size() == 1 ? "" : "s");
    const size_t shown = std::min<size_t>(problems_.size(), kMaxReportedProblems);
    for (size_t i = 0; i < shown; ++i) {
      const Problem& p = problems_[i];
      if (p.where.empty()) {
        absl::StrAppendFormat(&message, "\n  line %d: %s", p.line, p.reason);
      } else {
        absl::StrAppendFormat(&message, "\n  line %d, %s%s: %s", p.line, where_prefix_, p.where,
                              p.reason);
      }
    }
    if (shown < problems_.size()) {
      absl::StrAppendFormat(&message, "\n  ... and %d more", problems_.size() - shown);
    }
    return absl::InvalidArgumentError(message);
  }

 private:
  struct Problem {
    int line;
    std::string where;
    std::string reason;
  };
  std::string reader_;
  std::string where_prefix_;
  std::vector<Problem> problems_;
};

}  // namespace esg::storage

#endif  // ESG_FORMATS_CSV_PROBLEMS_H_
