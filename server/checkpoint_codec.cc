// Binary layout of the server checkpoint (see checkpoint_codec.h). Doubles are copied as their
// IEEE-754 bytes so the session resumes bit for bit.
#include "server/checkpoint_codec.h"

#include <cstring>
#include <limits>

#include "absl/strings/str_cat.h"

namespace esg::server {
namespace {

constexpr absl::string_view kMagicV1 = "ESGSRV01";
constexpr absl::string_view kMagicV2 = "ESGSRV02";
constexpr absl::string_view kMagic = "ESGSRV03";

class Writer {
 public:
  void I64(int64_t v) { Raw(&v, sizeof v); }
  void F64(double v) { Raw(&v, sizeof v); }
  void Str(absl::string_view s) {
    I64(static_cast<int64_t>(s.size()));
    out_.append(s.data(), s.size());
  }
  void Time(absl::Time t) {
    I64(t == absl::InfinitePast() ? std::numeric_limits<int64_t>::min() : absl::ToUnixNanos(t));
  }
  std::string& out() { return out_; }

 private:
  void Raw(const void* p, size_t n) { out_.append(static_cast<const char*>(p), n); }
  std::string out_;
};

class Reader {
 public:
  explicit Reader(absl::string_view in) : in_(in) {}
  bool I64(int64_t* v) { return Raw(v, sizeof *v); }
  bool F64(double* v) { return Raw(v, sizeof *v); }
  bool Str(std::string* s) {
    int64_t n = 0;
    if (!I64(&n) || n < 0 || static_cast<size_t>(n) > in_.size() - pos_) return false;
    s->assign(in_.data() + pos_, n);
    pos_ += n;
    return true;
  }
  bool Time(absl::Time* t) {
    int64_t ns = 0;
    if (!I64(&ns)) return false;
    *t = ns == std::numeric_limits<int64_t>::min() ? absl::InfinitePast() : absl::FromUnixNanos(ns);
    return true;
  }
  bool done() const { return pos_ == in_.size(); }
  size_t remaining() const { return in_.size() - pos_; }

 private:
  bool Raw(void* p, size_t n) {
    if (in_.size() - pos_ < n) return false;
    std::memcpy(p, in_.data() + pos_, n);
    pos_ += n;
    return true;
  }
  absl::string_view in_;
  size_t pos_ = 0;
};

}  // namespace

std::string EncodeCheckpoint(const ServerCheckpoint& c) {
  Writer w;
  w.out().append(kMagic.data(), kMagic.size());
  w.Str(c.model);
  w.Time(c.applied_time);
  w.Str(c.applied_station);
  w.I64(c.applied_sequence);
  w.Time(c.effects_written_until);
  w.Str(c.quarantine_reason);
  w.I64(c.rebuilding ? 1 : 0);
  w.Time(c.last_star_tracker_time);
  w.I64(c.frames_applied);
  w.I64(c.frames_apply_failed);
  w.I64(c.star_tracker_rejections);
  w.I64(static_cast<int64_t>(c.alert_tracks.size()));
  for (const AlertTrack& t : c.alert_tracks) {
    w.Str(t.reason);
    w.Str(t.subsystem);
    w.I64(t.sequence);
    w.I64(t.repeat_count);
    w.Time(t.last_time);
  }
  w.I64(c.session.has_value() ? 1 : 0);
  if (c.session.has_value()) {
    w.I64(c.session->version);
    w.I64(static_cast<int64_t>(c.session->values.size()));
    for (double v : c.session->values) w.F64(v);
  }
  return std::move(w.out());
}

absl::StatusOr<ServerCheckpoint> DecodeCheckpoint(absl::string_view blob) {
  const auto bad = [](absl::string_view what) {
    return absl::DataLossError(absl::StrCat("server checkpoint: ", what));
  };
  const bool v1 = blob.substr(0, kMagicV1.size()) == kMagicV1;
  const bool v2 = blob.substr(0, kMagicV2.size()) == kMagicV2;
  if (!v1 && !v2 && blob.substr(0, kMagic.size()) != kMagic) {
    return bad("unknown format (magic)");
  }
  Reader r(blob.substr(kMagic.size()));
  ServerCheckpoint c;
  int64_t n_tracks = 0;
  if (!r.Str(&c.model)) return bad("truncated header");
  if (v1) {
    c.cursor_from_sequence = true;
  } else {
    int64_t rebuilding = 0;
    if (!r.Time(&c.applied_time) || !r.Str(&c.applied_station) || !r.I64(&c.applied_sequence) ||
        !r.Time(&c.effects_written_until) || !r.Str(&c.quarantine_reason) ||
        !r.I64(&rebuilding)) {
      return bad("truncated apply cursor");
    }
    c.rebuilding = rebuilding != 0;
    if (!v2 && !r.Time(&c.last_star_tracker_time)) return bad("truncated apply cursor");
  }
  if (!r.I64(&c.frames_applied) || !r.I64(&c.frames_apply_failed) ||
      !r.I64(&c.star_tracker_rejections) || !r.I64(&n_tracks) || n_tracks < 0 ||
      n_tracks > 100000) {
    return bad("truncated header");
  }
  for (int64_t i = 0; i < n_tracks; ++i) {
    AlertTrack t;
    if (!r.Str(&t.reason) || !r.Str(&t.subsystem) || !r.I64(&t.sequence) ||
        !r.I64(&t.repeat_count) || !r.Time(&t.last_time)) {
      return bad("truncated alert track");
    }
    c.alert_tracks.push_back(std::move(t));
  }
  int64_t has_session = 0;
  if (!r.I64(&has_session)) return bad("truncated session flag");
  if (has_session != 0) {
    estimator::SessionCheckpoint s;
    int64_t version = 0, n = 0;
    if (!r.I64(&version) || !r.I64(&n) || n < 0 ||
        static_cast<uint64_t>(n) > r.remaining() / sizeof(double) ||
        static_cast<size_t>(n) * sizeof(double) != r.remaining()) {
      return bad("truncated session values");
    }
    s.version = static_cast<int>(version);
    s.values.resize(n);
    for (int64_t i = 0; i < n; ++i) r.F64(&s.values[i]);
    c.session = std::move(s);
  }
  if (!r.done()) return bad("trailing bytes");
  return c;
}

}  // namespace esg::server
