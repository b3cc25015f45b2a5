// Helpers shared by the libFuzzer targets (docs/fuzzing.md): the property check that aborts, so
// libFuzzer records a violated property as a crash with its input, and the checks of a parsed
// recording that both CSV readers promise.
#ifndef ESG_FUZZ_FUZZ_UTIL_H_
#define ESG_FUZZ_FUZZ_UTIL_H_

#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <string_view>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/status.h"
#include "absl/strings/string_view.h"
#include "estimator/channels.h"
#include "estimator/telemetry.h"

namespace esg::fuzz {

// Aborts with the violated property and a note (e.g. a status message) on stderr.
[[noreturn]] inline void Violated(const char* property, std::string_view note, const char* file,
                                  int line) {
  std::fprintf(stderr, "%s:%d: property violated: %s\n  %.*s\n", file, line, property,
               static_cast<int>(note.size()), note.data());
  std::abort();
}

#define ESG_FUZZ_CHECK(cond, note)                                         \
  do {                                                                     \
    if (!(cond)) ::esg::fuzz::Violated(#cond, (note), __FILE__, __LINE__); \
  } while (false)

// A refused input must be refused with `code` and a message that says why.
inline void CheckCleanError(const absl::Status& status, absl::StatusCode code) {
  ESG_FUZZ_CHECK(status.code() == code, status.ToString());
  ESG_FUZZ_CHECK(!status.message().empty(), status.ToString());
}

inline std::string_view AsText(const uint8_t* data, size_t size) {
  return std::string_view(reinterpret_cast<const char*>(data), size);
}

// Abseil 20220623 in Debian has its own absl::string_view (not std::string_view).
inline absl::string_view AsAbslText(const uint8_t* data, size_t size) {
  return absl::string_view(reinterpret_cast<const char*>(data), size);
}

inline bool SameBits(double a, double b) {
  return std::bit_cast<uint64_t>(a) == std::bit_cast<uint64_t>(b);
}
template <typename A, typename B>
bool SameBits(const A& a, const B& b) {
  if (a.size() != b.size()) return false;
  for (int i = 0; i < a.size(); ++i) {
    if (!SameBits(a(i), b(i))) return false;
  }
  return true;
}

inline bool IsFinite(const Eigen::Vector3d& v) { return v.allFinite(); }

// |norm - 1| within the readers' tolerance (and renormalised beyond 1e-12, so within ~1e-12).
inline bool IsUnit(double norm) { return std::abs(norm - 1.0) <= 1e-9; }

// What every accepted recording satisfies (formats/recording_csv.h, formats/column_mapping.h):
// times strictly increase, spin axes and valid star-tracker quaternions are finite and unit,
// voltages finite.
inline void CheckRecordingInvariants(const estimator::Recording& recording) {
  for (size_t i = 0; i < recording.frames.size(); ++i) {
    const estimator::TelemetryFrame& f = recording.frames[i];
    if (i > 0) ESG_FUZZ_CHECK(recording.frames[i - 1].time < f.time, "times strictly increase");
    ESG_FUZZ_CHECK(f.time != absl::InfinitePast() && f.time != absl::InfiniteFuture(),
                   "finite time");
    for (const auto& g : f.gyros) {
      if (!g.has_value()) continue;
      ESG_FUZZ_CHECK(IsFinite(g->h_k) && IsUnit(g->h_k.norm()), "unit spin axis");
      if (g->u_k_mv.has_value()) ESG_FUZZ_CHECK(IsFinite(*g->u_k_mv), "finite voltages");
    }
    if (f.star_tracker.has_value() && f.star_tracker->valid) {
      const Eigen::Vector4d q = f.star_tracker->q_in_b.coeffs();
      ESG_FUZZ_CHECK(q.allFinite() && IsUnit(q.norm()), "unit star-tracker quaternion");
    }
    // Channels (estimator/channels.h): at most kMaxChannels, valid names once each in name
    // order, finite values.
    ESG_FUZZ_CHECK(f.channels.size() <= estimator::kMaxChannels, "at most 64 channels");
    const estimator::ChannelValue* previous = nullptr;
    for (const estimator::ChannelValue& c : f.channels) {
      ESG_FUZZ_CHECK(estimator::ValidateChannelName(c.name, "name").ok(), c.name);
      ESG_FUZZ_CHECK(std::isfinite(c.value), "finite channel value");
      ESG_FUZZ_CHECK(previous == nullptr || previous->name < c.name, "channels in name order");
      previous = &c;
    }
  }
}

// Bit for bit: times, gyro readings, channels, star-tracker readings (the quaternion only when
// valid).
inline bool SameFrames(const estimator::Recording& a, const estimator::Recording& b) {
  if (a.frames.size() != b.frames.size()) return false;
  for (size_t i = 0; i < a.frames.size(); ++i) {
    const estimator::TelemetryFrame& x = a.frames[i];
    const estimator::TelemetryFrame& y = b.frames[i];
    if (x.time != y.time) return false;
    for (size_t k = 0; k < x.gyros.size(); ++k) {
      if (x.gyros[k].has_value() != y.gyros[k].has_value()) return false;
      if (!x.gyros[k].has_value()) continue;
      if (!SameBits(x.gyros[k]->h_k, y.gyros[k]->h_k)) return false;
      if (x.gyros[k]->u_k_mv.has_value() != y.gyros[k]->u_k_mv.has_value()) return false;
      if (x.gyros[k]->u_k_mv.has_value() && !SameBits(*x.gyros[k]->u_k_mv, *y.gyros[k]->u_k_mv)) {
        return false;
      }
    }
    if (x.channels.size() != y.channels.size()) return false;
    auto cy = y.channels.begin();
    for (const estimator::ChannelValue& cx : x.channels) {
      if (cx.name != cy->name || !SameBits(cx.value, cy->value)) return false;
      ++cy;
    }
    if (x.star_tracker.has_value() != y.star_tracker.has_value()) return false;
    if (!x.star_tracker.has_value()) continue;
    if (x.star_tracker->valid != y.star_tracker->valid) return false;
    if (x.star_tracker->valid && !SameBits(Eigen::Vector4d(x.star_tracker->q_in_b.coeffs()),
                                           Eigen::Vector4d(y.star_tracker->q_in_b.coeffs()))) {
      return false;
    }
  }
  return true;
}

}  // namespace esg::fuzz

#endif  // ESG_FUZZ_FUZZ_UTIL_H_
