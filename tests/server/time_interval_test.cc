// One time-interval convention for every call with from/to (docs/service.md "Time intervals"):
// [from, to], both ends inclusive. Against a real esgd on loopback with a real SQLite file, each
// of GetEstimateHistory, GetCoefficientHistory, ExportCoefficientHistory, ExportTelemetry and
// Diagnose answers a span whose `to` is exactly a record's measurement time with that record
// included, and with exactly the records the whole answer holds inside the span; `to` before
// `from` is INVALID_ARGUMENT naming `to`.
#include <algorithm>
#include <optional>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "proto/convert.h"
#include "tests/server/server_test_util.h"

namespace esg::testing {
namespace {

using ::testing::HasSubstr;

constexpr char kId[] = "SPAN-1";

absl::Time TimeOf(const google::protobuf::Timestamp& t) {
  absl::StatusOr<absl::Time> time = proto_convert::TimeFromProto(t);
  EXPECT_TRUE(time.ok()) << time.status();
  return time.ok() ? *time : absl::InfinitePast();
}

template <typename Request>
Request Spanned(std::optional<absl::Time> from, std::optional<absl::Time> to) {
  Request request;
  request.set_spacecraft_id(kId);
  if (from) *request.mutable_from() = proto_convert::TimeToProto(*from);
  if (to) *request.mutable_to() = proto_convert::TimeToProto(*to);
  return request;
}

// The measurement times of every record of a paged call over the span, all pages followed:
// `call` makes the call, `times_of` appends a page's records' times.
template <typename Page, typename Request, typename Call, typename TimesOf>
std::vector<absl::Time> AllPages(Request request, Call call, TimesOf times_of,
                                 grpc::Status* status) {
  std::vector<absl::Time> times;
  do {
    grpc::ClientContext context;
    Page page;
    *status = call(&context, request, &page);
    if (!status->ok()) return times;
    times_of(page, times);
    request.set_page_token(page.next_page_token());
  } while (!request.page_token().empty());
  return times;
}

std::vector<absl::Time> EstimateTimes(esg::v1::EstimationService::Stub& stub,
                                      std::optional<absl::Time> from,
                                      std::optional<absl::Time> to, grpc::Status* status) {
  return AllPages<esg::v1::EstimateHistoryResponse>(
      Spanned<esg::v1::EstimateHistoryRequest>(from, to),
      [&](auto* context, const auto& request, auto* page) {
        return stub.GetEstimateHistory(context, request, page);
      },
      [](const esg::v1::EstimateHistoryResponse& page, std::vector<absl::Time>& times) {
        for (const auto& e : page.estimates()) times.push_back(TimeOf(e.measurement_time()));
      },
      status);
}

// One snapshot per gyro and step.
std::vector<absl::Time> SnapshotTimes(esg::v1::EstimationService::Stub& stub,
                                      std::optional<absl::Time> from,
                                      std::optional<absl::Time> to, grpc::Status* status) {
  return AllPages<esg::v1::HistoryResponse>(
      Spanned<esg::v1::HistoryRequest>(from, to),
      [&](auto* context, const auto& request, auto* page) {
        return stub.GetCoefficientHistory(context, request, page);
      },
      [](const esg::v1::HistoryResponse& page, std::vector<absl::Time>& times) {
        for (const auto& s : page.snapshots()) times.push_back(TimeOf(s.measurement_time()));
      },
      status);
}

std::vector<absl::Time> ExportedSnapshotTimes(esg::v1::EstimationService::Stub& stub,
                                              std::optional<absl::Time> from,
                                              std::optional<absl::Time> to,
                                              grpc::Status* status) {
  grpc::ClientContext context;
  auto reader = stub.ExportCoefficientHistory(
      &context, Spanned<esg::v1::ExportCoefficientHistoryRequest>(from, to));
  std::vector<absl::Time> times;
  esg::v1::ExportCoefficientHistoryResponse chunk;
  while (reader->Read(&chunk)) {
    for (const auto& s : chunk.snapshots()) times.push_back(TimeOf(s.measurement_time()));
  }
  *status = reader->Finish();
  return times;
}

std::vector<absl::Time> ExportedFrameTimes(esg::v1::EstimationService::Stub& stub,
                                           std::optional<absl::Time> from,
                                           std::optional<absl::Time> to, grpc::Status* status) {
  grpc::ClientContext context;
  auto reader = stub.ExportTelemetry(&context, Spanned<esg::v1::ExportTelemetryRequest>(from, to));
  std::vector<absl::Time> times;
  esg::v1::ExportTelemetryResponse chunk;
  while (reader->Read(&chunk)) {
    for (const auto& f : chunk.frames()) times.push_back(TimeOf(f.time()));
  }
  *status = reader->Finish();
  return times;
}

using Fetch = std::vector<absl::Time> (*)(esg::v1::EstimationService::Stub&,
                                          std::optional<absl::Time>, std::optional<absl::Time>,
                                          grpc::Status*);

class TimeIntervalRpc : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    server_ = new LoopbackServer();
    const SimulatedRun run = SimulateRun(kId, 1.0, 11);
    auto stub = server_->Stub();
    grpc::ClientContext context;
    esg::v1::ConfigureResponse response;
    ASSERT_TRUE(
        stub->ConfigureSpacecraft(&context, ConfigureRequestFor(run.config), &response).ok());
    const StreamResult streamed = StreamFrames(*stub, run.frames);
    ASSERT_TRUE(streamed.status.ok()) << streamed.status.error_message();
    ASSERT_TRUE(server_->core().WaitApplied(kId, absl::Seconds(60)).ok());
  }
  static void TearDownTestSuite() {
    delete server_;
    server_ = nullptr;
  }

  // The whole answer of `fetch`, then the answer over [all[a], all[b]] (records a and b chosen
  // among the distinct times): the same records, the one at `to` included.
  static void ExpectInclusive(Fetch fetch, const char* call) {
    SCOPED_TRACE(call);
    auto stub = server_->Stub();
    grpc::Status status;
    const std::vector<absl::Time> all = fetch(*stub, std::nullopt, std::nullopt, &status);
    ASSERT_TRUE(status.ok()) << status.error_message();
    std::vector<absl::Time> distinct = all;
    distinct.erase(std::unique(distinct.begin(), distinct.end()), distinct.end());
    ASSERT_GE(distinct.size(), 20u);
    const absl::Time from = distinct[distinct.size() / 4];
    const absl::Time to = distinct[distinct.size() / 2];
    std::vector<absl::Time> expected;
    for (absl::Time t : all) {
      if (from <= t && t <= to) expected.push_back(t);
    }
    const std::vector<absl::Time> got = fetch(*stub, from, to, &status);
    ASSERT_TRUE(status.ok()) << status.error_message();
    ASSERT_FALSE(got.empty());
    EXPECT_EQ(got.front(), from) << "the record at from is included";
    EXPECT_EQ(got.back(), to) << "the record at to is included";
    EXPECT_EQ(got, expected);
    // from = to: the records of that one instant.
    const std::vector<absl::Time> instant = fetch(*stub, to, to, &status);
    ASSERT_TRUE(status.ok()) << status.error_message();
    EXPECT_EQ(instant, std::vector<absl::Time>(std::count(all.begin(), all.end(), to), to));
    // to before from.
    fetch(*stub, to, from, &status);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_THAT(status.error_message(), HasSubstr("to: "));
    EXPECT_THAT(status.error_message(), HasSubstr(" is before from "));
  }

  static LoopbackServer* server_;
};
LoopbackServer* TimeIntervalRpc::server_ = nullptr;

TEST_F(TimeIntervalRpc, EstimateHistoryIncludesTheRecordAtTo) {
  ExpectInclusive(&EstimateTimes, "GetEstimateHistory");
}

TEST_F(TimeIntervalRpc, CoefficientHistoryIncludesTheSnapshotsAtTo) {
  ExpectInclusive(&SnapshotTimes, "GetCoefficientHistory");
}

TEST_F(TimeIntervalRpc, CoefficientExportIncludesTheSnapshotsAtTo) {
  ExpectInclusive(&ExportedSnapshotTimes, "ExportCoefficientHistory");
}

TEST_F(TimeIntervalRpc, TelemetryExportIncludesTheFrameAtTo) {
  ExpectInclusive(&ExportedFrameTimes, "ExportTelemetry");
}

// The diagnosis runs on the frames of [from, to]: the stored result counts the frame at `to`
// and names it its last.
TEST_F(TimeIntervalRpc, DiagnosisIncludesTheFrameAtTo) {
  auto stub = server_->Stub();
  grpc::Status status;
  const std::vector<absl::Time> frames =
      ExportedFrameTimes(*stub, std::nullopt, std::nullopt, &status);
  ASSERT_TRUE(status.ok()) << status.error_message();
  ASSERT_GE(frames.size(), 40u);
  const size_t a = 10;
  const size_t b = 39;
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(300));
  auto reader = stub->Diagnose(&context, Spanned<esg::v1::DiagnoseRequest>(frames[a], frames[b]));
  esg::v1::DiagnoseUpdate update;
  std::optional<esg::v1::DiagnosisResult> result;
  while (reader->Read(&update)) {
    if (update.has_result()) result = update.result();
  }
  status = reader->Finish();
  ASSERT_TRUE(status.ok()) << status.error_message();
  ASSERT_TRUE(result.has_value());
  EXPECT_EQ(result->frames(), static_cast<int64_t>(b - a + 1));
  EXPECT_EQ(TimeOf(result->first_frame_time()), frames[a]);
  EXPECT_EQ(TimeOf(result->last_frame_time()), frames[b]);
}

}  // namespace
}  // namespace esg::testing
