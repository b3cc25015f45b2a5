// The acknowledgement invariant of docs/service.md ("Ingest contract") as a property: two
// concurrent senders (two ground stations receiving the same downlink, each with its own
// sequences) send random interleavings of in-order, duplicate, late, conflicting, unstorable and
// oversized frames to the real esgd, which is killed with -9 at random points and restarted;
// the senders reconnect and resend what was not acknowledged, as a client should. Late frames
// within the reorder window (2 h) are accepted and re-run the filter from a window checkpoint,
// kept across the kills. After every run: every frame acknowledged as stored is in the archive
// exactly once with the content that was sent, every duplicate ack names a stored frame or
// measurement, nothing else is archived, and the filter's final state and current coefficient
// history equal an offline run over the merged recording (the archive in time order): the
// state bit for bit, the drift coefficients to 1e-12 deg/h.
//
// Seeds: ESG_ACK_INVARIANT_SEEDS (comma-separated; default "1,2" in CI);
// scripts/ack_invariant.sh runs many.
#include <atomic>
#include <cstdlib>
#include <iostream>
#include <map>
#include <random>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_split.h"
#include "absl/synchronization/mutex.h"
#include "gmock/gmock.h"
#include "google/protobuf/io/coded_stream.h"
#include "google/protobuf/io/zero_copy_stream_impl_lite.h"
#include "gtest/gtest.h"
#include "storage/storage.h"
#include "tests/server/reorder_test_util.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::Daemon;
using ::esg::testing::ExpectDriftCoefficientsEqualOffline;
using ::esg::testing::OfflineCoefficientHistory;
using ::esg::testing::OfflineSessionValues;
using ::esg::testing::SimulateRun;
using ::esg::testing::SimulatedRun;
using ::esg::testing::StoredSessionValues;
using ::esg::testing::TempDir;

// The measurement a frame carries, without the identity (station, sequence) of the frame.
std::string Measurement(esg::v1::TelemetryFrame frame) {
  frame.clear_station_id();
  frame.clear_sequence();
  std::string out;
  {
    google::protobuf::io::StringOutputStream stream(&out);
    google::protobuf::io::CodedOutputStream coded(&stream);
    coded.SetSerializationDeterministic(true);
    frame.SerializeToCodedStream(&coded);
  }
  return out;
}

enum class Kind { kInOrder, kDuplicate, kConflict, kLate, kUnstorable, kOversized };

struct Sent {
  Kind kind = Kind::kInOrder;
  int index = 0;  // into the timeline
  esg::v1::TelemetryFrame frame;
};

struct Acked {
  Sent sent;
  esg::v1::TelemetryAck ack;
};

// The daemon under test, restarted by the controller; senders read its current port.
class DaemonSlot {
 public:
  DaemonSlot(std::string db, std::string log) : db_(std::move(db)), log_(std::move(log)) {
    Restart();
  }
  void Restart() {
    absl::MutexLock lock(&mu_);
    if (daemon_) daemon_->Stop(SIGKILL);
    daemon_.reset();
    daemon_ = std::make_unique<Daemon>(db_, log_);
    ++generation_;
  }
  void Stop() {
    absl::MutexLock lock(&mu_);
    daemon_.reset();  // SIGTERM: graceful
  }
  std::unique_ptr<esg::v1::EstimationService::Stub> Stub() {
    absl::MutexLock lock(&mu_);
    return daemon_->Stub();
  }

 private:
  const std::string db_;
  const std::string log_;
  absl::Mutex mu_;
  std::unique_ptr<Daemon> daemon_ ABSL_GUARDED_BY(mu_);
  int generation_ ABSL_GUARDED_BY(mu_) = 0;
};

// One ground station's sender: a random script over the timeline, sent in windows of 1-8
// frames; after a broken stream it reconnects and resends the in-order frames not acknowledged.
// The reserved frames are left out of the script: SendLate sends one after the script.
class Sender {
 public:
  Sender(std::string station, const std::vector<esg::v1::TelemetryFrame>& timeline,
         uint64_t seed, std::set<int> reserved)
      : station_(std::move(station)), timeline_(timeline), rng_(seed),
        reserved_(std::move(reserved)) {
    BuildScript();
  }

  // Sends one frame late, on a stream of its own, and keeps its acknowledgement.
  void SendLate(DaemonSlot& slot, int index) {
    const Sent sent{Kind::kLate, index, Frame(index)};
    auto stub = slot.Stub();
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    auto stream = stub->StreamTelemetry(&context);
    esg::v1::TelemetryAck ack;
    const bool acknowledged = stream->Write(sent.frame) && stream->Read(&ack);
    stream->WritesDone();
    const grpc::Status status = stream->Finish();
    ASSERT_TRUE(acknowledged) << status.error_message();
    acked_.push_back({sent, ack});
  }

  void Run(DaemonSlot& slot, std::atomic<int64_t>& total_acks) {
    std::vector<Sent> queue = script_;
    size_t next = 0;
    std::vector<Sent> resend;
    int attempts = 0;
    while ((next < queue.size() || !resend.empty()) && attempts < 200) {
      ++attempts;
      auto stub = slot.Stub();
      grpc::ClientContext context;
      context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
      auto stream = stub->StreamTelemetry(&context);
      bool broken = false;
      while (!broken && (next < queue.size() || !resend.empty())) {
        std::vector<Sent> window;
        const size_t want = 1 + rng_() % 8;
        while (window.size() < want && !resend.empty()) {
          window.push_back(resend.front());
          resend.erase(resend.begin());
        }
        while (window.size() < want && next < queue.size()) window.push_back(queue[next++]);
        size_t written = 0;
        for (; written < window.size(); ++written) {
          if (!stream->Write(window[written].frame)) break;
        }
        size_t read = 0;
        for (; read < written; ++read) {
          esg::v1::TelemetryAck ack;
          if (!stream->Read(&ack)) break;
          acked_.push_back({window[read], ack});
          ++total_acks;
        }
        if (read < window.size()) {
          broken = true;
          // Not acknowledged: an in-order frame is resent (the client still has it); the
          // others were tests of refusals and are dropped.
          for (size_t k = read; k < window.size(); ++k) {
            if (window[k].kind == Kind::kInOrder) resend.push_back(window[k]);
          }
        }
      }
      stream->WritesDone();
      stream->Finish();
      if (broken) absl::SleepFor(absl::Milliseconds(20));
    }
    EXPECT_LT(attempts, 200) << station_ << " could not finish its script";
  }

  const std::vector<Acked>& acked() const { return acked_; }
  const std::string& station() const { return station_; }

 private:
  esg::v1::TelemetryFrame Frame(int index) const {
    esg::v1::TelemetryFrame f = timeline_[index];
    f.set_station_id(station_);
    f.set_sequence(index + 1);  // each station numbers the pass from 1
    return f;
  }

  void BuildScript() {
    std::vector<int> skipped;
    std::vector<int> sent;
    for (int i = 0; i < static_cast<int>(timeline_.size()); ++i) {
      if (reserved_.count(i) > 0) continue;
      const int dice = static_cast<int>(rng_() % 100);
      if (dice < 8) {  // skipped now, sent late
        skipped.push_back(i);
        continue;
      }
      if (dice < 12) {
        esg::v1::TelemetryFrame f = Frame(i);
        f.mutable_time()->set_seconds(10413792000);  // year 2300: storage cannot hold it
        script_.push_back({Kind::kUnstorable, i, f});
      } else if (dice < 16) {
        esg::v1::TelemetryFrame f = Frame(i);
        f.mutable_gyros(0)->mutable_u_k_mv()->Resize(2000, 1.0);  // 16 kB
        script_.push_back({Kind::kOversized, i, f});
      }
      script_.push_back({Kind::kInOrder, i, Frame(i)});
      sent.push_back(i);
      const int extra = static_cast<int>(rng_() % 100);
      if (extra < 8 && !sent.empty()) {
        script_.push_back({Kind::kDuplicate, sent[rng_() % sent.size()], {}});
        script_.back().frame = Frame(script_.back().index);
      } else if (extra < 14 && !sent.empty()) {
        const int j = sent[rng_() % sent.size()];
        esg::v1::TelemetryFrame f = Frame(j);
        f.mutable_gyros(1)->set_h_k(2, f.gyros(1).h_k(2) + 1e-6);
        script_.push_back({Kind::kConflict, j, f});
      } else if (extra < 20 && !skipped.empty()) {
        const int j = skipped.back();
        skipped.pop_back();
        script_.push_back({Kind::kLate, j, Frame(j)});
      }
    }
  }

  const std::string station_;
  const std::vector<esg::v1::TelemetryFrame>& timeline_;
  std::mt19937_64 rng_;
  const std::set<int> reserved_;
  std::vector<Sent> script_;
  std::vector<Acked> acked_;
};

std::vector<uint64_t> Seeds() {
  const char* env = std::getenv("ESG_ACK_INVARIANT_SEEDS");
  std::vector<uint64_t> seeds;
  for (absl::string_view part : absl::StrSplit(env != nullptr ? env : "1,2", ',',
                                               absl::SkipEmpty())) {
    uint64_t seed = 0;
    if (absl::SimpleAtoi(part, &seed)) seeds.push_back(seed);
  }
  return seeds;
}

void RunOnce(uint64_t seed) {
  SCOPED_TRACE(::testing::Message() << "seed " << seed);
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("PROP-1", 4.0, 41));
  const std::vector<esg::v1::TelemetryFrame>& timeline = run->frames;
  TempDir dir;
  const std::string db = dir.File("var/esg.db");
  DaemonSlot slot(db, dir.File("esgd.log"));
  {
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(slot.Stub()->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run->config), &r).ok());
  }
  // A frame neither station sends in its script, 30 frames before the end of the pass: sent
  // late once both scripts are done, it is within the reorder window and nobody has stored its
  // time, so it must be stored. (Whether a late frame of a script is stored depends on the race
  // with the other station, which may have stored the same time first.)
  const int reserved = static_cast<int>(timeline.size()) - 30;
  Sender a("GS-1", timeline, seed * 1000 + 1, {reserved});
  Sender b("GS-2", timeline, seed * 1000 + 2, {reserved});
  std::atomic<int64_t> total_acks{0};
  std::atomic<bool> done{false};
  std::atomic<int> kills{0};
  std::mt19937_64 rng(seed);
  // kill -9 after a random number of acknowledgements, twice.
  std::thread controller([&] {
    for (int kill = 0; kill < 2 && !done; ++kill) {
      const int64_t at = total_acks + 40 + static_cast<int64_t>(rng() % 160);
      while (!done && total_acks < at) absl::SleepFor(absl::Milliseconds(1));
      if (done) break;
      slot.Restart();
      ++kills;
    }
  });
  std::thread ta([&] { a.Run(slot, total_acks); });
  std::thread tb([&] { b.Run(slot, total_acks); });
  ta.join();
  tb.join();
  done = true;
  controller.join();
  ASSERT_NO_FATAL_FAILURE(a.SendLate(slot, reserved));
  EXPECT_TRUE(a.acked().back().ack.accepted() && !a.acked().back().ack.duplicate())
      << "a late frame within the reorder window that no station had sent was not stored: "
      << a.acked().back().ack.rejection().reason();
  slot.Stop();
  EXPECT_EQ(kills, 2) << "the senders finished before the daemon was killed twice";

  // The archive after a graceful stop.
  auto storage = storage::Storage::Open(db);
  ASSERT_TRUE(storage.ok()) << storage.status();
  auto archived = (*storage)->archive().ReadTimeRange("PROP-1", absl::InfinitePast(),
                                                      absl::InfiniteFuture());
  ASSERT_TRUE(archived.ok());
  std::map<std::pair<std::string, int64_t>, std::string> by_identity;  // -> measurement
  std::map<int64_t, std::string> by_time;                              // unix s -> measurement
  std::vector<esg::v1::TelemetryFrame> archived_frames;
  for (const storage::ArchivedFrame& f : *archived) {
    esg::v1::TelemetryFrame proto;
    ASSERT_TRUE(proto.ParseFromString(f.payload));
    const std::string m = Measurement(proto);
    ASSERT_TRUE(by_identity.emplace(std::make_pair(f.station_id, f.sequence), m).second)
        << "identity stored twice";
    ASSERT_TRUE(by_time.emplace(proto.time().seconds(), m).second) << "time stored twice";
    // Nothing else: every stored frame is a timeline frame, under its sender's numbering,
    // never a conflicting, unstorable or oversized variant.
    const int index = static_cast<int>(f.sequence) - 1;
    ASSERT_GE(index, 0);
    ASSERT_LT(index, static_cast<int>(timeline.size()));
    EXPECT_EQ(m, Measurement(timeline[index])) << f.station_id << " " << f.sequence;
    archived_frames.push_back(proto);
  }
  int stored_acks = 0, duplicate_acks = 0, refusals = 0, late_stored = 0;
  std::set<int> acknowledged_in_order;
  for (const Sender* sender : {&a, &b}) {
    for (const Acked& x : sender->acked()) {
      EXPECT_EQ(x.ack.station_id(), sender->station());
      EXPECT_EQ(x.ack.sequence(), x.sent.frame.sequence());
      const std::string m = Measurement(x.sent.frame);
      const auto id = std::make_pair(sender->station(), x.sent.frame.sequence());
      if (x.ack.accepted() && !x.ack.duplicate()) {
        ++stored_acks;
        if (x.sent.kind == Kind::kLate) ++late_stored;
        // Stored exactly once (the maps refuse repeats), with the content that was sent.
        auto it = by_identity.find(id);
        ASSERT_NE(it, by_identity.end()) << "acknowledged as stored, not archived";
        EXPECT_EQ(it->second, m);
      } else if (x.ack.accepted()) {
        ++duplicate_acks;
        auto it = by_identity.find(id);
        auto at = by_time.find(x.sent.frame.time().seconds());
        EXPECT_TRUE((it != by_identity.end() && it->second == m) ||
                    (at != by_time.end() && at->second == m))
            << "a duplicate ack for a frame whose measurement is not stored";
      } else {
        ++refusals;
        // A refusal is never of an exact copy of what is stored under its identity.
        auto it = by_identity.find(id);
        if (it != by_identity.end()) EXPECT_NE(it->second, m);
        switch (x.sent.kind) {
          case Kind::kConflict:
            // Other content under a used identity: a conflict when that measurement is stored;
            // late when the station's original never was.
            EXPECT_EQ(x.ack.rejection().code(),
                      by_time.count(x.sent.frame.time().seconds()) > 0
                          ? grpc::StatusCode::ALREADY_EXISTS
                          : grpc::StatusCode::OUT_OF_RANGE)
                << x.ack.rejection().reason();
            break;
          case Kind::kUnstorable:
            EXPECT_EQ(x.ack.rejection().code(), grpc::StatusCode::OUT_OF_RANGE);
            break;
          case Kind::kOversized:
            EXPECT_EQ(x.ack.rejection().code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
            break;
          default:  // late (by sequence or by time) or conflicting with the other station
            EXPECT_THAT(x.ack.rejection().code(),
                        ::testing::AnyOf(static_cast<int>(grpc::StatusCode::OUT_OF_RANGE),
                                         static_cast<int>(grpc::StatusCode::ALREADY_EXISTS)));
        }
      }
      if (x.sent.kind == Kind::kInOrder) acknowledged_in_order.insert(x.sent.index);
    }
  }
  std::cout << "seed " << seed << ": " << kills << " kill -9, " << archived->size()
            << " frames archived, acks: " << stored_acks << " stored, " << duplicate_acks
            << " duplicate, " << refusals << " refused, " << late_stored
            << " late frames stored\n";
  EXPECT_GT(stored_acks, 100);
  EXPECT_GT(duplicate_acks, 10);
  EXPECT_GT(refusals, 10);
  EXPECT_GT(late_stored, 0) << "no late frame was accepted within the reorder window";
  // Every archived frame was acknowledged (as stored or as a duplicate after a resend).
  for (const auto& [time_s, m] : by_time) {
    bool acknowledged = false;
    for (const Sender* sender : {&a, &b}) {
      for (const Acked& x : sender->acked()) {
        if (x.ack.accepted() && x.sent.frame.time().seconds() == time_s) acknowledged = true;
      }
    }
    EXPECT_TRUE(acknowledged) << "archived but never acknowledged: " << time_s;
  }
  // The kill -9s and late frames changed nothing: the filter's state and its current coefficient
  // history equal an offline run over the merged recording in time order.
  auto history = (*storage)->coefficients().History("PROP-1", 0, absl::InfinitePast(),
                                                   absl::InfiniteFuture());
  ASSERT_TRUE(history.ok()) << history.status();
  auto with_revised = (*storage)->coefficients().History(
      "PROP-1", 0, absl::InfinitePast(), absl::InfiniteFuture(), /*include_revised=*/true);
  ASSERT_TRUE(with_revised.ok());
  std::cout << "seed " << seed << ": " << history->size() << " current estimates, "
            << with_revised->size() - history->size() << " revised\n";
  storage->reset();
  EXPECT_EQ(StoredSessionValues(db, "PROP-1"),
            OfflineSessionValues(run->config, "10+11", archived_frames));
  ASSERT_NO_FATAL_FAILURE(ExpectDriftCoefficientsEqualOffline(
      *history, OfflineCoefficientHistory(run->config, "10+11", archived_frames)));
}

TEST(AckInvariant, RandomInterleavingsWithKillNineKeepEveryAcknowledgementTrue) {
  for (uint64_t seed : Seeds()) RunOnce(seed);
}

}  // namespace
}  // namespace esg::server
