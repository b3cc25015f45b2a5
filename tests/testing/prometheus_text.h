// A strict reader of the Prometheus text exposition format 0.0.4 for the tests: every sample
// line is split into name, labels (escapes undone) and value; the HELP and TYPE lines are kept
// per family; anything else is an error naming the line.
#ifndef ESG_TESTS_TESTING_PROMETHEUS_TEXT_H_
#define ESG_TESTS_TESTING_PROMETHEUS_TEXT_H_

#include <cstdlib>
#include <map>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"

namespace esg::testing {

struct Sample {
  std::string name;
  std::map<std::string, std::string> labels;
  double value = 0.0;
};

struct Exposition {
  std::map<std::string, std::string> help;  // family name -> help text
  std::map<std::string, std::string> type;  // family name -> counter, gauge, histogram
  std::vector<Sample> samples;

  // The value of the sample `name` with exactly `labels`; -1 when absent.
  double Value(const std::string& name, const std::map<std::string, std::string>& labels = {}) const {
    for (const Sample& s : samples) {
      if (s.name == name && s.labels == labels) return s.value;
    }
    return -1.0;
  }
  // The sum over the samples named `name` whose labels include `match`.
  double Sum(const std::string& name, const std::map<std::string, std::string>& match = {}) const {
    double sum = 0.0;
    for (const Sample& s : samples) {
      if (s.name != name) continue;
      bool all = true;
      for (const auto& [k, v] : match) {
        auto it = s.labels.find(k);
        all = all && it != s.labels.end() && it->second == v;
      }
      if (all) sum += s.value;
    }
    return sum;
  }
};

inline bool IsMetricNameChar(char c, bool first) {
  return (c >= 'a' && c <= 'z') || (c >= 'A' && c <= 'Z') || c == '_' || c == ':' ||
         (!first && c >= '0' && c <= '9');
}

inline absl::StatusOr<Exposition> ParseExposition(const std::string& text) {
  Exposition e;
  int number = 0;
  for (absl::string_view line : absl::StrSplit(text, '\n')) {
    ++number;
    auto error = [&](absl::string_view what) {
      return absl::InvalidArgumentError(absl::StrCat("line ", number, ": ", what, ": ", line));
    };
    if (line.empty()) continue;
    if (line[0] == '#') {
      std::vector<std::string> parts = absl::StrSplit(line, absl::MaxSplits(' ', 3));
      if (parts.size() < 4 || (parts[1] != "HELP" && parts[1] != "TYPE")) {
        return error("a comment that is not HELP or TYPE");
      }
      if (parts[1] == "HELP") {
        e.help[parts[2]] = parts[3];
      } else {
        if (parts[3] != "counter" && parts[3] != "gauge" && parts[3] != "histogram") {
          return error("unknown type");
        }
        e.type[parts[2]] = parts[3];
      }
      continue;
    }
    Sample s;
    size_t i = 0;
    while (i < line.size() && IsMetricNameChar(line[i], i == 0)) ++i;
    if (i == 0) return error("no metric name");
    s.name = std::string(line.substr(0, i));
    if (i < line.size() && line[i] == '{') {
      ++i;
      while (i < line.size() && line[i] != '}') {
        const size_t start = i;
        while (i < line.size() && IsMetricNameChar(line[i], i == start)) ++i;
        const std::string key(line.substr(start, i - start));
        if (key.empty() || i + 1 >= line.size() || line[i] != '=' || line[i + 1] != '"') {
          return error("bad label");
        }
        i += 2;
        std::string value;
        bool closed = false;
        while (i < line.size()) {
          const char c = line[i++];
          if (c == '"') {
            closed = true;
            break;
          }
          if (c == '\\') {
            if (i >= line.size()) return error("dangling escape");
            const char n = line[i++];
            if (n == 'n') {
              value += '\n';
            } else if (n == '\\' || n == '"') {
              value += n;
            } else {
              return error("bad escape");
            }
          } else {
            value += c;
          }
        }
        if (!closed) return error("unterminated label value");
        if (!s.labels.emplace(key, value).second) return error("label repeated");
        if (i < line.size() && line[i] == ',') ++i;
      }
      if (i >= line.size()) return error("unterminated labels");
      ++i;  // '}'
    }
    if (i >= line.size() || line[i] != ' ') return error("no value");
    const std::string value(line.substr(i + 1));
    char* end = nullptr;  // strtod also reads +Inf, -Inf and NaN
    s.value = std::strtod(value.c_str(), &end);
    if (value.empty() || *end != '\0') return error("bad value");
    e.samples.push_back(std::move(s));
  }
  return e;
}

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_PROMETHEUS_TEXT_H_
