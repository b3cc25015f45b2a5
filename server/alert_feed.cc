// AlertFeed (alert_feed.h).
#include "server/alert_feed.h"

#include <algorithm>
#include <vector>

#include "absl/strings/str_cat.h"
#include "server/proto_mapping.h"

namespace esg::server {

std::string AlertFeed::TooSlowMessage() {
  return "alert subscriber too slow: queue limit reached";
}

std::string AlertFeed::DroppedMessage(absl::string_view why) {
  return absl::StrCat("alert subscriber too slow, dropped: ", why,
                      "; subscribe again with since = the latest measurement_time received");
}

std::string AlertFeed::ReplayStoppedMessage(size_t records, int64_t bytes,
                                            absl::string_view why) {
  return absl::StrCat("alert replay stopped: the page of ", records,
                      " stored alerts read for it (", bytes, " bytes) would pass the bound: ", why,
                      "; subscribe again with since = the latest measurement_time received");
}

AlertFeed::Message AlertFeed::ToProto(const Record& r) { return AlertToProto(r); }

int64_t AlertFeed::RecordBytes(const Record& r) {
  return static_cast<int64_t>(sizeof(Record) + r.spacecraft_id.capacity() +
                              r.severity.capacity() + r.reason.capacity() +
                              r.subsystem.capacity() + r.unit.capacity() + r.message.capacity() +
                              r.acknowledged_by.capacity());
}

bool AlertFeed::Admit(const Record& r, bool replaying) {
  const Version v{r.repeat_count, r.acknowledged, r.cleared,
                  r.revised_time != absl::InfinitePast()};
  auto [it, inserted] = sent_.try_emplace({r.spacecraft_id, r.sequence}, Sent{v, 0});
  it->second.touched = ++offers_;
  bool admit = true;
  Version& sent = it->second.version;
  if (!inserted && !replaying) {
    if (v == sent) {
      admit = false;  // the replay already sent this state
    } else if (std::get<1>(sent) && !std::get<1>(v)) {
      // An acknowledgement is never undone: an unacknowledged state after an acknowledged one
      // was read before the acknowledgement committed (a new alert acknowledged between its
      // commit and its publication); the stored alert is acknowledged.
      admit = false;
    } else {
      sent = v;
    }
  } else if (!inserted) {
    const Version old = sent;
    // A revision is news even where a re-run set the repeat count back.
    const bool revision = std::get<3>(v) && !std::get<3>(old);
    if (!revision && std::get<0>(v) <= std::get<0>(old) && std::get<1>(v) <= std::get<1>(old) &&
        std::get<2>(v) <= std::get<2>(old) && std::get<3>(v) <= std::get<3>(old)) {
      admit = false;  // not newer
    } else {
      sent = Version{std::max(std::get<0>(v), std::get<0>(old)),
                     std::get<1>(v) || std::get<1>(old), std::get<2>(v) || std::get<2>(old),
                     std::get<3>(v) || std::get<3>(old)};
    }
  }
  if (replay_complete_ && sent_.size() > 2 * kRemembered) Trim();
  return admit;
}

void AlertFeed::ReplayComplete() {
  replay_complete_ = true;
  if (sent_.size() > kRemembered) Trim();
}

void AlertFeed::Trim() {
  std::vector<uint64_t> touched;
  touched.reserve(sent_.size());
  for (const auto& [key, s] : sent_) touched.push_back(s.touched);
  // The kRemembered largest stamps stay (the stamps are distinct).
  const auto cut = touched.end() - static_cast<std::ptrdiff_t>(kRemembered);
  std::nth_element(touched.begin(), cut, touched.end());
  const uint64_t oldest_kept = *cut;
  for (auto it = sent_.begin(); it != sent_.end();) {
    it = it->second.touched < oldest_kept ? sent_.erase(it) : std::next(it);
  }
}

int64_t AlertFeed::Forget() {
  const int64_t bytes = static_cast<int64_t>(sent_.size() * kSentNodeBytes);
  std::map<Key, Sent>().swap(sent_);
  return bytes;
}

}  // namespace esg::server
