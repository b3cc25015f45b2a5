// `esg estimates` as a real process against a real esgd child process on 127.0.0.1: estimates
// written into the daemon's database (4500 steps, three pages of GetEstimateHistory) come out
// every one once, in order, with the stored values (CSV with 17 significant digits reads back the
// double; innovations under their gyro id's columns, empty where none was formed); --from/--to are
// inclusive; --json is the EstimateHistoryResponse (the attitude error estimate empty on steps
// without one); the table counts them; an unknown spacecraft
// is exit 1 with the server's NOT_FOUND, a bad time exit 2 naming the option.
#include <cmath>
#include <map>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "proto/convert.h"
#include "storage/storage.h"
#include "tests/client/cli_test_support.h"
#include "tests/testing/paper_setup.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using ::esg::testing::Daemon;
using ::esg::testing::RunResult;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;
using Json = nlohmann::json;

const absl::Time kStart = absl::FromUnixSeconds(1551398400);  // 2019-03-01T00:00:00Z
constexpr int kSteps = 4500;

// Step i: every value derived from i, so a row tells which step it is. Every third step has no
// attitude output; the innovations of gyros 2 and 1 (in that session order) and the attitude
// error estimate on even steps.
storage::EstimateRecord Step(int i) {
  storage::EstimateRecord r;
  r.spacecraft_id = "CLI-EST";
  r.measurement_time = kStart + absl::Minutes(i);
  r.compute_time = kStart + absl::Hours(1000);
  r.state = i < 100 ? "CALIBRATING" : "CONVERGED";
  r.attitude_valid = i % 3 != 0;
  if (r.attitude_valid) {
    const double half = 1e-4 * i;
    r.q_in_b = {std::cos(half), 0.0, std::sin(half), 0.0};
    r.sigma_b = {estimator::ArcsecToRad(1.0 + 1e-3 * i), estimator::ArcsecToRad(2.0),
                 estimator::ArcsecToRad(3.0)};
    r.output_pair = {1, 2};
  } else {
    r.attitude_invalid_reason = "no readable pair, step " + std::to_string(i);
  }
  r.star_tracker_used = i % 2 == 0;
  if (i % 2 == 0) {
    for (int id : {2, 1}) {
      storage::GyroInnovationRecord g;
      g.gyro_id = id;
      g.innovation = {estimator::ArcsecToRad(0.01 * i + id), estimator::ArcsecToRad(-id)};
      g.sigma = {estimator::ArcsecToRad(4.0), estimator::ArcsecToRad(5.0)};
      r.star_tracker_innovations.push_back(g);
    }
    r.last_star_tracker_time = r.measurement_time;
    r.has_attitude_error = true;
    r.attitude_error_b = {estimator::ArcsecToRad(1e-3 * i), estimator::ArcsecToRad(-0.5),
                          estimator::ArcsecToRad(2.0)};
    r.attitude_error_sigma_b = {estimator::ArcsecToRad(1.5), estimator::ArcsecToRad(1.75),
                                estimator::ArcsecToRad(9.0)};
  } else {
    r.last_star_tracker_time = r.measurement_time - absl::Minutes(1);
  }
  r.star_tracker_test_ratio = 1e-3 * i;
  return r;
}

class EstimatesCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir;
    const std::string db = dir_->File("esg.db");
    {
      Daemon daemon(db, dir_->File("esgd.log"));
      grpc::ClientContext context;
      esg::v1::ConfigureRequest request;
      estimator::SpacecraftConfig config = testing::PaperConfig();
      config.spacecraft_id = "CLI-EST";
      *request.mutable_config() = proto_convert::ConfigToProto(config);
      esg::v1::ConfigureResponse response;
      ASSERT_TRUE(daemon.Stub()->ConfigureSpacecraft(&context, request, &response).ok());
    }  // stopped: the estimates are written straight into its database
    absl::StatusOr<std::unique_ptr<storage::Storage>> storage = storage::Storage::Open(db);
    ASSERT_TRUE(storage.ok()) << storage.status();
    auto txn = (*storage)->database().Begin();
    ASSERT_TRUE(txn.ok());
    for (int i = 0; i < kSteps; ++i) ASSERT_TRUE((*storage)->estimates().Put(*txn, Step(i)).ok());
    ASSERT_TRUE(txn->Commit().ok());
    storage->reset();
    daemon_ = new Daemon(db, dir_->File("esgd.log"));
  }
  static void TearDownTestSuite() {
    delete daemon_;
    delete dir_;
  }
  static TempDir* dir_;
  static Daemon* daemon_;
};
TempDir* EstimatesCli::dir_ = nullptr;
Daemon* EstimatesCli::daemon_ = nullptr;

TEST_F(EstimatesCli, CsvHasEveryStepOnceInOrderWithTheStoredValues) {
  const RunResult r = Esg(*dir_, *daemon_, "estimates --spacecraft CLI-EST --csv");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<std::string> lines = absl::StrSplit(r.out, '\n', absl::SkipEmpty());
  ASSERT_EQ(lines.size(), static_cast<size_t>(kSteps) + 1);
  const std::vector<std::string> header = absl::StrSplit(lines[0], ',');
  std::map<std::string, size_t> column;
  for (size_t c = 0; c < header.size(); ++c) column[header[c]] = c;
  for (const char* name :
       {"time_utc", "state", "q0", "q2", "sigma_x_arcsec", "reference_gyro", "star_tracker_used",
        "star_tracker_test_ratio", "last_star_tracker_time_utc", "g1_innovation_1_arcsec",
        "g2_sigma_2_arcsec", "g3_innovation_1_arcsec", "attitude_invalid_reason",
        "compute_time_utc", "attitude_error_x_arcsec", "attitude_error_z_arcsec",
        "attitude_error_sigma_y_arcsec"}) {
    ASSERT_EQ(column.count(name), 1u) << name << " in " << lines[0];
  }
  for (int i = 0; i < kSteps; ++i) {
    const storage::EstimateRecord want = Step(i);
    const std::vector<std::string> cells = CsvCells(lines[i + 1]);
    ASSERT_EQ(cells.size(), header.size()) << lines[i + 1];
    auto cell = [&](const char* name) { return cells[column.at(name)]; };
    ASSERT_EQ(cell("time_utc"),
              absl::FormatTime("%Y-%m-%dT%H:%M:%E3SZ", want.measurement_time, absl::UTCTimeZone()));
    EXPECT_EQ(cell("state"), want.state);
    if (want.attitude_valid) {
      EXPECT_EQ(std::stod(cell("q2")), want.q_in_b[2]) << i;
      EXPECT_NEAR(std::stod(cell("sigma_x_arcsec")), 1.0 + 1e-3 * i, 1e-12) << i;
      EXPECT_EQ(cell("reference_gyro"), "1");
      EXPECT_EQ(cell("attitude_invalid_reason"), "");
    } else {
      EXPECT_EQ(cell("q0"), "");
      EXPECT_EQ(cell("reference_gyro"), "");
      EXPECT_EQ(cell("attitude_invalid_reason"), want.attitude_invalid_reason);
    }
    EXPECT_EQ(cell("star_tracker_used"), want.star_tracker_used ? "true" : "false");
    EXPECT_EQ(std::stod(cell("star_tracker_test_ratio")), want.star_tracker_test_ratio) << i;
    if (want.star_tracker_used) {
      EXPECT_NEAR(std::stod(cell("g1_innovation_1_arcsec")), 0.01 * i + 1, 1e-12) << i;
      EXPECT_NEAR(std::stod(cell("g2_innovation_2_arcsec")), -2.0, 1e-12) << i;
      EXPECT_NEAR(std::stod(cell("g2_sigma_2_arcsec")), 5.0, 1e-12) << i;
      EXPECT_NEAR(std::stod(cell("attitude_error_x_arcsec")), 1e-3 * i, 1e-12) << i;
      EXPECT_NEAR(std::stod(cell("attitude_error_z_arcsec")), 2.0, 1e-12) << i;
      EXPECT_NEAR(std::stod(cell("attitude_error_sigma_y_arcsec")), 1.75, 1e-12) << i;
    } else {
      EXPECT_EQ(cell("g1_innovation_1_arcsec"), "");
      EXPECT_EQ(cell("attitude_error_x_arcsec"), "");
      EXPECT_EQ(cell("attitude_error_sigma_z_arcsec"), "");
    }
    EXPECT_EQ(cell("g3_innovation_1_arcsec"), "") << "no innovation of gyro 3 was formed";
  }
}

TEST_F(EstimatesCli, SpanIsInclusiveJsonIsTheResponseAndTheTableCounts) {
  const std::string span =
      " --from 2019-03-01T01:00:00Z --to 2019-03-01T02:00:00Z";  // steps 60..120
  RunResult r = Esg(*dir_, *daemon_, "estimates --spacecraft CLI-EST --json" + span);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json doc = Json::parse(r.out, nullptr, false);
  ASSERT_TRUE(doc.is_object()) << r.out;
  ASSERT_EQ(doc["estimates"].size(), 61u);
  // Every page was followed: no token of a further page (the JSON printer writes empty strings).
  EXPECT_TRUE(!doc.contains("nextPageToken") || doc["nextPageToken"] == "") << doc["nextPageToken"];
  const Json& first = doc["estimates"][0];
  EXPECT_EQ(first["measurementTime"], "2019-03-01T01:00:00.000Z");
  EXPECT_EQ(first["state"], "SESSION_STATE_CALIBRATING");
  EXPECT_EQ(first["starTrackerInnovations"][0]["gyroId"], 2) << "the session's gyro order";
  EXPECT_EQ(first["starTrackerInnovations"][1]["gyroId"], 1);
  EXPECT_TRUE(!first.contains("attitude") || first["attitude"]["qInB"].empty())
      << "step 60 has no attitude output: " << first.dump();
  EXPECT_EQ(doc["estimates"][1]["attitude"]["qInB"].size(), 4u);
  EXPECT_EQ(first["attitudeInvalidReason"], "no readable pair, step 60");
  // Step 60 applied the star tracker: its attitude error estimate and 1-sigma about body x, y, z;
  // step 61 did not, and has none.
  ASSERT_EQ(first["attitudeErrorBArcsec"].size(), 3u) << first.dump();
  EXPECT_NEAR(first["attitudeErrorBArcsec"][0].get<double>(), 0.06, 1e-12);
  EXPECT_NEAR(first["attitudeErrorSigmaBArcsec"][2].get<double>(), 9.0, 1e-12);
  EXPECT_TRUE(!doc["estimates"][1].contains("attitudeErrorBArcsec") ||
              doc["estimates"][1]["attitudeErrorBArcsec"].empty())
      << doc["estimates"][1].dump();
  r = Esg(*dir_, *daemon_, "estimates --spacecraft CLI-EST" + span);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("61 estimates"));
  EXPECT_THAT(r.out, HasSubstr("2019-03-01T01:59:00.000Z"));
  EXPECT_THAT(r.out, HasSubstr("att. error x,y,z [arcsec]"));
  EXPECT_THAT(r.out, HasSubstr("  +0.06   -0.50   +2.00"));
  r = Esg(*dir_, *daemon_, "estimates --spacecraft CLI-EST --csv --json");
  EXPECT_EQ(r.exit_code, 2);
}

TEST_F(EstimatesCli, UnknownSpacecraftAndBadTimesAreRefused) {
  RunResult r = Esg(*dir_, *daemon_, "estimates --spacecraft NOPE-1");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err,
              HasSubstr("esg estimates: NOT_FOUND: spacecraft_id: 'NOPE-1' is not configured"));
  r = Esg(*dir_, *daemon_, "estimates --spacecraft CLI-EST --from yesterday");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("--from: 'yesterday' is not an RFC 3339 time"));
  r = Esg(*dir_, *daemon_,
          "estimates --spacecraft CLI-EST --from 2019-03-02T00:00:00Z --to 2019-03-01T00:00:00Z");
  EXPECT_EQ(r.exit_code, 2) << "refused before the call, as every verb's span (docs/cli.md)";
  EXPECT_THAT(r.err, HasSubstr("esg estimates: --to '2019-03-01T00:00:00Z': is before --from "
                               "'2019-03-02T00:00:00Z'"));
}

}  // namespace
}  // namespace esg::client
