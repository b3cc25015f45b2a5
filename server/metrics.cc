// Metrics registry and Prometheus text exposition (see metrics.h).
#include "server/metrics.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <utility>

#include "absl/strings/str_cat.h"

namespace esg::server {

Histogram::Histogram(std::vector<double> bounds)
    : bounds_(std::move(bounds)),
      counts_(std::make_unique<std::atomic<uint64_t>[]>(bounds_.size() + 1)) {
  for (size_t i = 0; i <= bounds_.size(); ++i) counts_[i].store(0, std::memory_order_relaxed);
}

void Histogram::Observe(double value) {
  // The first bucket whose upper bound holds the value (le is inclusive).
  const size_t bucket =
      std::lower_bound(bounds_.begin(), bounds_.end(), value) - bounds_.begin();
  counts_[bucket].fetch_add(1, std::memory_order_relaxed);
  sum_.fetch_add(value, std::memory_order_relaxed);
}

Histogram::Snapshot Histogram::Read() const {
  Snapshot s;
  s.cumulative.reserve(bounds_.size() + 1);
  uint64_t running = 0;
  for (size_t i = 0; i <= bounds_.size(); ++i) {
    running += counts_[i].load(std::memory_order_relaxed);
    s.cumulative.push_back(running);
  }
  s.count = running;
  s.sum = sum_.load(std::memory_order_relaxed);
  return s;
}

std::vector<double> LatencyBuckets() {
  return {0.0001, 0.00025, 0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025,
          0.05,   0.1,     0.25,   0.5,   1.0,    2.5,   5.0,  10.0};
}

Family<Counter>& MetricsRegistry::AddCounter(const std::string& name, const std::string& help,
                                             std::vector<std::string> label_names) {
  auto entry = std::make_unique<Entry>();
  entry->name = name;
  entry->help = help;
  entry->type = "counter";
  entry->counters = std::make_unique<Family<Counter>>(std::move(label_names),
                                                      [] { return std::make_unique<Counter>(); });
  Family<Counter>& family = *entry->counters;
  absl::MutexLock lock(&mu_);
  entries_.push_back(std::move(entry));
  return family;
}

Family<Gauge>& MetricsRegistry::AddGauge(const std::string& name, const std::string& help,
                                         std::vector<std::string> label_names) {
  auto entry = std::make_unique<Entry>();
  entry->name = name;
  entry->help = help;
  entry->type = "gauge";
  entry->gauges = std::make_unique<Family<Gauge>>(std::move(label_names),
                                                  [] { return std::make_unique<Gauge>(); });
  Family<Gauge>& family = *entry->gauges;
  absl::MutexLock lock(&mu_);
  entries_.push_back(std::move(entry));
  return family;
}

Family<Histogram>& MetricsRegistry::AddHistogram(const std::string& name, const std::string& help,
                                                 std::vector<std::string> label_names,
                                                 std::vector<double> bounds) {
  auto entry = std::make_unique<Entry>();
  entry->name = name;
  entry->help = help;
  entry->type = "histogram";
  entry->histograms = std::make_unique<Family<Histogram>>(
      std::move(label_names), [bounds] { return std::make_unique<Histogram>(bounds); });
  Family<Histogram>& family = *entry->histograms;
  absl::MutexLock lock(&mu_);
  entries_.push_back(std::move(entry));
  return family;
}

void MetricsRegistry::AddCollector(std::function<void()> collect) {
  absl::MutexLock lock(&mu_);
  collectors_.push_back(std::move(collect));
}

std::string EscapeLabelValue(absl::string_view value) {
  std::string out;
  out.reserve(value.size());
  for (const char c : value) {
    if (c == '\\') {
      out += "\\\\";
    } else if (c == '"') {
      out += "\\\"";
    } else if (c == '\n') {
      out += "\\n";
    } else {
      out += c;
    }
  }
  return out;
}

std::string EscapeHelp(absl::string_view help) {
  std::string out;
  out.reserve(help.size());
  for (const char c : help) {
    if (c == '\\') {
      out += "\\\\";
    } else if (c == '\n') {
      out += "\\n";
    } else {
      out += c;
    }
  }
  return out;
}

std::string FormatSampleValue(double value) {
  if (std::isnan(value)) return "NaN";
  if (std::isinf(value)) return value > 0 ? "+Inf" : "-Inf";
  if (value == std::floor(value) && std::fabs(value) < 1e15) {
    return absl::StrCat(static_cast<int64_t>(value));
  }
  // The shortest text that reads back as the same double (0.0001, not 0.00010000000000000001).
  // Fixed notation in the usual range (le="0.0001", not "1e-04"), scientific outside it.
  char buffer[64];
  const double magnitude = std::fabs(value);
  const std::to_chars_result r =
      magnitude >= 1e-9 && magnitude < 1e15
          ? std::to_chars(buffer, buffer + sizeof buffer, value, std::chars_format::fixed)
          : std::to_chars(buffer, buffer + sizeof buffer, value);
  return std::string(buffer, r.ptr);
}

namespace {

// `{a="x",b="y"}` with an optional extra label (le) last; empty without labels.
std::string LabelText(const std::vector<std::string>& names, const std::vector<std::string>& values,
                      absl::string_view extra_name = {}, absl::string_view extra_value = {}) {
  std::string out;
  for (size_t i = 0; i < names.size(); ++i) {
    absl::StrAppend(&out, out.empty() ? "{" : ",", names[i], "=\"", EscapeLabelValue(values[i]),
                    "\"");
  }
  if (!extra_name.empty()) {
    absl::StrAppend(&out, out.empty() ? "{" : ",", extra_name, "=\"", extra_value, "\"");
  }
  if (!out.empty()) out += "}";
  return out;
}

}  // namespace

std::string MetricsRegistry::Render() {
  std::vector<std::function<void()>> collectors;
  {
    absl::MutexLock lock(&mu_);
    collectors = collectors_;
  }
  for (const auto& collect : collectors) collect();
  std::string out;
  absl::MutexLock lock(&mu_);
  for (const auto& e : entries_) {
    absl::StrAppend(&out, "# HELP ", e->name, " ", EscapeHelp(e->help), "\n# TYPE ", e->name, " ",
                    e->type, "\n");
    if (e->counters != nullptr) {
      const std::vector<std::string>& names = e->counters->label_names();
      e->counters->ForEach([&](const std::vector<std::string>& labels, const Counter& c) {
        absl::StrAppend(&out, e->name, LabelText(names, labels), " ",
                        FormatSampleValue(c.Value()), "\n");
      });
    } else if (e->gauges != nullptr) {
      const std::vector<std::string>& names = e->gauges->label_names();
      e->gauges->ForEach([&](const std::vector<std::string>& labels, const Gauge& g) {
        absl::StrAppend(&out, e->name, LabelText(names, labels), " ",
                        FormatSampleValue(g.Value()), "\n");
      });
    } else {
      const std::vector<std::string>& names = e->histograms->label_names();
      e->histograms->ForEach([&](const std::vector<std::string>& labels, const Histogram& h) {
        const Histogram::Snapshot s = h.Read();
        for (size_t i = 0; i < s.cumulative.size(); ++i) {
          const std::string le =
              i < h.bounds().size() ? FormatSampleValue(h.bounds()[i]) : std::string("+Inf");
          absl::StrAppend(&out, e->name, "_bucket", LabelText(names, labels, "le", le), " ",
                          s.cumulative[i], "\n");
        }
        absl::StrAppend(&out, e->name, "_sum", LabelText(names, labels), " ",
                        FormatSampleValue(s.sum), "\n", e->name, "_count",
                        LabelText(names, labels), " ", s.count, "\n");
      });
    }
  }
  return out;
}

}  // namespace esg::server
