// A small metrics registry and its Prometheus text exposition (format 0.0.4: HELP and TYPE lines,
// one sample a line, label values escaped, histograms as cumulative `_bucket{le=...}` series with
// `_sum` and `_count`). docs/service.md "Metrics" lists what esgd exposes; server/metrics_http.h
// serves Render() on `--metrics-listen`.
//
// Cost on the hot path: a counter or histogram update is one or two relaxed atomic operations; a
// labelled series is found under its family's mutex (a map lookup), so callers that update the
// same series often may keep the reference (it stays valid for the registry's life).
//
// Label values come from clients (station ids): each family keeps at most kMaxSeries label sets;
// further ones are counted in one series whose label values are all kOverflowLabel.
#ifndef ESG_SERVER_METRICS_H_
#define ESG_SERVER_METRICS_H_

#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"

namespace esg::server {

class Counter {
 public:
  // `amount` >= 0 (a counter only grows); negative amounts are ignored.
  void Increment(double amount = 1.0) {
    if (amount > 0.0) value_.fetch_add(amount, std::memory_order_relaxed);
  }
  double Value() const { return value_.load(std::memory_order_relaxed); }

 private:
  std::atomic<double> value_{0.0};
};

class Gauge {
 public:
  void Set(double value) { value_.store(value, std::memory_order_relaxed); }
  void Add(double amount) { value_.fetch_add(amount, std::memory_order_relaxed); }
  double Value() const { return value_.load(std::memory_order_relaxed); }

 private:
  std::atomic<double> value_{0.0};
};

class Histogram {
 public:
  // `bounds`: the buckets' upper bounds, strictly increasing; +Inf is implied.
  explicit Histogram(std::vector<double> bounds);
  void Observe(double value);

  struct Snapshot {
    std::vector<uint64_t> cumulative;  // per bound, then +Inf (== count)
    double sum = 0.0;
    uint64_t count = 0;
  };
  // Bucket counts are read one by one while others observe: each is exact at its own read, and
  // count is the +Inf bucket, so the exposition is monotone and self-consistent.
  Snapshot Read() const;
  const std::vector<double>& bounds() const { return bounds_; }

 private:
  const std::vector<double> bounds_;
  std::unique_ptr<std::atomic<uint64_t>[]> counts_;  // per bucket (not cumulative), +Inf last
  std::atomic<double> sum_{0.0};
};

// Bucket bounds in seconds from 100 us to 10 s (1-2.5-5 steps).
std::vector<double> LatencyBuckets();

inline constexpr size_t kMaxSeries = 1000;
inline constexpr const char* kOverflowLabel = "_overflow";

// The series of one metric name, one per label set.
template <typename Metric>
class Family {
 public:
  // `make` builds a new series (histograms need their bounds).
  Family(std::vector<std::string> label_names, std::function<std::unique_ptr<Metric>()> make)
      : label_names_(std::move(label_names)), make_(std::move(make)) {}

  // The series of `values` (one per label name, in order; missing ones are empty), created at 0
  // on first use.
  Metric& With(const std::vector<std::string>& values);
  Metric& With(std::initializer_list<absl::string_view> values) {
    return With(std::vector<std::string>(values.begin(), values.end()));
  }
  // Without labels.
  Metric& Get() { return With(std::vector<std::string>{}); }

  const std::vector<std::string>& label_names() const { return label_names_; }
  // Visits every series in label order (for the exposition).
  void ForEach(const std::function<void(const std::vector<std::string>&, const Metric&)>& visit);

 private:
  const std::vector<std::string> label_names_;
  const std::function<std::unique_ptr<Metric>()> make_;
  absl::Mutex mu_;
  std::map<std::vector<std::string>, std::unique_ptr<Metric>> series_ ABSL_GUARDED_BY(mu_);
};

class MetricsRegistry {
 public:
  MetricsRegistry() = default;
  MetricsRegistry(const MetricsRegistry&) = delete;
  MetricsRegistry& operator=(const MetricsRegistry&) = delete;

  // `name` follows Prometheus' rules ([a-zA-Z_:][a-zA-Z0-9_:]*; counters end in _total);
  // `help` is one sentence. The family lives as long as the registry.
  Family<Counter>& AddCounter(const std::string& name, const std::string& help,
                              std::vector<std::string> label_names = {});
  Family<Gauge>& AddGauge(const std::string& name, const std::string& help,
                          std::vector<std::string> label_names = {});
  Family<Histogram>& AddHistogram(const std::string& name, const std::string& help,
                                  std::vector<std::string> label_names, std::vector<double> bounds);

  // Called at the start of every Render(), in the order added: sets the gauges that are read
  // from state (sessions by state, backlog). Must not call Render().
  void AddCollector(std::function<void()> collect);

  // The text exposition (Content-Type "text/plain; version=0.0.4"). Thread-safe.
  std::string Render();

 private:
  struct Entry {
    std::string name;
    std::string help;
    std::string type;  // counter, gauge, histogram
    std::unique_ptr<Family<Counter>> counters;
    std::unique_ptr<Family<Gauge>> gauges;
    std::unique_ptr<Family<Histogram>> histograms;
  };
  absl::Mutex mu_;
  std::vector<std::unique_ptr<Entry>> entries_ ABSL_GUARDED_BY(mu_);
  std::vector<std::function<void()>> collectors_ ABSL_GUARDED_BY(mu_);
};

// Exposition helpers (exposed for the tests): a label value with \, " and newline escaped; a
// HELP text with \ and newline escaped; a sample value (integers without a fraction, +Inf,
// -Inf, NaN).
std::string EscapeLabelValue(absl::string_view value);
std::string EscapeHelp(absl::string_view help);
std::string FormatSampleValue(double value);

// ---- Family implementation ----

template <typename Metric>
Metric& Family<Metric>::With(const std::vector<std::string>& values) {
  std::vector<std::string> key = values;
  key.resize(label_names_.size());
  absl::MutexLock lock(&mu_);
  auto it = series_.find(key);
  if (it != series_.end()) return *it->second;
  if (series_.size() >= kMaxSeries) {
    key.assign(label_names_.size(), kOverflowLabel);
    it = series_.find(key);
    if (it != series_.end()) return *it->second;
  }
  return *series_.emplace(std::move(key), make_()).first->second;
}

template <typename Metric>
void Family<Metric>::ForEach(
    const std::function<void(const std::vector<std::string>&, const Metric&)>& visit) {
  absl::MutexLock lock(&mu_);
  for (const auto& [labels, metric] : series_) visit(labels, *metric);
}

}  // namespace esg::server

#endif  // ESG_SERVER_METRICS_H_
