// The line loop under both recording readers (recording_csv.cc, the project's CSV;
// column_mapping.cc, any CSV through a column mapping): numbered lines without their line end,
// blank lines skipped, and the "# key: value" metadata lines before the header, a repeated key
// reported. One reader of lines, so that both formats number, trim and report lines alike
// (docs/formats.md).
#ifndef ESG_FORMATS_CSV_LINES_H_
#define ESG_FORMATS_CSV_LINES_H_

#include <map>
#include <optional>
#include <string>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "absl/strings/string_view.h"
#include "formats/csv_problems.h"

namespace esg::storage {

// The non-blank lines of a CSV text, numbered from 1 as an editor numbers them, without "\n" or
// "\r\n"; a UTF-8 byte order mark before the first line is dropped.
class CsvLines {
 public:
  explicit CsvLines(absl::string_view text) : text_(text) {
    if (absl::StartsWith(text_, "\xEF\xBB\xBF")) text_.remove_prefix(3);
  }
  // The next non-blank line and its number; false at the end.
  bool Next(int* line_no, absl::string_view* line) {
    while (pos_ < text_.size()) {
      size_t eol = text_.find('\n', pos_);
      if (eol == absl::string_view::npos) eol = text_.size();
      absl::string_view l = text_.substr(pos_, eol - pos_);
      pos_ = eol + 1;
      ++line_no_;
      if (!l.empty() && l.back() == '\r') l.remove_suffix(1);
      if (absl::StripAsciiWhitespace(l).empty()) continue;
      *line_no = line_no_;
      *line = l;
      return true;
    }
    return false;
  }

 private:
  absl::string_view text_;
  size_t pos_ = 0;
  int line_no_ = 0;
};

// The metadata lines "# key: value" before a CSV's header (a '#' line without ':' is a free
// comment); a key given twice is a problem on its second line, the first value kept.
class CsvMetadata {
 public:
  // The key and value of `line` (it starts with '#'), or nullopt for a free comment or a repeat.
  std::optional<std::pair<std::string, std::string>> Read(absl::string_view line, int line_no,
                                                          CsvProblems& problems) {
    const absl::string_view body = line.substr(1);
    const size_t colon = body.find(':');
    if (colon == absl::string_view::npos) return std::nullopt;
    std::string key(absl::StripAsciiWhitespace(body.substr(0, colon)));
    if (key.empty()) return std::nullopt;
    if (auto [it, inserted] = line_of_.emplace(key, line_no); !inserted) {
      problems.Add(line_no, "",
                   absl::StrFormat("metadata key '%s' repeats line %d", key, it->second));
      return std::nullopt;
    }
    return std::make_pair(std::move(key),
                          std::string(absl::StripAsciiWhitespace(body.substr(colon + 1))));
  }

 private:
  std::map<std::string, int> line_of_;  // key -> the line that gave it
};

}  // namespace esg::storage

#endif  // ESG_FORMATS_CSV_LINES_H_
