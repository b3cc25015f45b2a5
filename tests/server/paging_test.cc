// Paging and export against a real server on loopback (issue 11 item 3, docs/service.md
// "Paging"): 30 days of coefficient history paged by a plain client with gRPC's default 4 MB
// receive limit (every record exactly once, in order; a record appended between pages is not
// lost), the page-size rules and a refused token naming page_token; ListDiagnoses as summaries
// with the full report by GetDiagnosis; ListSessions paged; ExportCoefficientHistory and
// ExportTelemetry streaming everything in order.
#include <set>
#include <string>
#include <tuple>
#include <vector>

#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/coefficient_store.h"
#include "tests/server/server_test_util.h"

namespace esg::testing {
namespace {

using ::testing::HasSubstr;

const absl::Time kStart = absl::FromUnixSeconds(1551398400);  // 2019-03-01T00:00:00Z
constexpr int kGyros = 3;

// One record per gyro every 60 s over `days`, k0 = the record's index (to check order and
// identity), in one transaction.
void AppendHistory(storage::Storage& storage, const std::string& id, int days) {
  auto txn = storage.database().Begin(storage::TransactionMode::kImmediate);
  ASSERT_TRUE(txn.ok()) << txn.status();
  const int steps = days * 1440;
  for (int step = 0; step < steps; ++step) {
    for (int gyro = 1; gyro <= kGyros; ++gyro) {
      storage::CoefficientRecord r;
      r.spacecraft_id = id;
      r.gyro_id = gyro;
      r.measurement_time = kStart + absl::Minutes(step);
      r.compute_time = kStart;
      r.model_name = "10+11";
      r.values.assign(storage::kNumCoefficientValues, 0.01);
      // Records are SI: k0 = the index in deg/h.
      r.values[estimator::kThetaK0] = estimator::DegPerHourToRadPerSec(step * kGyros + (gyro - 1));
      r.sigmas.assign(storage::kNumCoefficientValues, 0.001);
      ASSERT_TRUE(storage.coefficients().Append(*txn, r).ok());
    }
  }
  ASSERT_TRUE(txn->Commit().ok());
}

void Configure(esg::v1::EstimationService::Stub& stub, const std::string& id) {
  grpc::ClientContext context;
  esg::v1::ConfigureResponse configured;
  ASSERT_TRUE(
      stub.ConfigureSpacecraft(&context, ConfigureRequestFor(ServerTestConfig(id)), &configured)
          .ok());
}

grpc::Status HistoryPage(esg::v1::EstimationService::Stub& stub,
                         const esg::v1::HistoryRequest& request, esg::v1::HistoryResponse* page) {
  grpc::ClientContext context;
  return stub.GetCoefficientHistory(&context, request, page);
}

TEST(Paging, ThirtyDaysOfHistoryPageByPageUnderTheDefaultMessageLimit) {
  LoopbackServer server;
  // A plain client: the default channel, gRPC's default 4 MB receive limit.
  auto stub = server.Stub();
  Configure(*stub, "PAGE-30D");
  AppendHistory(server.core().storage(), "PAGE-30D", 30);
  const int64_t total = 30 * 1440 * kGyros;

  // Unpaged, the history is 30 times the 4 MB limit: one page (the default size) answers.
  esg::v1::HistoryRequest request;
  request.set_spacecraft_id("PAGE-30D");
  int64_t expected_k0 = 0;
  int pages = 0;
  bool appended = false;
  size_t largest_page_bytes = 0;
  size_t total_bytes = 0;
  do {
    esg::v1::HistoryResponse page;
    const grpc::Status status = HistoryPage(*stub, request, &page);
    ASSERT_TRUE(status.ok()) << status.error_message() << " at page " << pages;
    ++pages;
    largest_page_bytes = std::max(largest_page_bytes, page.ByteSizeLong());
    total_bytes += page.ByteSizeLong();
    EXPECT_LE(page.snapshots_size(), 5000);
    for (const esg::v1::CoefficientSnapshot& s : page.snapshots()) {
      ASSERT_DOUBLE_EQ(TermDegH(s.model(), estimator::kThetaK0), static_cast<double>(expected_k0)) << "page " << pages;
      ASSERT_EQ(s.gyro_id(), expected_k0 % kGyros + 1);
      ++expected_k0;
    }
    if (!appended) {
      // A record stored after the first page (a later measurement) shows up once, at the end.
      storage::CoefficientRecord late;
      late.spacecraft_id = "PAGE-30D";
      late.gyro_id = 1;
      late.measurement_time = kStart + absl::Hours(24 * 30);
      late.compute_time = kStart;
      late.model_name = "10+11";
      late.values.assign(storage::kNumCoefficientValues, 0.0);
      late.values[estimator::kThetaK0] =
          estimator::DegPerHourToRadPerSec(static_cast<double>(total));
      ASSERT_TRUE(server.core().storage().coefficients().Append(late).ok());
      appended = true;
    }
    request.set_page_token(page.next_page_token());
  } while (!request.page_token().empty());
  EXPECT_EQ(expected_k0, total + 1);  // every record once, in order, the late one last
  EXPECT_EQ(pages, 26);               // 129601 records, 5000 per page
  EXPECT_LT(largest_page_bytes, 4u << 20);
  RecordProperty("largest_page_bytes", std::to_string(largest_page_bytes));
  RecordProperty("total_bytes", std::to_string(total_bytes));

  // page_size: larger than the maximum is the maximum; small sizes are honoured.
  esg::v1::HistoryRequest sized;
  sized.set_spacecraft_id("PAGE-30D");
  sized.set_page_size(1000000);
  esg::v1::HistoryResponse page;
  ASSERT_TRUE(HistoryPage(*stub, sized, &page).ok());
  EXPECT_EQ(page.snapshots_size(), 5000);
  sized.set_page_size(7);
  sized.set_gyro_id(2);
  ASSERT_TRUE(HistoryPage(*stub, sized, &page).ok());
  ASSERT_EQ(page.snapshots_size(), 7);
  EXPECT_DOUBLE_EQ(TermDegH(page.snapshots(6).model(), estimator::kThetaK0), 6 * kGyros + 1);
  const std::string gyro2_token = page.next_page_token();
  ASSERT_FALSE(gyro2_token.empty());

  // Refused: a negative size, a token that is not one, a token of another request.
  esg::v1::HistoryRequest bad;
  bad.set_spacecraft_id("PAGE-30D");
  bad.set_page_size(-1);
  grpc::Status status = HistoryPage(*stub, bad, &page);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), ::testing::StartsWith("page_size: "));
  bad.set_page_size(0);
  bad.set_page_token("not-a-token");
  status = HistoryPage(*stub, bad, &page);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), ::testing::StartsWith("page_token: "));
  bad.set_page_token(gyro2_token);  // the request asks for every gyro, the token for gyro 2
  status = HistoryPage(*stub, bad, &page);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), ::testing::StartsWith("page_token: "));

  // The export streams the same records in the same order, in chunks of at most 1000.
  grpc::ClientContext context;
  esg::v1::ExportCoefficientHistoryRequest export_request;
  export_request.set_spacecraft_id("PAGE-30D");
  auto reader = stub->ExportCoefficientHistory(&context, export_request);
  esg::v1::ExportCoefficientHistoryResponse chunk;
  int64_t exported = 0;
  int chunks = 0;
  while (reader->Read(&chunk)) {
    ++chunks;
    EXPECT_LE(chunk.snapshots_size(), 1000);
    for (const esg::v1::CoefficientSnapshot& s : chunk.snapshots()) {
      ASSERT_DOUBLE_EQ(TermDegH(s.model(), estimator::kThetaK0), static_cast<double>(exported));
      ++exported;
    }
  }
  status = reader->Finish();
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(exported, total + 1);
  EXPECT_EQ(chunks, 130);
}

TEST(Paging, AHistoryTokenStaysValidAcrossARestart) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  std::string token;
  {
    LoopbackServer server({}, db);
    auto stub = server.Stub();
    Configure(*stub, "PAGE-RESTART");
    AppendHistory(server.core().storage(), "PAGE-RESTART", 1);
    esg::v1::HistoryRequest request;
    request.set_spacecraft_id("PAGE-RESTART");
    request.set_page_size(1000);
    esg::v1::HistoryResponse page;
    ASSERT_TRUE(HistoryPage(*stub, request, &page).ok());
    ASSERT_EQ(page.snapshots_size(), 1000);
    token = page.next_page_token();
  }
  LoopbackServer server({}, db);
  esg::v1::HistoryRequest request;
  request.set_spacecraft_id("PAGE-RESTART");
  request.set_page_size(1000);
  request.set_page_token(token);
  esg::v1::HistoryResponse page;
  const grpc::Status status = HistoryPage(*server.Stub(), request, &page);
  ASSERT_TRUE(status.ok()) << status.error_message();
  ASSERT_EQ(page.snapshots_size(), 1000);
  EXPECT_DOUBLE_EQ(TermDegH(page.snapshots(0).model(), estimator::kThetaK0), 1000.0);  // the record after the first page
}

TEST(Paging, DiagnosesAreListedAsSummariesAndReadOneByOne) {
  LoopbackServer server;
  auto stub = server.Stub();
  Configure(*stub, "PAGE-DIAG");
  Configure(*stub, "PAGE-OTHER");
  std::vector<int64_t> ids;
  for (int i = 0; i < 120; ++i) {
    storage::DiagnosisRecord r;
    r.spacecraft_id = i % 10 == 9 ? "PAGE-OTHER" : "PAGE-DIAG";  // 12 of another spacecraft
    r.from_time = kStart;
    r.to_time = kStart + absl::Hours(1);
    r.compute_time = kStart + absl::Hours(2);
    r.verdict = "none";
    r.report_json = absl::StrCat("{\"n\": ", i, "}");
    auto id = server.core().storage().diagnoses().Put(r);
    ASSERT_TRUE(id.ok()) << id.status();
    if (r.spacecraft_id == "PAGE-DIAG") ids.push_back(*id);
  }
  esg::v1::ListDiagnosesRequest request;
  request.set_spacecraft_id("PAGE-DIAG");
  std::vector<int64_t> listed;
  std::vector<int> sizes;
  do {
    grpc::ClientContext context;
    esg::v1::ListDiagnosesResponse page;
    const grpc::Status status = stub->ListDiagnoses(&context, request, &page);
    ASSERT_TRUE(status.ok()) << status.error_message();
    sizes.push_back(page.diagnoses_size());
    for (const esg::v1::DiagnosisResult& d : page.diagnoses()) {
      listed.push_back(d.id());
      EXPECT_EQ(d.verdict(), "none");
      EXPECT_TRUE(d.report_json().empty()) << "a summary";
    }
    request.set_page_token(page.next_page_token());
  } while (!request.page_token().empty());
  EXPECT_EQ(listed, ids);
  EXPECT_EQ(sizes, (std::vector<int>{50, 50, 8}));  // 108 of PAGE-DIAG, default page 50

  grpc::ClientContext context;
  esg::v1::GetDiagnosisRequest get;
  get.set_spacecraft_id("PAGE-DIAG");
  get.set_id(ids[5]);
  esg::v1::DiagnosisResult full;
  ASSERT_TRUE(stub->GetDiagnosis(&context, get, &full).ok());
  EXPECT_EQ(full.report_json(), "{\"n\": 5}");
  // An id of another spacecraft is not found under this one.
  grpc::ClientContext other_context;
  get.set_id(ids.back() + 1);  // PAGE-OTHER's record i = 119
  const grpc::Status status = stub->GetDiagnosis(&other_context, get, &full);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_THAT(status.error_message(), ::testing::StartsWith("id: "));
  // A token of PAGE-DIAG is refused for PAGE-OTHER.
  esg::v1::ListDiagnosesRequest first;
  first.set_spacecraft_id("PAGE-DIAG");
  first.set_page_size(1);
  esg::v1::ListDiagnosesResponse page;
  grpc::ClientContext c1;
  ASSERT_TRUE(stub->ListDiagnoses(&c1, first, &page).ok());
  first.set_spacecraft_id("PAGE-OTHER");
  first.set_page_token(page.next_page_token());
  grpc::ClientContext c2;
  const grpc::Status refused = stub->ListDiagnoses(&c2, first, &page);
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(refused.error_message(), ::testing::StartsWith("page_token: "));
}

TEST(Paging, SessionsArePagedInIdOrder) {
  LoopbackServer server;
  auto stub = server.Stub();
  std::vector<std::string> ids;
  for (int i = 0; i < 7; ++i) ids.push_back(absl::StrCat("PAGE-S", i));
  for (auto it = ids.rbegin(); it != ids.rend(); ++it) Configure(*stub, *it);
  esg::v1::ListSessionsRequest request;
  request.set_page_size(3);
  std::vector<std::string> listed;
  int pages = 0;
  do {
    grpc::ClientContext context;
    esg::v1::ListSessionsResponse page;
    ASSERT_TRUE(stub->ListSessions(&context, request, &page).ok());
    ++pages;
    for (const esg::v1::SessionInfo& s : page.sessions()) listed.push_back(s.spacecraft_id());
    request.set_page_token(page.next_page_token());
  } while (!request.page_token().empty());
  EXPECT_EQ(listed, ids);
  EXPECT_EQ(pages, 3);
  grpc::ClientContext context;
  esg::v1::ListSessionsResponse all;
  ASSERT_TRUE(stub->ListSessions(&context, {}, &all).ok());
  EXPECT_EQ(all.sessions_size(), 7);
  EXPECT_TRUE(all.next_page_token().empty());
}

TEST(Paging, TelemetryExportStreamsTheArchiveInTimeOrder) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun run = SimulateRun("PAGE-TM", 40.0, 9);  // 2401 frames
  {
    grpc::ClientContext context;
    esg::v1::ConfigureResponse configured;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&context, ConfigureRequestFor(run.config), &configured)
                    .ok());
  }
  const StreamResult streamed = StreamFrames(*stub, run.frames);
  ASSERT_TRUE(streamed.status.ok()) << streamed.status.error_message();
  auto export_all = [&](const esg::v1::ExportTelemetryRequest& request, int* chunks) {
    grpc::ClientContext context;
    auto reader = stub->ExportTelemetry(&context, request);
    esg::v1::ExportTelemetryResponse chunk;
    std::vector<esg::v1::TelemetryFrame> frames;
    *chunks = 0;
    while (reader->Read(&chunk)) {
      ++*chunks;
      for (const esg::v1::TelemetryFrame& f : chunk.frames()) frames.push_back(f);
    }
    EXPECT_TRUE(reader->Finish().ok());
    return frames;
  };
  esg::v1::ExportTelemetryRequest request;
  request.set_spacecraft_id("PAGE-TM");
  int chunks = 0;
  const std::vector<esg::v1::TelemetryFrame> frames = export_all(request, &chunks);
  ASSERT_EQ(frames.size(), run.frames.size());
  EXPECT_EQ(chunks, 3);
  for (size_t i = 0; i < frames.size(); ++i) {
    esg::v1::TelemetryFrame expected = run.frames[i];
    expected.set_station_id("default");
    ASSERT_EQ(frames[i].SerializeAsString(), expected.SerializeAsString()) << "frame " << i;
  }
  // [from, to], both ends inclusive: the 10th to the 20th frame.
  *request.mutable_from() = run.frames[10].time();
  *request.mutable_to() = run.frames[20].time();
  const std::vector<esg::v1::TelemetryFrame> window = export_all(request, &chunks);
  ASSERT_EQ(window.size(), 11u);
  EXPECT_EQ(window.front().sequence(), run.frames[10].sequence());
  EXPECT_EQ(window.back().sequence(), run.frames[20].sequence());
  // An unknown spacecraft is NOT_FOUND.
  grpc::ClientContext context;
  esg::v1::ExportTelemetryRequest unknown;
  unknown.set_spacecraft_id("NOBODY");
  auto reader = stub->ExportTelemetry(&context, unknown);
  esg::v1::ExportTelemetryResponse chunk;
  EXPECT_FALSE(reader->Read(&chunk));
  EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::NOT_FOUND);
}

}  // namespace
}  // namespace esg::testing
