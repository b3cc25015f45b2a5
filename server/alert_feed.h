// AlertFeed: the per-stream state of a SubscribeAlerts stream (the Feed of
// subscription_reactor.h): which state of each alert the stream has sent, so that the replay and
// the live alerts give no duplicate and no older state after a newer one.
//
// Bound: after the replay, the stream remembers the last state sent of the kRemembered alerts it
// touched most recently (at most twice as many between trims, about 100 bytes each), so a stream
// that reads for months holds a bounded map, not one node per alert it ever sent. An alert it no
// longer remembers is one not published for the last kRemembered alerts; its next state is sent
// whatever it is: at worst a state the subscriber already has, never a state lost. The two rules
// that need memory act within moments of a commit (a live state the replay already sent; an
// acknowledgement published before the older unacknowledged state), long before an alert is
// forgotten. During the replay nothing is forgotten: its merge with the live alerts buffered
// meanwhile needs every replayed state (the replay is bounded by the caller's queue budget).
#ifndef ESG_SERVER_ALERT_FEED_H_
#define ESG_SERVER_ALERT_FEED_H_

#include <cstddef>
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <tuple>
#include <utility>

#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "esg/v1/attitude.pb.h"
#include "storage/alert_store.h"
#include "storage/records.h"

namespace esg::server {

class AlertFeed {
 public:
  using Record = storage::AlertRecord;
  using Message = esg::v1::Alert;
  static constexpr size_t kMaxQueued = 100000;
  // The replay is read as the client keeps up, so the live alerts buffered meanwhile are bounded
  // like the queue (and charged to the QueueBudget).
  static constexpr size_t kMaxBuffered = kMaxQueued;
  // Alerts whose last sent state is remembered after the replay (bound above).
  static constexpr size_t kRemembered = 10000;

  static std::string TooSlowMessage();
  static std::string DroppedMessage(absl::string_view why);
  static std::string ReplayStoppedMessage(size_t records, int64_t bytes, absl::string_view why);
  static Message ToProto(const Record& r);
  static int64_t RecordBytes(const Record& r);

  // Whether to queue `r`: not if that state of the alert was already queued. While the replay is
  // merged with the changes buffered during it, their order is unknown, so only a newer state is
  // queued (a count that grew, an acknowledgement, a clear, a revision). Live changes come in
  // commit order (AlertHub), so any state other than the last one sent is queued: a re-run over a
  // late frame may set a repeat count back or undo a clear (docs/service.md "Several ground
  // stations"), and the subscriber must end with the stored state.
  bool Admit(const Record& r, bool replaying);
  // The replay's buffer has been released: from now on the map is trimmed to its bound.
  void ReplayComplete();
  // The stream is finished: drops the map and returns about the bytes it held.
  int64_t Forget();
  // Alerts remembered now (for tests).
  size_t remembered() const { return sent_.size(); }

  // The replay: the request's spacecraft ("" for all), since (InfiniteFuture: no replay),
  // include_revised, and where the read stands (the last alert read; nullopt before the first
  // page); `read` once the last page was read.
  std::string spacecraft_id;
  absl::Time since = absl::InfiniteFuture();
  bool include_revised = false;
  std::optional<storage::AlertPosition> after;
  bool read = false;

 private:
  // repeat_count, acknowledged, cleared, revised (a re-run over a late frame superseded it)
  using Version = std::tuple<int64_t, bool, bool, bool>;
  using Key = std::pair<std::string, int64_t>;  // spacecraft, sequence
  struct Sent {
    Version version;
    uint64_t touched = 0;  // when the alert was last offered, in offers
  };
  // A map node: the key and value, and the tree's three pointers and colour.
  static constexpr size_t kSentNodeBytes = sizeof(Key) + sizeof(Sent) + 4 * sizeof(void*);

  // Keeps the kRemembered alerts touched last.
  void Trim();

  std::map<Key, Sent> sent_;
  uint64_t offers_ = 0;
  bool replay_complete_ = false;
};

}  // namespace esg::server

#endif  // ESG_SERVER_ALERT_FEED_H_
