// The per-step estimate archive (docs/service.md "Per-step estimates") against a real esgd on
// loopback over a real SQLite file, through real gRPC calls: the stored estimates equal an offline
// EstimationSession run over the same frames (attitude, 1-sigma, pair, star-tracker innovations
// per gyro id, last star-tracker time); GetEstimateHistory pages and refuses bad requests;
// SubscribeEstimates replays, marks the end of the replay and goes live without gap or duplicate
// while frames are applied during the replay, for one spacecraft or all; the retention prunes
// what it should and nothing else; a restarted server neither loses nor repeats an estimate and
// keeps the last star-tracker time; a late frame's re-run replaces the recomputed steps and
// sends them to subscribers again; shutdown does not wait for open subscriptions.
#include <algorithm>
#include <array>
#include <atomic>
#include <chrono>
#include <cmath>
#include <functional>
#include <map>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/escaping.h"
#include "absl/synchronization/mutex.h"
#include "absl/synchronization/notification.h"
#include "absl/time/clock.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/checkpoint_codec.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/run_process.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::LoopbackServer;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;
using ::testing::StartsWith;

// 13 h of 60 s frames with star-tracker outliers (about 3% of samples, 300-900 arcsec), so that
// some steps reject the star tracker.
const SimulatedRun& Run13h() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("EST-1", 13.0, 41, 0.03));
  return *run;
}

// The run for spacecraft `id`: configuration and frames renamed.
SimulatedRun Renamed(const SimulatedRun& run, const std::string& id) {
  SimulatedRun out = run;
  out.config.spacecraft_id = id;
  for (esg::v1::TelemetryFrame& f : out.frames) f.set_spacecraft_id(id);
  return out;
}

std::vector<esg::v1::TelemetryFrame> Frames(const SimulatedRun& run, size_t from, size_t to) {
  return {run.frames.begin() + from, run.frames.begin() + std::min(to, run.frames.size())};
}

absl::Time TimeOf(const google::protobuf::Timestamp& t) {
  absl::StatusOr<absl::Time> time = proto_convert::TimeFromProto(t);
  EXPECT_TRUE(time.ok()) << time.status();
  return time.value_or(absl::InfinitePast());
}

void Configure(esg::v1::EstimationService::Stub& stub, const SimulatedRun& run) {
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(stub.ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
}

void Stream(esg::v1::EstimationService::Stub& stub, const std::vector<esg::v1::TelemetryFrame>& f) {
  const esg::testing::StreamResult result = StreamFrames(stub, f);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_EQ(result.acks.size(), f.size());
  for (const auto& ack : result.acks) ASSERT_TRUE(ack.accepted()) << ack.rejection().reason();
}

// What an offline run stores at one measurement step, typed out from the estimator's report
// (SI): the innovations two per gyro that has a reading and is not faulty, in Gyros() order.
struct OfflineEstimate {
  absl::Time time;
  esg::v1::SessionState state = esg::v1::SESSION_STATE_UNSPECIFIED;
  bool valid = false;
  Eigen::Quaterniond q_in_b;
  Eigen::Vector3d sigma_b;
  std::array<int, 2> pair = {0, 0};
  std::string invalid_reason;
  bool star_tracker_used = false;
  double test_ratio = 0.0;
  absl::Time last_star_tracker_time = absl::InfinitePast();
  std::vector<int> gyro_order;
  std::map<int, std::array<double, 4>> innovations;  // gyro id -> z1, z2, sigma1, sigma2 [rad]
  // The attitude error estimate of the step's star-tracker update and its 1-sigma [arcsec].
  std::optional<Eigen::Vector3d> attitude_error_b_arcsec;
  std::optional<Eigen::Vector3d> attitude_error_sigma_b_arcsec;
};

std::vector<OfflineEstimate> OfflineEstimates(const estimator::SpacecraftConfig& config,
                                              const std::vector<esg::v1::TelemetryFrame>& frames) {
  auto spec = estimator::ParseModel("10+11");
  EXPECT_TRUE(spec.ok());
  auto session = estimator::EstimationSession::Create(config, estimator::SessionOptions{*spec});
  EXPECT_TRUE(session.ok()) << session.status();
  std::vector<OfflineEstimate> out;
  absl::Time last_used = absl::InfinitePast();
  for (const esg::v1::TelemetryFrame& proto : frames) {
    auto frame = proto_convert::FrameFromProto(proto);
    EXPECT_TRUE(frame.ok()) << frame.status();
    auto report = session->AddFrame(*frame);
    EXPECT_TRUE(report.ok()) << report.status();
    if (!report.ok() || !report->measurement_step) continue;
    if (report->star_tracker_used) last_used = frame->time;
    OfflineEstimate e;
    e.time = frame->time;
    e.state = StateToProto(session->state());
    e.valid = report->attitude.valid;
    e.q_in_b = report->attitude.q_in_b;
    e.sigma_b = report->attitude.sigma_b;
    e.pair = report->attitude.pair;
    e.invalid_reason = report->attitude.invalid_reason;
    e.star_tracker_used = report->star_tracker_used;
    e.test_ratio = report->star_tracker_test_ratio;
    e.last_star_tracker_time = last_used;
    e.attitude_error_b_arcsec = report->attitude_error_b_arcsec;
    e.attitude_error_sigma_b_arcsec = report->attitude_error_sigma_b_arcsec;
    int k = 0;
    const int m = static_cast<int>(report->star_tracker_innovation.size());
    for (const estimator::GyroEstimate& g : session->Gyros()) {
      if (g.faulty || !frame->gyros[g.id - 1].has_value() || 2 * k + 1 >= m) continue;
      e.gyro_order.push_back(g.id);
      e.innovations[g.id] = {report->star_tracker_innovation(2 * k),
                             report->star_tracker_innovation(2 * k + 1),
                             report->star_tracker_innovation_sigma(2 * k),
                             report->star_tracker_innovation_sigma(2 * k + 1)};
      ++k;
    }
    out.push_back(std::move(e));
  }
  return out;
}

// |a - b| within 1e-12 of |b| (plus 1e-300 so that exact zeros compare).
::testing::AssertionResult Near(double a, double b) {
  if (std::abs(a - b) <= 1e-12 * std::abs(b) + 1e-300) return ::testing::AssertionSuccess();
  return ::testing::AssertionFailure() << a << " vs " << b << " (difference " << a - b << ")";
}

void ExpectEqualsOffline(const esg::v1::EstimateRecord& got, const OfflineEstimate& want,
                         const std::string& id) {
  SCOPED_TRACE(FormatUtc(want.time));
  EXPECT_EQ(got.spacecraft_id(), id);
  EXPECT_EQ(TimeOf(got.measurement_time()), want.time);
  EXPECT_EQ(got.state(), want.state);
  EXPECT_FALSE(got.replay_complete());
  ASSERT_EQ(got.has_attitude(), want.valid);
  if (want.valid) {
    const esg::v1::AttitudeSample& a = got.attitude();
    EXPECT_EQ(TimeOf(a.time()), want.time);
    ASSERT_EQ(a.q_in_b_size(), 4);
    EXPECT_GE(a.q_in_b(0), 0.0) << "canonical sign at the output";
    const std::array<double, 4> q = {want.q_in_b.w(), want.q_in_b.x(), want.q_in_b.y(),
                                     want.q_in_b.z()};
    const double sign = q[0] < 0.0 ? -1.0 : 1.0;
    for (int i = 0; i < 4; ++i) EXPECT_TRUE(Near(a.q_in_b(i), sign * q[i])) << "q" << i;
    ASSERT_EQ(a.sigma_arcsec_size(), 3);
    for (int i = 0; i < 3; ++i) {
      EXPECT_TRUE(Near(a.sigma_arcsec(i), estimator::RadToArcsec(want.sigma_b(i)))) << i;
    }
    EXPECT_THAT(got.output_pair(), ::testing::ElementsAre(want.pair[0], want.pair[1]));
    EXPECT_EQ(got.attitude_invalid_reason(), "");
  } else {
    EXPECT_EQ(got.output_pair_size(), 0);
    EXPECT_EQ(got.attitude_invalid_reason(), want.invalid_reason);
  }
  EXPECT_EQ(got.star_tracker_used(), want.star_tracker_used);
  EXPECT_TRUE(Near(got.star_tracker_test_ratio(), want.test_ratio));
  if (want.last_star_tracker_time == absl::InfinitePast()) {
    EXPECT_FALSE(got.has_last_star_tracker_time());
  } else {
    EXPECT_EQ(TimeOf(got.last_star_tracker_time()), want.last_star_tracker_time);
  }
  ASSERT_EQ(static_cast<size_t>(got.star_tracker_innovations_size()), want.gyro_order.size());
  for (int k = 0; k < got.star_tracker_innovations_size(); ++k) {
    const esg::v1::GyroInnovation& g = got.star_tracker_innovations(k);
    EXPECT_EQ(g.gyro_id(), want.gyro_order[k]) << "the session's gyro order";
    const std::array<double, 4>& w = want.innovations.at(want.gyro_order[k]);
    ASSERT_EQ(g.innovation_arcsec_size(), 2);
    ASSERT_EQ(g.sigma_arcsec_size(), 2);
    for (int i = 0; i < 2; ++i) {
      EXPECT_TRUE(Near(g.innovation_arcsec(i), estimator::RadToArcsec(w[i]))) << g.gyro_id();
      EXPECT_TRUE(Near(g.sigma_arcsec(i), estimator::RadToArcsec(w[2 + i]))) << g.gyro_id();
    }
  }
  if (want.attitude_error_b_arcsec.has_value()) {
    ASSERT_EQ(got.attitude_error_b_arcsec_size(), 3);
    ASSERT_EQ(got.attitude_error_sigma_b_arcsec_size(), 3);
    for (int i = 0; i < 3; ++i) {
      EXPECT_TRUE(Near(got.attitude_error_b_arcsec(i), (*want.attitude_error_b_arcsec)(i))) << i;
      EXPECT_TRUE(
          Near(got.attitude_error_sigma_b_arcsec(i), (*want.attitude_error_sigma_b_arcsec)(i)))
          << i;
    }
  } else {
    EXPECT_EQ(got.attitude_error_b_arcsec_size(), 0);
    EXPECT_EQ(got.attitude_error_sigma_b_arcsec_size(), 0);
  }
  EXPECT_TRUE(got.has_compute_time());
}

void ExpectAllEqualOffline(const std::vector<esg::v1::EstimateRecord>& got,
                           const std::vector<OfflineEstimate>& want, const std::string& id) {
  ASSERT_EQ(got.size(), want.size());
  for (size_t k = 0; k < got.size(); ++k) ExpectEqualsOffline(got[k], want[k], id);
}

// GetEstimateHistory over every page; `pages` counts them.
std::vector<esg::v1::EstimateRecord> History(esg::v1::EstimationService::Stub& stub,
                                             const std::string& id, int page_size = 0,
                                             int* pages = nullptr) {
  std::vector<esg::v1::EstimateRecord> out;
  esg::v1::EstimateHistoryRequest request;
  request.set_spacecraft_id(id);
  request.set_page_size(page_size);
  int n = 0;
  do {
    grpc::ClientContext ctx;
    esg::v1::EstimateHistoryResponse page;
    const grpc::Status status = stub.GetEstimateHistory(&ctx, request, &page);
    EXPECT_TRUE(status.ok()) << status.error_message();
    if (!status.ok()) break;
    ++n;
    for (const auto& e : page.estimates()) out.push_back(e);
    request.set_page_token(page.next_page_token());
  } while (!request.page_token().empty());
  if (pages != nullptr) *pages = n;
  return out;
}

// A SubscribeEstimates call read on its own thread.
class Subscriber {
 public:
  Subscriber(esg::v1::EstimationService::Stub& stub, const esg::v1::EstimateSubscription& request) {
    reader_ = stub.SubscribeEstimates(&context_, request);
    thread_ = std::thread([this] {
      esg::v1::EstimateRecord r;
      while (reader_->Read(&r)) {
        absl::MutexLock lock(&mu_);
        got_.push_back(r);
      }
      absl::MutexLock lock(&mu_);
      ended_ = true;
    });
  }
  ~Subscriber() {
    context_.TryCancel();
    if (thread_.joinable()) thread_.join();
  }
  // Polls until `done(received)` or `timeout`; false on timeout.
  bool WaitFor(const std::function<bool(const std::vector<esg::v1::EstimateRecord>&)>& done,
               absl::Duration timeout = absl::Seconds(60)) {
    const absl::Time deadline = absl::Now() + timeout;
    while (absl::Now() < deadline) {
      {
        absl::MutexLock lock(&mu_);
        if (done(got_)) return true;
        if (ended_) return false;
      }
      absl::SleepFor(absl::Milliseconds(5));
    }
    return false;
  }
  std::vector<esg::v1::EstimateRecord> Received() {
    absl::MutexLock lock(&mu_);
    return got_;
  }
  // Waits for the stream to end (the server finished it) and returns its status.
  grpc::Status Finish(absl::Duration timeout = absl::Seconds(10)) {
    const absl::Time deadline = absl::Now() + timeout;
    for (;;) {
      {
        absl::MutexLock lock(&mu_);
        if (ended_) break;
      }
      if (absl::Now() > deadline) context_.TryCancel();
      absl::SleepFor(absl::Milliseconds(5));
    }
    thread_.join();
    return reader_->Finish();
  }

 private:
  grpc::ClientContext context_;
  std::unique_ptr<grpc::ClientReader<esg::v1::EstimateRecord>> reader_;
  std::thread thread_;
  absl::Mutex mu_;
  std::vector<esg::v1::EstimateRecord> got_ ABSL_GUARDED_BY(mu_);
  bool ended_ ABSL_GUARDED_BY(mu_) = false;
};

size_t Markers(const std::vector<esg::v1::EstimateRecord>& got) {
  return std::count_if(got.begin(), got.end(), [](const auto& r) { return r.replay_complete(); });
}

esg::v1::EstimateSubscription Subscription(const std::string& id, bool marker,
                                           std::optional<absl::Time> since) {
  esg::v1::EstimateSubscription s;
  s.set_spacecraft_id(id);
  s.set_replay_marker(marker);
  if (since.has_value()) *s.mutable_since() = proto_convert::TimeToProto(*since);
  return s;
}

TEST(EstimateArchive, StoredEstimatesEqualAnOfflineSessionRunOverTheSameFrames) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun run = Renamed(Run13h(), "EST-OFF");
  const std::vector<esg::v1::TelemetryFrame> frames = Frames(run, 0, 240);
  Configure(*stub, run);
  Stream(*stub, frames);
  ASSERT_TRUE(server.core().WaitApplied("EST-OFF", absl::Seconds(60)).ok());
  const std::vector<OfflineEstimate> offline = OfflineEstimates(run.config, frames);
  ASSERT_GT(offline.size(), 200u);
  // The run exercises both outcomes of the star tracker and three gyros' innovations.
  const auto rejected = std::count_if(offline.begin(), offline.end(),
                                      [](const auto& e) { return !e.star_tracker_used; });
  EXPECT_GT(rejected, 0);
  EXPECT_LT(rejected, static_cast<long>(offline.size()) / 2);
  EXPECT_GE(offline.back().gyro_order.size(), 3u);
  // Every step that applied the star tracker carries an attitude error estimate, no other does.
  for (const OfflineEstimate& e : offline) {
    EXPECT_EQ(e.attitude_error_b_arcsec.has_value(), e.star_tracker_used) << FormatUtc(e.time);
  }
  int pages = 0;
  const std::vector<esg::v1::EstimateRecord> stored = History(*stub, "EST-OFF", 70, &pages);
  ExpectAllEqualOffline(stored, offline, "EST-OFF");
  EXPECT_EQ(pages, static_cast<int>((offline.size() + 69) / 70));
  // A page at the maximum (5000) of such records stays under gRPC's default 4 MB receive limit.
  size_t bytes = 0;
  for (const auto& e : stored) bytes += e.ByteSizeLong();
  const double per_record = static_cast<double>(bytes) / static_cast<double>(stored.size());
  ::testing::Test::RecordProperty("bytes_per_record", std::to_string(per_record));
  EXPECT_LT(per_record * EstimationCore::kMaxEstimatesPageSize, 4.0e6) << per_record;
}

TEST(EstimateArchive, HistoryPagesBySizeAndRefusesBadRequestsNamingTheField) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun run = Renamed(Run13h(), "EST-PAGE");
  Configure(*stub, run);
  // 5100 stored steps (one a second), written straight through the store.
  const absl::Time t0 = absl::FromUnixSeconds(1551398400);
  {
    storage::Storage& storage = server.core().storage();
    auto txn = storage.database().Begin();
    ASSERT_TRUE(txn.ok());
    for (int i = 0; i < 5100; ++i) {
      storage::EstimateRecord r;
      r.spacecraft_id = "EST-PAGE";
      r.measurement_time = t0 + absl::Seconds(i);
      r.compute_time = t0;
      r.state = "CALIBRATING";
      r.star_tracker_test_ratio = i;
      ASSERT_TRUE(storage.estimates().Put(*txn, r).ok());
    }
    ASSERT_TRUE(txn->Commit().ok());
  }
  auto get = [&](const esg::v1::EstimateHistoryRequest& request,
                 esg::v1::EstimateHistoryResponse* response) {
    grpc::ClientContext ctx;
    return stub->GetEstimateHistory(&ctx, request, response);
  };
  esg::v1::EstimateHistoryRequest request;
  request.set_spacecraft_id("EST-PAGE");
  esg::v1::EstimateHistoryResponse page;
  ASSERT_TRUE(get(request, &page).ok());
  EXPECT_EQ(page.estimates_size(), 2000) << "page_size 0 is 2000";
  EXPECT_FALSE(page.next_page_token().empty());
  request.set_page_size(6000);
  ASSERT_TRUE(get(request, &page).ok());
  EXPECT_EQ(page.estimates_size(), 5000) << "above 5000 is 5000";
  // Every record once, in order, over pages of the default size.
  int pages = 0;
  const std::vector<esg::v1::EstimateRecord> all = History(*stub, "EST-PAGE", 0, &pages);
  EXPECT_EQ(pages, 3);
  ASSERT_EQ(all.size(), 5100u);
  for (size_t i = 0; i < all.size(); ++i) {
    ASSERT_EQ(all[i].star_tracker_test_ratio(), static_cast<double>(i));
    EXPECT_FALSE(all[i].has_attitude());
  }
  // from and to inclusive.
  request.set_page_size(0);
  *request.mutable_from() = proto_convert::TimeToProto(t0 + absl::Seconds(10));
  *request.mutable_to() = proto_convert::TimeToProto(t0 + absl::Seconds(20));
  ASSERT_TRUE(get(request, &page).ok());
  ASSERT_EQ(page.estimates_size(), 11);
  EXPECT_EQ(TimeOf(page.estimates(0).measurement_time()), t0 + absl::Seconds(10));
  EXPECT_TRUE(page.next_page_token().empty());
  // A step stored between two pages before the cursor is not repeated; one after it follows.
  request.set_page_size(5);
  ASSERT_TRUE(get(request, &page).ok());
  ASSERT_EQ(page.estimates_size(), 5);
  {
    storage::EstimateRecord r;
    r.spacecraft_id = "EST-PAGE";
    r.compute_time = t0;
    r.state = "CONVERGED";
    r.measurement_time = t0 + absl::Seconds(11) + absl::Milliseconds(500);
    ASSERT_TRUE(server.core().storage().estimates().Put(r).ok());
    r.measurement_time = t0 + absl::Seconds(16) + absl::Milliseconds(500);
    ASSERT_TRUE(server.core().storage().estimates().Put(r).ok());
  }
  request.set_page_token(page.next_page_token());
  ASSERT_TRUE(get(request, &page).ok());
  ASSERT_EQ(page.estimates_size(), 5);
  EXPECT_EQ(TimeOf(page.estimates(0).measurement_time()), t0 + absl::Seconds(15));
  EXPECT_EQ(TimeOf(page.estimates(2).measurement_time()),
            t0 + absl::Seconds(16) + absl::Milliseconds(500));

  // Errors, each naming its field.
  esg::v1::EstimateHistoryRequest bad;
  bad.set_spacecraft_id("EST-PAGE");
  bad.set_page_size(-1);
  grpc::Status status = get(bad, &page);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), StartsWith("page_size:"));
  bad.set_page_size(0);
  bad.set_page_token("not-a-token");
  status = get(bad, &page);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), StartsWith("page_token:"));
  // The token of another request (another span).
  esg::v1::EstimateHistoryRequest first;
  first.set_spacecraft_id("EST-PAGE");
  first.set_page_size(10);
  ASSERT_TRUE(get(first, &page).ok());
  bad.set_page_token(page.next_page_token());
  *bad.mutable_from() = proto_convert::TimeToProto(t0);
  status = get(bad, &page);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), StartsWith("page_token:"));
  // A coefficient-history token is not one of this list.
  bad.clear_from();
  bad.set_page_token(absl::WebSafeBase64Escape("esg1;GetCoefficientHistory;0;1:1:1"));
  status = get(bad, &page);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), StartsWith("page_token:"));
  esg::v1::EstimateHistoryRequest reversed;
  reversed.set_spacecraft_id("EST-PAGE");
  *reversed.mutable_from() = proto_convert::TimeToProto(t0 + absl::Seconds(2));
  *reversed.mutable_to() = proto_convert::TimeToProto(t0);
  status = get(reversed, &page);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), StartsWith("to:"));
  esg::v1::EstimateHistoryRequest unknown;
  unknown.set_spacecraft_id("NOPE-1");
  status = get(unknown, &page);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_THAT(status.error_message(), HasSubstr("spacecraft_id: 'NOPE-1' is not configured"));
  esg::v1::EstimateHistoryRequest empty;
  status = get(empty, &page);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), StartsWith("spacecraft_id:"));
}

// The replay is held before its second page while more frames are applied (published live,
// buffered by the subscription); the second page then reads some of those from storage too.
// Every step arrives exactly once, all before the marker, and the later ones after it.
TEST(EstimateSubscription, ReplayThenMarkerThenLiveWithoutGapOrDuplicateWhileFramesArrive) {
  std::atomic<int> page_reads{0};
  absl::Notification release;
  ServerOptions options;
  options.core.before_estimate_replay_page = [&](const std::string&) {
    if (page_reads.fetch_add(1) + 1 == 2) release.WaitForNotificationWithTimeout(absl::Seconds(30));
  };
  LoopbackServer server(options);
  auto stub = server.Stub();
  const SimulatedRun run = Renamed(Run13h(), "EST-SUB");
  Configure(*stub, run);
  Stream(*stub, Frames(run, 0, 600));  // more than one replay page (500)
  ASSERT_TRUE(server.core().WaitApplied("EST-SUB", absl::Seconds(60)).ok());

  Subscriber sub(*stub, Subscription("EST-SUB", true, TimeOf(run.frames[0].time())));
  const absl::Time deadline = absl::Now() + absl::Seconds(30);
  while (page_reads.load() < 2 && absl::Now() < deadline) absl::SleepFor(absl::Milliseconds(5));
  ASSERT_EQ(page_reads.load(), 2) << "the replay reached its second page";
  // Live steps while the replay is held.
  Stream(*stub, Frames(run, 600, 700));
  ASSERT_TRUE(server.core().WaitApplied("EST-SUB", absl::Seconds(60)).ok());
  absl::SleepFor(absl::Milliseconds(200));  // the last job's publication follows its commit
  EXPECT_TRUE(sub.Received().size() <= 500u) << "the replay was held";
  release.Notify();
  ASSERT_TRUE(sub.WaitFor([](const auto& got) { return Markers(got) == 1; }));
  // And after the marker.
  Stream(*stub, Frames(run, 700, 780));
  const std::vector<OfflineEstimate> offline = OfflineEstimates(run.config, Frames(run, 0, 780));
  ASSERT_TRUE(sub.WaitFor([&](const auto& got) { return got.size() == offline.size() + 1; }))
      << sub.Received().size() << " of " << offline.size() + 1;
  absl::SleepFor(absl::Milliseconds(100));
  std::vector<esg::v1::EstimateRecord> got = sub.Received();
  ASSERT_EQ(got.size(), offline.size() + 1) << "nothing more than each step once and the marker";
  const absl::Time live_from = TimeOf(run.frames[700].time());
  size_t marker_at = got.size();
  std::vector<esg::v1::EstimateRecord> steps;
  for (size_t k = 0; k < got.size(); ++k) {
    if (got[k].replay_complete()) {
      marker_at = k;
      // The marker carries nothing else.
      esg::v1::EstimateRecord bare;
      bare.set_replay_complete(true);
      EXPECT_EQ(got[k].SerializeAsString(), bare.SerializeAsString());
      continue;
    }
    const absl::Time t = TimeOf(got[k].measurement_time());
    EXPECT_EQ(k < marker_at, t < live_from) << "step " << FormatUtc(t) << " at " << k;
    steps.push_back(got[k]);
  }
  std::stable_sort(steps.begin(), steps.end(), [](const auto& a, const auto& b) {
    return TimeOf(a.measurement_time()) < TimeOf(b.measurement_time());
  });
  ExpectAllEqualOffline(steps, offline, "EST-SUB");
  // What was sent is what is stored (same computation).
  const std::vector<esg::v1::EstimateRecord> stored = History(*stub, "EST-SUB");
  ASSERT_EQ(stored.size(), steps.size());
  for (size_t k = 0; k < stored.size(); ++k) {
    EXPECT_EQ(stored[k].SerializeAsString(), steps[k].SerializeAsString()) << k;
  }
}

// A page of the replay counts against its caller's bound from its read until its estimates are
// queued, as an alert replay's page does: a caller whose bound one page passes is told so, by
// name, instead of the server holding the page beyond the bound.
TEST(EstimateSubscription, AReplayPageBeyondTheCallersBoundEndsTheStreamNamingIt) {
  ServerOptions options;
  options.calls.max_queued_bytes_per_caller = 64 << 10;
  LoopbackServer server(options);
  auto stub = server.Stub();
  const SimulatedRun run = Renamed(Run13h(), "EST-PAGE");
  Configure(*stub, run);
  Stream(*stub, Frames(run, 0, 600));  // a full first page (500)
  ASSERT_TRUE(server.core().WaitApplied("EST-PAGE", absl::Seconds(60)).ok());
  Subscriber sub(*stub, Subscription("EST-PAGE", true, TimeOf(run.frames[0].time())));
  const grpc::Status status = sub.Finish();
  EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << status.error_message();
  EXPECT_THAT(status.error_message(),
              StartsWith("estimate replay stopped: the page of 500 stored estimates read for it ("));
  EXPECT_THAT(status.error_message(), HasSubstr("--max-queued-mb-per-caller"));
  EXPECT_TRUE(sub.Received().empty());
  EXPECT_EQ(server.get()->service().queue_budget().held(), 0);
}

TEST(EstimateSubscription, AllSpacecraftReplayAndLiveAndOneSpacecraftSeesOnlyItsOwn) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun a = Renamed(Run13h(), "EST-A");
  const SimulatedRun b = Renamed(Run13h(), "EST-B");
  Configure(*stub, a);
  Configure(*stub, b);
  Stream(*stub, Frames(a, 0, 60));
  ASSERT_TRUE(server.core().WaitApplied("EST-A", absl::Seconds(60)).ok());
  const absl::Time start = TimeOf(a.frames[0].time());
  Subscriber all(*stub, Subscription("", true, start));
  Subscriber only_b(*stub, Subscription("EST-B", true, std::nullopt));
  ASSERT_TRUE(all.WaitFor([](const auto& got) { return Markers(got) == 1; }));
  ASSERT_TRUE(only_b.WaitFor([](const auto& got) { return Markers(got) == 1; }));
  EXPECT_TRUE(only_b.Received().front().replay_complete()) << "without since: the marker first";
  Stream(*stub, Frames(b, 0, 90));
  Stream(*stub, Frames(a, 60, 120));
  const size_t steps_a = OfflineEstimates(a.config, Frames(a, 0, 120)).size();
  const size_t steps_b = OfflineEstimates(b.config, Frames(b, 0, 90)).size();
  ASSERT_TRUE(all.WaitFor([&](const auto& got) { return got.size() == steps_a + steps_b + 1; }))
      << all.Received().size();
  ASSERT_TRUE(only_b.WaitFor([&](const auto& got) { return got.size() == steps_b + 1; }));
  absl::SleepFor(absl::Milliseconds(100));
  std::map<std::string, std::vector<absl::Time>> by_spacecraft;
  for (const auto& r : all.Received()) {
    if (!r.replay_complete())
      by_spacecraft[r.spacecraft_id()].push_back(TimeOf(r.measurement_time()));
  }
  for (const auto& r : only_b.Received()) {
    if (!r.replay_complete()) EXPECT_EQ(r.spacecraft_id(), "EST-B");
  }
  EXPECT_EQ(only_b.Received().size(), steps_b + 1);
  ASSERT_EQ(by_spacecraft.size(), 2u);
  for (const auto& [id, times] : by_spacecraft) {
    std::vector<absl::Time> stored;
    for (const auto& e : History(*stub, id)) stored.push_back(TimeOf(e.measurement_time()));
    EXPECT_EQ(times, stored) << id << ": each spacecraft's steps once, in time order";
  }
  // A second subscriber to all replays both from storage, spacecraft by id, then the marker.
  Subscriber later(*stub, Subscription("", true, start));
  ASSERT_TRUE(later.WaitFor([](const auto& got) { return Markers(got) == 1; }));
  const std::vector<esg::v1::EstimateRecord> replay = later.Received();
  ASSERT_EQ(replay.size(), steps_a + steps_b + 1);
  EXPECT_TRUE(replay.back().replay_complete());
  EXPECT_EQ(replay.front().spacecraft_id(), "EST-A");
  EXPECT_EQ(replay[steps_a].spacecraft_id(), "EST-B");
  // Unknown spacecraft and a bad role are refused like SubscribeAlerts.
  Subscriber unknown(*stub, Subscription("NOPE-1", true, std::nullopt));
  const grpc::Status status = unknown.Finish();
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_THAT(status.error_message(), HasSubstr("spacecraft_id: 'NOPE-1' is not configured"));
}

TEST(EstimateArchive, RetentionPrunesOldStepsOfEachSpacecraftAndNothingElse) {
  ServerOptions options;
  options.core.estimate_retention = absl::Hours(1);
  options.core.estimate_retention_period = absl::Minutes(10);
  LoopbackServer server(options);
  auto stub = server.Stub();
  const SimulatedRun long_run = Renamed(Run13h(), "EST-RET");
  const SimulatedRun short_run = Renamed(Run13h(), "EST-SHORT");
  Configure(*stub, long_run);
  Configure(*stub, short_run);
  const std::vector<esg::v1::TelemetryFrame> frames = Frames(long_run, 0, 240);
  Stream(*stub, frames);
  Stream(*stub, Frames(short_run, 0, 50));
  ASSERT_TRUE(server.core().WaitApplied("EST-RET", absl::Seconds(60)).ok());
  ASSERT_TRUE(server.core().WaitApplied("EST-SHORT", absl::Seconds(60)).ok());
  const std::vector<OfflineEstimate> offline = OfflineEstimates(long_run.config, frames);
  const absl::Time newest = offline.back().time;
  // Kept: every step within the retention of the newest, and at most one period more.
  std::vector<OfflineEstimate> expected_kept;
  for (const OfflineEstimate& e : offline) {
    if (e.time >= newest - absl::Hours(1)) expected_kept.push_back(e);
  }
  const std::vector<esg::v1::EstimateRecord> kept = History(*stub, "EST-RET");
  ASSERT_FALSE(kept.empty());
  EXPECT_EQ(TimeOf(kept.back().measurement_time()), newest);
  EXPECT_GE(TimeOf(kept.front().measurement_time()), newest - absl::Hours(1) - absl::Minutes(10));
  EXPECT_LE(TimeOf(kept.front().measurement_time()), newest - absl::Hours(1));
  ASSERT_GE(kept.size(), expected_kept.size());
  const std::vector<esg::v1::EstimateRecord> tail(kept.end() - expected_kept.size(), kept.end());
  ExpectAllEqualOffline(tail, expected_kept, "EST-RET");
  EXPECT_LT(kept.size(), offline.size() / 2) << "the older steps are gone";
  // The short spacecraft (50 min) keeps everything.
  EXPECT_EQ(History(*stub, "EST-SHORT").size(),
            OfflineEstimates(short_run.config, Frames(short_run, 0, 50)).size());
}

TEST(EstimateArchive, RetentionZeroKeepsEverything) {
  ServerOptions options;
  options.core.estimate_retention = absl::ZeroDuration();
  options.core.estimate_retention_period = absl::Minutes(1);
  LoopbackServer server(options);
  auto stub = server.Stub();
  const SimulatedRun run = Renamed(Run13h(), "EST-KEEP");
  Configure(*stub, run);
  Stream(*stub, Frames(run, 0, 180));
  ASSERT_TRUE(server.core().WaitApplied("EST-KEEP", absl::Seconds(60)).ok());
  EXPECT_EQ(History(*stub, "EST-KEEP").size(),
            OfflineEstimates(run.config, Frames(run, 0, 180)).size());
}

// A star-tracker outage over minutes 100-129 spans the restart after minute 115: the steps
// after the restart carry the time of the last step that used the star tracker before it.
TEST(EstimateArchive, RestartNeitherLosesNorRepeatsEstimatesAndKeepsTheLastStarTrackerTime) {
  TempDir dir;
  const std::string db = dir.File("var/esg.db");
  SimulatedRun run = Renamed(Run13h(), "EST-RST");
  for (size_t i = 100; i < 130; ++i) run.frames[i].clear_star_tracker();
  const std::vector<esg::v1::TelemetryFrame> frames = Frames(run, 0, 240);
  {
    LoopbackServer server({}, db);
    auto stub = server.Stub();
    Configure(*stub, run);
    Stream(*stub, Frames(run, 0, 116));
    ASSERT_TRUE(server.core().WaitApplied("EST-RST", absl::Seconds(60)).ok());
  }
  LoopbackServer server({}, db);
  auto stub = server.Stub();
  Stream(*stub, Frames(run, 116, 240));
  ASSERT_TRUE(server.core().WaitApplied("EST-RST", absl::Seconds(60)).ok());
  const std::vector<OfflineEstimate> offline = OfflineEstimates(run.config, frames);
  const std::vector<esg::v1::EstimateRecord> stored = History(*stub, "EST-RST");
  ExpectAllEqualOffline(stored, offline, "EST-RST");
  // The outage: no step of it used the star tracker, and the ones after the restart name the
  // last step before it that did.
  const absl::Time outage = TimeOf(run.frames[100].time());
  const absl::Time restart = TimeOf(run.frames[116].time());
  const absl::Time outage_end = TimeOf(run.frames[130].time());
  absl::Time last_before = absl::InfinitePast();
  for (const OfflineEstimate& e : offline) {
    if (e.time < outage && e.star_tracker_used) last_before = e.time;
  }
  ASSERT_NE(last_before, absl::InfinitePast());
  int after_restart = 0;
  for (const esg::v1::EstimateRecord& e : stored) {
    const absl::Time t = TimeOf(e.measurement_time());
    if (t < restart || t >= outage_end) continue;
    ++after_restart;
    EXPECT_FALSE(e.star_tracker_used());
    EXPECT_EQ(TimeOf(e.last_star_tracker_time()), last_before) << FormatUtc(t);
  }
  EXPECT_GE(after_restart, 10);
}

// A late frame within the reorder window: the re-run from a window checkpoint replaces the
// recomputed steps (the stored estimates end equal to an offline run over the frames in time
// order), and a live subscriber receives the recomputed steps again, newer than before.
TEST(EstimateArchive, LateFrameReRunReplacesTheRecomputedStepsAndSendsThemAgain) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun run = Renamed(Run13h(), "EST-LATE");
  Configure(*stub, run);
  std::vector<esg::v1::TelemetryFrame> first = Frames(run, 0, 150);
  for (const auto& f : Frames(run, 160, 200)) first.push_back(f);
  Stream(*stub, first);
  ASSERT_TRUE(server.core().WaitApplied("EST-LATE", absl::Seconds(60)).ok());
  std::map<absl::Time, absl::Time> computed_before;  // measurement time -> compute time
  for (const auto& e : History(*stub, "EST-LATE")) {
    computed_before[TimeOf(e.measurement_time())] = TimeOf(e.compute_time());
  }
  EXPECT_EQ(computed_before.size(), OfflineEstimates(run.config, first).size());

  Subscriber sub(*stub, Subscription("EST-LATE", true, std::nullopt));
  ASSERT_TRUE(sub.WaitFor([](const auto& got) { return Markers(got) == 1; }));
  std::vector<esg::v1::TelemetryFrame> late = Frames(run, 150, 160);
  for (size_t i = 0; i < late.size(); ++i) {
    late[i].set_station_id("GS-2");
    late[i].set_sequence(static_cast<int64_t>(i) + 1);
  }
  Stream(*stub, late);
  ASSERT_TRUE(server.core().WaitApplied("EST-LATE", absl::Seconds(60)).ok());
  EXPECT_GE(server.core().metrics().revisions.Value(), 1);

  const std::vector<OfflineEstimate> offline = OfflineEstimates(run.config, Frames(run, 0, 200));
  const std::vector<esg::v1::EstimateRecord> stored = History(*stub, "EST-LATE");
  ExpectAllEqualOffline(stored, offline, "EST-LATE");
  // The subscriber got the re-run's steps: from its start (a window checkpoint before the late
  // frames, not the configuration) to the last frame, each the stored computation.
  const absl::Time late_time = TimeOf(late.front().time());
  const absl::Time last_time = TimeOf(run.frames[199].time());
  ASSERT_TRUE(sub.WaitFor([&](const auto& got) {
    return !got.empty() && TimeOf(got.back().measurement_time()) == last_time;
  }));
  std::map<absl::Time, esg::v1::EstimateRecord> latest;  // what a client keeps
  for (const auto& r : sub.Received()) {
    if (!r.replay_complete()) latest[TimeOf(r.measurement_time())] = r;
  }
  ASSERT_FALSE(latest.empty());
  const absl::Time rerun_from = latest.begin()->first;
  EXPECT_LE(rerun_from, late_time);
  EXPECT_GT(rerun_from, TimeOf(run.frames[0].time()) + absl::Hours(1));
  size_t in_span = 0;
  for (const auto& e : stored) {
    const absl::Time t = TimeOf(e.measurement_time());
    if (t < rerun_from) continue;
    ++in_span;
    ASSERT_EQ(latest.count(t), 1u) << FormatUtc(t);
    EXPECT_EQ(latest[t].SerializeAsString(), e.SerializeAsString()) << FormatUtc(t);
    if (computed_before.count(t) != 0) {
      EXPECT_GT(TimeOf(e.compute_time()), computed_before[t]) << "recomputed: " << FormatUtc(t);
    }
  }
  EXPECT_EQ(in_span, latest.size());
}

TEST(EstimateSubscription, ShutdownFinishesOpenSubscriptionsAtOnce) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun run = Renamed(Run13h(), "EST-STOP");
  Configure(*stub, run);
  Subscriber one(*stub, Subscription("EST-STOP", true, std::nullopt));
  Subscriber all(*stub, Subscription("", true, absl::UnixEpoch()));
  ASSERT_TRUE(one.WaitFor([](const auto& got) { return Markers(got) == 1; }));
  ASSERT_TRUE(all.WaitFor([](const auto& got) { return Markers(got) == 1; }));
  const absl::Time start = absl::Now();
  server.get()->Shutdown(absl::Seconds(5), absl::Seconds(1));
  const absl::Duration took = absl::Now() - start;
  EXPECT_LT(took, absl::Seconds(2)) << "open subscriptions do not hold the shutdown";
  for (Subscriber* s : {&one, &all}) {
    const grpc::Status status = s->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAVAILABLE) << status.error_message();
  }
}

// The last star-tracker time is part of the server checkpoint (format 3); a checkpoint of format
// 2 (written before the archive existed) still decodes, without it.
TEST(EstimateArchive, CheckpointKeepsTheLastStarTrackerTimeAndReadsFormat2) {
  ServerCheckpoint c;
  c.model = "10+11";
  c.applied_time = absl::FromUnixSeconds(1551398400);
  c.applied_station = "GS-1";
  c.applied_sequence = 7;
  c.quarantine_reason = "";
  c.last_star_tracker_time = absl::FromUnixSeconds(1551398340);
  c.frames_applied = 7;
  const std::string blob = EncodeCheckpoint(c);
  absl::StatusOr<ServerCheckpoint> back = DecodeCheckpoint(blob);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->last_star_tracker_time, c.last_star_tracker_time);
  EXPECT_EQ(back->frames_applied, 7);
  // Format 2: the same bytes without the 8 of the last star-tracker time, under its magic.
  ASSERT_EQ(blob.substr(0, 8), "ESGSRV03");
  const size_t header = 8 + (8 + c.model.size()) + 8 + (8 + c.applied_station.size()) + 8 + 8 +
                        (8 + c.quarantine_reason.size()) + 8;
  const std::string v2 = "ESGSRV02" + blob.substr(8, header - 8) + blob.substr(header + 8);
  absl::StatusOr<ServerCheckpoint> old = DecodeCheckpoint(v2);
  ASSERT_TRUE(old.ok()) << old.status();
  EXPECT_EQ(old->last_star_tracker_time, absl::InfinitePast());
  EXPECT_EQ(old->applied_sequence, 7);
  EXPECT_EQ(old->frames_applied, 7);
}

// esgd documents the flag in --help and refuses a value that is not a duration >= 0, naming it.
TEST(EstimateArchive, EsgdListsTheRetentionFlagAndRefusesABadValue) {
  TempDir dir;
  const esg::testing::RunResult help = esg::testing::RunBinary(dir, ESGD_PATH, "--help");
  EXPECT_EQ(help.exit_code, 0) << help.err;
  EXPECT_THAT(help.out, HasSubstr("--estimate-retention"));
  EXPECT_THAT(help.out, HasSubstr("720h"));
  const esg::testing::RunResult bad = esg::testing::RunBinary(
      dir, ESGD_PATH, "--listen 127.0.0.1:0 --estimate-retention 3x --db " + dir.File("x.db"));
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_THAT(bad.err, HasSubstr("--estimate-retention: '3x' is not a duration >= 0"));
}

}  // namespace
}  // namespace esg::server
