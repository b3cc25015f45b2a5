// Tests of storage/estimate_store.h: round trip of a per-step estimate (SI in the record, arcsec in
// the columns, innovations in the session's gyro order), replacement at the same measurement
// time, paging, deletion after a re-run start and before a retention bound, validation; and,
// through storage/storage.h, that a filter job's re-run deletes the steps after its start before
// writing, that retention prunes in the same transaction, and that a replaced session drops the
// spacecraft's estimates. The migration of a version-6 file is in schema_test.cc.
#include "storage/estimate_store.h"

#include <cmath>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/storage.h"
#include "tests/storage/backend.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/status_matchers.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::BackendTest;
using ::esg::storage::testing::IsOkAndHolds;
using ::esg::storage::testing::QueryDouble;
using ::esg::storage::testing::QueryInt;
using ::esg::storage::testing::QueryText;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;

// A valid step of spacecraft `id` at T(at_seconds) with innovations of gyros 2, 1, 3 (in that
// session order) whose values depend on the time, so rows are told apart.
EstimateRecord Estimate(const std::string& id, double at_seconds) {
  EstimateRecord r;
  r.spacecraft_id = id;
  r.measurement_time = T(at_seconds);
  r.compute_time = T(at_seconds + 0.5);
  r.state = "CALIBRATING";
  r.attitude_valid = true;
  const double half = 0.001 * at_seconds;
  r.q_in_b = {std::cos(half), std::sin(half), 0.0, 0.0};
  r.sigma_b = {estimator::ArcsecToRad(1.5), estimator::ArcsecToRad(2.5),
               estimator::ArcsecToRad(3.5 + at_seconds)};
  r.output_pair = {2, 1};
  r.star_tracker_used = true;
  for (int id_gyro : {2, 1, 3}) {
    GyroInnovationRecord g;
    g.gyro_id = id_gyro;
    g.innovation = {estimator::ArcsecToRad(0.25 * id_gyro + at_seconds),
                    estimator::ArcsecToRad(-0.5 * id_gyro)};
    g.sigma = {estimator::ArcsecToRad(4.0 + id_gyro), estimator::ArcsecToRad(5.0 + id_gyro)};
    r.star_tracker_innovations.push_back(g);
  }
  r.star_tracker_test_ratio = 0.75;
  r.last_star_tracker_time = T(at_seconds);
  r.has_attitude_error = true;
  r.attitude_error_b = {estimator::ArcsecToRad(-0.25), estimator::ArcsecToRad(0.5),
                        estimator::ArcsecToRad(0.01 * at_seconds)};
  r.attitude_error_sigma_b = {estimator::ArcsecToRad(0.75), estimator::ArcsecToRad(1.25),
                              estimator::ArcsecToRad(7.0)};
  return r;
}

// Field-by-field equality to the conversion rad -> arcsec -> rad (a few ulp).
void ExpectSame(const EstimateRecord& got, const EstimateRecord& want) {
  constexpr double kRelative = 1e-14;
  auto near = [&](double a, double b) { return std::abs(a - b) <= kRelative * std::abs(b); };
  EXPECT_EQ(got.spacecraft_id, want.spacecraft_id);
  EXPECT_EQ(got.measurement_time, want.measurement_time);
  EXPECT_EQ(got.compute_time, want.compute_time);
  EXPECT_EQ(got.state, want.state);
  EXPECT_EQ(got.attitude_valid, want.attitude_valid);
  if (want.attitude_valid) {
    for (int i = 0; i < 4; ++i) EXPECT_EQ(got.q_in_b[i], want.q_in_b[i]) << i;
    for (int i = 0; i < 3; ++i) EXPECT_TRUE(near(got.sigma_b[i], want.sigma_b[i])) << i;
    EXPECT_EQ(got.output_pair, want.output_pair);
  }
  EXPECT_EQ(got.attitude_invalid_reason, want.attitude_invalid_reason);
  EXPECT_EQ(got.star_tracker_used, want.star_tracker_used);
  EXPECT_EQ(got.star_tracker_test_ratio, want.star_tracker_test_ratio);
  EXPECT_EQ(got.last_star_tracker_time, want.last_star_tracker_time);
  ASSERT_EQ(got.star_tracker_innovations.size(), want.star_tracker_innovations.size());
  for (size_t k = 0; k < want.star_tracker_innovations.size(); ++k) {
    const GyroInnovationRecord& g = got.star_tracker_innovations[k];
    const GyroInnovationRecord& w = want.star_tracker_innovations[k];
    EXPECT_EQ(g.gyro_id, w.gyro_id) << k;
    for (int i = 0; i < 2; ++i) {
      EXPECT_TRUE(near(g.innovation[i], w.innovation[i])) << k << " " << i;
      EXPECT_TRUE(near(g.sigma[i], w.sigma[i])) << k << " " << i;
    }
  }
  EXPECT_EQ(got.has_attitude_error, want.has_attitude_error);
  if (want.has_attitude_error) {
    for (int i = 0; i < 3; ++i) {
      EXPECT_TRUE(near(got.attitude_error_b[i], want.attitude_error_b[i])) << i;
      EXPECT_TRUE(near(got.attitude_error_sigma_b[i], want.attitude_error_sigma_b[i])) << i;
    }
  }
}

// The EstimateStore tests run on both engines (tests/storage/backend.h).
class EstimateStoreTest : public BackendTest {
 protected:
  void SetUp() override {
    BackendTest::SetUp();
    if (HasFatalFailure()) return;
    absl::StatusOr<std::unique_ptr<Storage>> opened = Storage::Open(NewDatabase());
    ASSERT_THAT(opened, IsOk());
    storage_ = std::move(*opened);
  }
  EstimateStore& store() { return storage_->estimates(); }
  std::vector<EstimateRecord> All(const std::string& id) {
    absl::StatusOr<EstimatePage> page =
        store().Page(id, absl::InfinitePast(), absl::InfiniteFuture(), std::nullopt, 100000);
    EXPECT_THAT(page, IsOk());
    return page.ok() ? page->records : std::vector<EstimateRecord>();
  }
  std::vector<absl::Time> Times(const std::string& id) {
    std::vector<absl::Time> out;
    for (const EstimateRecord& r : All(id)) out.push_back(r.measurement_time);
    return out;
  }

  std::unique_ptr<Storage> storage_;
};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(EstimateStoreTest);

TEST_P(EstimateStoreTest, RoundTripKeepsSiValuesAndTheSessionGyroOrderWithArcsecColumns) {
  const EstimateRecord r = Estimate("SC-1", 60);
  ASSERT_THAT(store().Put(r), IsOk());
  const std::vector<EstimateRecord> all = All("SC-1");
  ASSERT_EQ(all.size(), 1u);
  ExpectSame(all[0], r);
  // Columns carry the units their names say: arcsec, by gyro id; the order as ids.
  Database& db = storage_->database();
  EXPECT_THAT(QueryDouble(db, "SELECT sigma_z_arcsec FROM estimates"),
              IsOkAndHolds(::testing::DoubleNear(63.5, 1e-9)));
  EXPECT_THAT(QueryDouble(db, "SELECT innovation_g3_1_arcsec FROM estimates"),
              IsOkAndHolds(::testing::DoubleNear(60.75, 1e-9)));
  EXPECT_THAT(QueryDouble(db, "SELECT innovation_sigma_g1_2_arcsec FROM estimates"),
              IsOkAndHolds(::testing::DoubleNear(6.0, 1e-12)));
  EXPECT_THAT(QueryText(db, "SELECT innovation_gyro_order FROM estimates"),
              IsOkAndHolds(std::string("2,1,3")));
  EXPECT_THAT(QueryInt(db, "SELECT COUNT(*) FROM estimates WHERE innovation_g4_1_arcsec IS NULL"),
              IsOkAndHolds(1));
  EXPECT_THAT(QueryDouble(db, "SELECT attitude_error_z_arcsec FROM estimates"),
              IsOkAndHolds(::testing::DoubleNear(0.6, 1e-12)));
  EXPECT_THAT(QueryDouble(db, "SELECT attitude_error_sigma_y_arcsec FROM estimates"),
              IsOkAndHolds(::testing::DoubleNear(1.25, 1e-12)));
}

TEST_P(EstimateStoreTest, AStepStoredAgainReplacesTheRowAtItsMeasurementTime) {
  ASSERT_THAT(store().Put(Estimate("SC-1", 60)), IsOk());
  ASSERT_THAT(store().Put(Estimate("SC-1", 120)), IsOk());
  EstimateRecord again = Estimate("SC-1", 60);
  again.compute_time = T(9000);
  again.state = "CONVERGED";
  again.star_tracker_innovations.resize(1);
  again.has_attitude_error = false;  // the replaced row's estimate does not linger
  ASSERT_THAT(store().Put(again), IsOk());
  const std::vector<EstimateRecord> all = All("SC-1");
  ASSERT_EQ(all.size(), 2u);
  ExpectSame(all[0], again);
  ExpectSame(all[1], Estimate("SC-1", 120));
}

TEST_P(EstimateStoreTest, AnInvalidOutputStoresNoAttitudeAndNoInnovationsWhenNoneFormed) {
  EstimateRecord r = Estimate("SC-1", 60);
  r.attitude_valid = false;
  r.attitude_invalid_reason = "no readable pair";
  r.star_tracker_innovations.clear();
  r.star_tracker_test_ratio = 0.0;
  r.last_star_tracker_time = absl::InfinitePast();
  r.q_in_b = {std::nan(""), 0, 0, 0};  // not stored, so not checked
  r.has_attitude_error = false;
  r.attitude_error_b = {std::nan(""), 0, 0};  // not stored, so not checked
  ASSERT_THAT(store().Put(r), IsOk());
  Database& db = storage_->database();
  EXPECT_THAT(QueryInt(db,
                       "SELECT COUNT(*) FROM estimates WHERE q0 IS NULL AND sigma_x_arcsec IS NULL "
                       "AND output_reference_gyro_id IS NULL AND innovation_gyro_order IS NULL "
                       "AND last_star_tracker_time_unix_ns IS NULL "
                       "AND attitude_error_x_arcsec IS NULL "
                       "AND attitude_error_sigma_z_arcsec IS NULL"),
              IsOkAndHolds(1));
  const std::vector<EstimateRecord> all = All("SC-1");
  ASSERT_EQ(all.size(), 1u);
  ExpectSame(all[0], r);
}

TEST_P(EstimateStoreTest, PagesFollowTheSpanWithoutGapOrRepeat) {
  for (int i = 1; i <= 25; ++i) ASSERT_THAT(store().Put(Estimate("SC-1", 60 * i)), IsOk());
  ASSERT_THAT(store().Put(Estimate("SC-2", 600)), IsOk());
  // [T(120), T(1320)): steps 2..21, 20 records, in pages of 7.
  std::vector<absl::Time> seen;
  std::optional<absl::Time> after;
  int pages = 0;
  do {
    absl::StatusOr<EstimatePage> page = store().Page("SC-1", T(120), T(1320), after, 7);
    ASSERT_THAT(page, IsOk());
    for (const EstimateRecord& r : page->records) {
      EXPECT_EQ(r.spacecraft_id, "SC-1");
      seen.push_back(r.measurement_time);
    }
    after = page->next;
    ++pages;
  } while (after.has_value());
  EXPECT_EQ(pages, 3);
  ASSERT_EQ(seen.size(), 20u);
  for (size_t k = 0; k < seen.size(); ++k) EXPECT_EQ(seen[k], T(60.0 * (k + 2))) << k;
  // A page that ends exactly at the last record says so.
  absl::StatusOr<EstimatePage> exact = store().Page("SC-1", T(60), T(360), std::nullopt, 5);
  ASSERT_THAT(exact, IsOk());
  EXPECT_EQ(exact->records.size(), 5u);
  EXPECT_FALSE(exact->next.has_value());
  EXPECT_THAT(store().Page("SC-1", T(0), T(1), std::nullopt, 0),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("limit")));
  EXPECT_THAT(store().Count("SC-1"), IsOkAndHolds(25));
}

TEST_P(EstimateStoreTest, DeletesAfterAReRunStartAndBeforeARetentionBoundOfOneSpacecraftOnly) {
  for (int i = 1; i <= 10; ++i) {
    ASSERT_THAT(store().Put(Estimate("SC-1", 60 * i)), IsOk());
    ASSERT_THAT(store().Put(Estimate("SC-2", 60 * i)), IsOk());
  }
  {
    absl::StatusOr<Transaction> txn = storage_->database().Begin();
    ASSERT_THAT(txn, IsOk());
    EXPECT_THAT(store().DeleteAfter(*txn, "SC-1", T(480)), IsOkAndHolds(2));
    EXPECT_THAT(store().DeleteBefore(*txn, "SC-1", T(180)), IsOkAndHolds(2));
    ASSERT_THAT(txn->Commit(), IsOk());
  }
  EXPECT_EQ(Times("SC-1"),
            (std::vector<absl::Time>{T(180), T(240), T(300), T(360), T(420), T(480)}));
  EXPECT_EQ(Times("SC-2").size(), 10u);
  {
    absl::StatusOr<Transaction> txn = storage_->database().Begin();
    ASSERT_THAT(txn, IsOk());
    EXPECT_THAT(store().DeleteAfter(*txn, "SC-2", absl::InfinitePast()), IsOkAndHolds(10));
    ASSERT_THAT(txn->Commit(), IsOk());
  }
  EXPECT_TRUE(Times("SC-2").empty());
  EXPECT_EQ(Times("SC-1").size(), 6u);
}

TEST_P(EstimateStoreTest, RefusesRecordsItCouldNotReadBackNamingTheField) {
  EstimateRecord no_state = Estimate("SC-1", 60);
  no_state.state.clear();
  EXPECT_THAT(store().Put(no_state),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("estimates.state")));
  EstimateRecord repeated = Estimate("SC-1", 60);
  repeated.star_tracker_innovations[1].gyro_id = 2;
  EXPECT_THAT(store().Put(repeated),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("estimates.star_tracker_innovations[1].gyro_id = 2")));
  EstimateRecord bad_pair = Estimate("SC-1", 60);
  bad_pair.output_pair = {0, 1};
  EXPECT_THAT(store().Put(bad_pair),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("estimates.output_pair")));
  EstimateRecord bad_q = Estimate("SC-1", 60);
  bad_q.q_in_b[2] = std::nan("");
  EXPECT_THAT(store().Put(bad_q),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("estimates.q_in_b")));
  EstimateRecord bad_error = Estimate("SC-1", 60);
  bad_error.attitude_error_b[1] = std::nan("");
  EXPECT_THAT(store().Put(bad_error),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("estimates.attitude_error_b[1]")));
  EstimateRecord bad_error_sigma = Estimate("SC-1", 60);
  bad_error_sigma.attitude_error_sigma_b[2] = -1e-6;
  EXPECT_THAT(store().Put(bad_error_sigma),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("estimates.attitude_error_sigma_b[2]")));
  EXPECT_THAT(store().Count("SC-1"), IsOkAndHolds(0));
}

// A filter job's effects with estimates at the given seconds.
FilterEffects Effects(const std::string& id, const std::vector<double>& seconds) {
  FilterEffects e;
  e.spacecraft_id = id;
  for (double s : seconds) e.estimates.push_back(Estimate(id, s));
  e.checkpoint = [id](const std::vector<int64_t>&) {
    CheckpointRecord cp;
    cp.spacecraft_id = id;
    cp.state_blob = "state";
    return cp;
  };
  return e;
}

TEST_P(EstimateStoreTest, AReRunDeletesTheStepsAfterItsStartThenWritesItsOwn) {
  ASSERT_THAT(storage_->CommitFilterEffects(Effects("SC-1", {60, 120, 180, 240, 300})), IsOk());
  // The re-run from the checkpoint of T(120) recomputes 180 and 270: 240 and 300 no longer exist.
  FilterEffects rerun = Effects("SC-1", {180, 270});
  rerun.revision = FilterEffects::Revision{T(120), T(10000), {}, {}};
  ASSERT_THAT(storage_->CommitFilterEffects(rerun), IsOk());
  EXPECT_EQ(Times("SC-1"), (std::vector<absl::Time>{T(60), T(120), T(180), T(270)}));
  // From a fresh session (no checkpoint before the late frame): everything goes.
  FilterEffects fresh = Effects("SC-1", {30});
  fresh.revision = FilterEffects::Revision{absl::InfinitePast(), T(10001), {}, {}};
  ASSERT_THAT(storage_->CommitFilterEffects(fresh), IsOk());
  EXPECT_EQ(Times("SC-1"), (std::vector<absl::Time>{T(30)}));
}

TEST_P(EstimateStoreTest, RetentionPrunesInTheJobTransactionAndAStoreErrorLeavesNothing) {
  ASSERT_THAT(storage_->CommitFilterEffects(Effects("SC-1", {60, 120, 180})), IsOk());
  FilterEffects job = Effects("SC-1", {240, 300});
  job.estimates_before = T(180);
  ASSERT_THAT(storage_->CommitFilterEffects(job), IsOk());
  EXPECT_EQ(Times("SC-1"), (std::vector<absl::Time>{T(180), T(240), T(300)}));
  // All or nothing: a bad record fails the job, and neither its pruning nor its rows are kept.
  FilterEffects bad = Effects("SC-1", {360, 420});
  bad.estimates[1].state.clear();
  bad.estimates_before = T(300);
  EXPECT_THAT(storage_->CommitFilterEffects(bad),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("estimates[1]")));
  EXPECT_EQ(Times("SC-1"), (std::vector<absl::Time>{T(180), T(240), T(300)}));
  FilterEffects other = Effects("SC-1", {480});
  other.estimates[0].spacecraft_id = "SC-2";
  EXPECT_THAT(storage_->CommitFilterEffects(other),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("estimates[0]")));
}

TEST_P(EstimateStoreTest, AReplacedSessionDropsTheSpacecraftsEstimates) {
  ASSERT_THAT(storage_->CommitFilterEffects(Effects("SC-1", {60, 120})), IsOk());
  ASSERT_THAT(storage_->CommitFilterEffects(Effects("SC-2", {60})), IsOk());
  ConfigurationChange change;
  change.config.spacecraft_id = "SC-1";
  change.config.config_json = "{}";
  change.checkpoint.spacecraft_id = "SC-1";
  change.checkpoint.state_blob = "fresh";
  change.new_session = false;
  ASSERT_THAT(storage_->CommitConfiguration(change), IsOk());
  EXPECT_EQ(Times("SC-1").size(), 2u);
  change.new_session = true;
  ASSERT_THAT(storage_->CommitConfiguration(change), IsOk());
  EXPECT_TRUE(Times("SC-1").empty());
  EXPECT_EQ(Times("SC-2").size(), 1u);
}

}  // namespace
}  // namespace esg::storage
