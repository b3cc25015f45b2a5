// The skeleton of the subscription reactors (SubscribeAlerts in alert_reactor.cc,
// SubscribeEstimates in estimate_reactor.cc): replay from the database, then live, with no gap
// and no duplicate.
//
// The reactor subscribes to the live feed (a Hub, hub.h) first and replays the store afterwards;
// live records published meanwhile are buffered. At the end of the replay it releases the buffer
// and, when the request asks for it (replay_marker), queues the end-of-replay marker; from then on
// live records are queued as published. Everything committed before the subscription is in the
// store and everything committed after it is published to the subscription, so nothing falls
// between replay and live; what both hold is kept out by the Feed's dedupe rule (Admit). How the
// store is read (pages read as the client keeps up, for both) is the reactor's own part.
//
// A Feed is the per-stream state of one kind of record, guarded by the stream's lock:
//   using Record, Message                      the hub's record, the streamed message (which has
//                                              a replay_complete field: the marker)
//   static constexpr size_t kMaxQueued         a stream with this many messages waiting, or
//   static constexpr size_t kMaxBuffered       this many live records buffered during the
//                                              replay, is finished with RESOURCE_EXHAUSTED and
//   static std::string TooSlowMessage()        this message
//   static std::string DroppedMessage(why)     the message of a stream dropped because the
//                                              unread messages of its caller, or of all
//                                              subscribers, reached their bound (`why`, from
//                                              QueueBudget)
//   static std::string ReplayStoppedMessage(   the message of a stream finished because a page
//       size_t records, int64_t bytes,         of its replay (`records` read, about `bytes` on
//       absl::string_view why)                 the heap) would pass its caller's or all
//                                              subscribers' bound (`why`, from QueueBudget)
//   static Message ToProto(const Record&)
//   static int64_t RecordBytes(const Record&)  about what a record holds on the heap (charged
//                                              to the QueueBudget while it is buffered or read)
//   bool Admit(const Record&, bool replaying)  the dedupe rule: whether to queue the record;
//                                              `replaying` until the buffer has been released
//   void ReplayComplete()                      the buffer has been released
//   int64_t Forget()                           the stream is finished: drops the dedupe state
//                                              and returns about the bytes it held
//
// Bounds (docs/service.md "Limits"): the stream holds its caller's subscription slot (a Permit)
// from its start until it is finished, and charges every queued message to its caller's
// QueueBudget account until the message is written, every live record buffered during the
// replay until it is released (a replay read as the client keeps up may take long), and every
// page of the replay from its read until its records are queued (OfferPage). Finishing
// the stream (an error, a cancel, a drop) gives back the slot, discards what is still queued and
// buffered and the Feed's dedupe state, and notes the freed memory (memory_release.h), so a
// dropped or cancelled subscriber's memory is returned at once, not when gRPC is done with the
// call (which waits for a client that does not read to take what was written before).
//
// Lifetime: the hub's listener and closer hold the Shared state weakly, since a closer may run
// (CloseAll calls them outside the hub's lock) after OnDone has unsubscribed and deleted the
// reactor; `reactor` is null from then on.
#ifndef ESG_SERVER_SUBSCRIPTION_REACTOR_H_
#define ESG_SERVER_SUBSCRIPTION_REACTOR_H_

#include <cstdint>
#include <deque>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "grpcpp/support/server_callback.h"
#include "proto/convert.h"
#include "server/call_counter.h"
#include "server/estimation_core.h"
#include "server/grpc_status.h"
#include "server/hub.h"
#include "server/memory_release.h"
#include "server/queue_budget.h"

namespace esg::server {

template <typename Feed>
class SubscriptionReactor : public grpc::ServerWriteReactor<typename Feed::Message> {
 public:
  using Record = typename Feed::Record;
  using Message = typename Feed::Message;

  void OnWriteDone(bool ok) override {
    {
      absl::MutexLock lock(&shared_->mu);
      shared_->writing = false;
      if (!ok) {
        FinishOnce(*shared_, absl::CancelledError("the client went away"));
        return;
      }
      shared_->hold.queue.Refund(shared_->queue.front().bytes);
      shared_->queue.pop_front();
    }
    Pump();
  }

  void OnCancel() override {
    absl::MutexLock lock(&shared_->mu);
    FinishOnce(*shared_, absl::CancelledError("the client went away"));
  }

  void OnDone() override {
    if (subscription_ != 0) hub_->Unsubscribe(subscription_);
    {
      absl::MutexLock lock(&shared_->mu);
      shared_->reactor = nullptr;
    }
    delete this;
  }

 protected:
  struct Shared {
    absl::Mutex mu;
    SubscriptionReactor* reactor ABSL_GUARDED_BY(mu) = nullptr;
    bool replaying ABSL_GUARDED_BY(mu) = true;
    bool marker ABSL_GUARDED_BY(mu) = false;  // the request asked for the end-of-replay marker
    std::vector<Record> buffered ABSL_GUARDED_BY(mu);  // live records published during the replay
    // Each queued message with the bytes charged for it (QueueBudget); the front one is being
    // written while `writing`.
    struct Queued {
      Message message;
      int64_t bytes = 0;
    };
    std::deque<Queued> queue ABSL_GUARDED_BY(mu);
    SubscriptionHold hold ABSL_GUARDED_BY(mu);
    bool writing ABSL_GUARDED_BY(mu) = false;
    bool finished ABSL_GUARDED_BY(mu) = false;
    Feed feed ABSL_GUARDED_BY(mu);
  };

  // `hold` not OK: the stream is refused with its status (by Accept).
  SubscriptionReactor(CallCounter* calls, EstimationCore* core, Hub<Record>* hub,
                      absl::StatusOr<SubscriptionHold> hold)
      : token_(calls), core_(core), hub_(hub), shared_(std::make_shared<Shared>()) {
    absl::MutexLock lock(&shared_->mu);
    shared_->reactor = this;
    if (hold.ok()) {
      shared_->hold = *std::move(hold);
    } else {
      refused_ = hold.status();
    }
  }

  // Checks the hold (role, routing scope and subscription slot, checked by the service), then that the request's spacecraft is empty or configured, then its `since`.
  // On an error finishes the stream with it (InvalidArgument "since: ..." for a bad time) and
  // returns false. Otherwise sets *since to the start of the replay (InfiniteFuture: no replay),
  // remembers whether the marker is asked for and returns true.
  template <typename Request>
  bool Accept(const Request& request, absl::Time* since) {
    absl::Status auth = refused_;
    if (auth.ok()) auth = core_->CheckSpacecraft(request.spacecraft_id());
    *since = absl::InfiniteFuture();
    if (auth.ok() && request.has_since()) {
      absl::StatusOr<absl::Time> t = proto_convert::TimeFromProto(request.since());
      if (t.ok()) {
        *since = *t;
      } else {
        auth =
            absl::InvalidArgumentError(std::string("since: ") + std::string(t.status().message()));
      }
    }
    absl::MutexLock lock(&shared_->mu);
    if (!auth.ok()) {
      FinishOnce(*shared_, auth);
      return false;
    }
    shared_->marker = request.replay_marker();
    return true;
  }

  // Subscribes to the live feed of `spacecraft_id` (empty: every spacecraft): records are
  // buffered while replaying and queued afterwards; the hub's CloseAll finishes the stream with
  // UNAVAILABLE.
  void Subscribe(const std::string& spacecraft_id) {
    std::weak_ptr<Shared> weak = shared_;
    subscription_ = hub_->Subscribe(
        spacecraft_id,
        [weak](const Record& r) {
          std::shared_ptr<Shared> s = weak.lock();
          if (s == nullptr) return;
          absl::MutexLock lock(&s->mu);
          if (s->finished) return;
          if (s->replaying) {
            if (s->buffered.size() >= Feed::kMaxBuffered) {
              TooSlow(*s);
              return;
            }
            if (absl::Status charged = s->hold.queue.Charge(Feed::RecordBytes(r));
                !charged.ok()) {
              FinishOnce(*s,
                         absl::ResourceExhaustedError(Feed::DroppedMessage(charged.message())));
              return;
            }
            s->buffered.push_back(r);
          } else {
            Offer(*s, r);
            TryWrite(*s);
          }
        },
        [weak]() {
          std::shared_ptr<Shared> s = weak.lock();
          if (s == nullptr) return;
          absl::MutexLock lock(&s->mu);
          FinishOnce(*s, absl::UnavailableError("the server is shutting down"));
        });
  }

  // Runs after each completed write (and wherever the reactor calls it): writes what is queued.
  // A reactor whose replay goes on while writes complete overrides it.
  virtual void Pump() {
    absl::MutexLock lock(&shared_->mu);
    TryWrite(*shared_);
  }

  // At the top of a replaying reactor's Pump, under the lock: whether to read the next page of
  // the replay now. Otherwise it has done what there is to do: nothing (the stream is finished),
  // written what is queued (the replay is over, or the client has not yet taken the last page),
  // or completed the replay (`last_page_read`).
  static bool ReadyForPage(Shared& s, bool last_page_read) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    if (s.finished) return false;
    if (!s.replaying || !s.queue.empty()) {
      TryWrite(s);
      return false;
    }
    if (last_page_read) {
      CompleteReplay(s);
      return false;
    }
    return true;
  }

  // A page of the replay, read outside the lock (`read` its status, `page` null when it failed):
  // charged to the caller's
  // QueueBudget account from the read until its records are queued, each then charged as a
  // message, so a client that does not read holds one page at most. A failed read, or a page
  // that would take the caller or all subscribers beyond their bound (RESOURCE_EXHAUSTED,
  // Feed::ReplayStoppedMessage), finishes the stream. Returns whether the stream goes on.
  static bool OfferPage(Shared& s, const absl::Status& read, const std::vector<Record>* page)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    if (s.finished) return false;
    if (!read.ok()) {
      FinishOnce(s, read);
      return false;
    }
    const int64_t page_bytes = BufferedBytes(*page);
    if (absl::Status charged = s.hold.queue.Charge(page_bytes); !charged.ok()) {
      FinishOnce(s, absl::ResourceExhaustedError(
                        Feed::ReplayStoppedMessage(page->size(), page_bytes, charged.message())));
      NoteFreedMemory(page_bytes);
      return false;
    }
    for (const Record& r : *page) Offer(s, r);
    s.hold.queue.Refund(page_bytes);
    return !s.finished;
  }

  // Queues `r` if the Feed admits it; a full queue (TooSlow), or a charge its caller's or all
  // subscribers' QueueBudget refuses, finishes the stream with RESOURCE_EXHAUSTED.
  static void Offer(Shared& s, const Record& r) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    if (s.finished || !s.feed.Admit(r, s.replaying)) return;
    if (s.queue.size() >= Feed::kMaxQueued) {
      TooSlow(s);
      return;
    }
    typename Shared::Queued queued{Feed::ToProto(r), 0};
    // The message object and its serialized size: about what it holds on the heap.
    queued.bytes = static_cast<int64_t>(sizeof(Message) + queued.message.ByteSizeLong());
    if (absl::Status charged = s.hold.queue.Charge(queued.bytes); !charged.ok()) {
      FinishOnce(s, absl::ResourceExhaustedError(Feed::DroppedMessage(charged.message())));
      return;
    }
    s.queue.push_back(std::move(queued));
  }

  // The end of the replay: the live records buffered meanwhile (still under the replay's dedupe
  // rule), then the marker if asked for; live records are queued as published from now on.
  static void CompleteReplay(Shared& s) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    std::vector<Record> buffered;  // Offer may finish the stream, which clears s.buffered
    buffered.swap(s.buffered);
    s.hold.queue.Refund(BufferedBytes(buffered));  // each is charged as a message instead
    for (const Record& r : buffered) Offer(s, r);
    s.replaying = false;
    s.feed.ReplayComplete();
    if (s.marker && !s.finished) {
      typename Shared::Queued marker;
      marker.message.set_replay_complete(true);
      s.queue.push_back(std::move(marker));
    }
    TryWrite(s);
  }

  static void TryWrite(Shared& s) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    if (s.finished || s.writing || s.reactor == nullptr || s.queue.empty()) return;
    s.writing = true;
    s.reactor->StartWrite(&s.queue.front().message);
  }

  // Finishes the stream with `status` unless it is finished already or the reactor is gone;
  // gives back the subscription slot and discards the queue (all but a message being written)
  // and the buffer.
  static void FinishOnce(Shared& s, const absl::Status& status)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    if (s.finished || s.reactor == nullptr) return;
    s.finished = true;
    s.reactor->Finish(ToGrpcStatus(status));
    s.hold.permit.Release();
    int64_t freed = 0;
    while (s.queue.size() > (s.writing ? 1u : 0u)) {
      freed += s.queue.back().bytes;
      s.hold.queue.Refund(s.queue.back().bytes);
      s.queue.pop_back();
    }
    const int64_t buffered = BufferedBytes(s.buffered);
    s.hold.queue.Refund(buffered);
    freed += buffered;
    std::vector<Record>().swap(s.buffered);
    freed += s.feed.Forget();
    NoteFreedMemory(freed);
  }

  static int64_t BufferedBytes(const std::vector<Record>& records) {
    int64_t bytes = 0;
    for (const Record& r : records) bytes += Feed::RecordBytes(r);
    return bytes;
  }

  static void TooSlow(Shared& s) ABSL_EXCLUSIVE_LOCKS_REQUIRED(s.mu) {
    FinishOnce(s, absl::ResourceExhaustedError(Feed::TooSlowMessage()));
  }

  EstimationCore* core() const { return core_; }
  Shared& shared() { return *shared_; }

 private:
  CallCounter::Token token_;
  EstimationCore* const core_;
  Hub<Record>* const hub_;
  std::shared_ptr<Shared> shared_;
  int64_t subscription_ = 0;
  absl::Status refused_;  // the hold's refusal
};

}  // namespace esg::server

#endif  // ESG_SERVER_SUBSCRIPTION_REACTOR_H_
