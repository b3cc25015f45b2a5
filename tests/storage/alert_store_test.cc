// Tests of storage/alert_store.h: per-spacecraft numbering, round trip, Since ordering and
// limits, acknowledge/clear state, repeat collapsing, errors.
#include "storage/alert_store.h"

#include <cmath>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/storage.h"
#include "tests/storage/backend.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/status_matchers.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::Alert;
using ::esg::storage::testing::BackendTest;
using ::esg::storage::testing::IsOkAndHolds;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

std::vector<std::pair<std::string, int64_t>> Keys(const std::vector<AlertRecord>& alerts) {
  std::vector<std::pair<std::string, int64_t>> out;
  for (const AlertRecord& a : alerts) out.emplace_back(a.spacecraft_id, a.sequence);
  return out;
}

using Key = std::pair<std::string, int64_t>;

// The AlertStore tests run on both engines (tests/storage/backend.h).
class AlertStoreTest : public BackendTest {};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(AlertStoreTest);

TEST_P(AlertStoreTest, NumbersPerSpacecraftAndRoundTripsEveryField) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  AlertStore& alerts = (*storage)->alerts();
  AlertRecord written = Alert("RDK-1", 60);
  written.sequence = 777;  // ignored
  written.threshold = std::nan("");
  EXPECT_THAT(alerts.Append(written), IsOkAndHolds(1));
  EXPECT_THAT(alerts.Append(Alert("RDK-1", 120)), IsOkAndHolds(2));
  EXPECT_THAT(alerts.Append(Alert("RDK-2", 0)), IsOkAndHolds(1));

  absl::StatusOr<AlertRecord> got = alerts.Get("RDK-1", 1);
  ASSERT_THAT(got, IsOk());
  EXPECT_EQ(got->spacecraft_id, "RDK-1");
  EXPECT_EQ(got->sequence, 1);
  EXPECT_EQ(got->severity, written.severity);
  EXPECT_EQ(got->reason, written.reason);
  EXPECT_EQ(got->subsystem, written.subsystem);
  EXPECT_EQ(got->value, written.value);
  EXPECT_TRUE(std::isnan(got->threshold));
  EXPECT_EQ(got->unit, "arcsec");
  EXPECT_EQ(got->repeat_count, 1);
  EXPECT_EQ(got->first_time, written.first_time);
  EXPECT_EQ(got->measurement_time, written.measurement_time);
  EXPECT_EQ(got->compute_time, written.compute_time);
  EXPECT_EQ(got->message, written.message);
  EXPECT_FALSE(got->acknowledged);
  EXPECT_EQ(got->acknowledged_by, "");
  EXPECT_EQ(got->acknowledged_time, absl::InfinitePast());
  EXPECT_FALSE(got->cleared);
  EXPECT_THAT(alerts.Get("RDK-1", 3), StatusIs(absl::StatusCode::kNotFound, HasSubstr("3")));
}

TEST_P(AlertStoreTest, SinceOrdersByMeasurementTimeThenSequenceAndHonoursLimit) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  AlertStore& alerts = (*storage)->alerts();
  // Sequences follow insertion; measurement times do not.
  ASSERT_THAT(alerts.Append(Alert("RDK-1", 300)), IsOkAndHolds(1));
  ASSERT_THAT(alerts.Append(Alert("RDK-1", 100)), IsOkAndHolds(2));
  ASSERT_THAT(alerts.Append(Alert("RDK-1", 100)), IsOkAndHolds(3));
  ASSERT_THAT(alerts.Append(Alert("RDK-2", 100)), IsOkAndHolds(1));
  ASSERT_THAT(alerts.Append(Alert("RDK-1", 200)), IsOkAndHolds(4));

  absl::StatusOr<std::vector<AlertRecord>> one = alerts.Since("RDK-1", T(0), 100);
  ASSERT_THAT(one, IsOk());
  EXPECT_THAT(Keys(*one), ElementsAre(Key("RDK-1", 2), Key("RDK-1", 3), Key("RDK-1", 4),
                                      Key("RDK-1", 1)));
  absl::StatusOr<std::vector<AlertRecord>> later = alerts.Since("RDK-1", T(200), 100);
  ASSERT_THAT(later, IsOk());
  EXPECT_THAT(Keys(*later), ElementsAre(Key("RDK-1", 4), Key("RDK-1", 1)));  // since inclusive
  absl::StatusOr<std::vector<AlertRecord>> all = alerts.Since("", T(0), 3);
  ASSERT_THAT(all, IsOk());
  EXPECT_THAT(Keys(*all), ElementsAre(Key("RDK-1", 2), Key("RDK-1", 3), Key("RDK-2", 1)));
  EXPECT_THAT(alerts.Since("RDK-1", T(1000), 10), IsOkAndHolds(IsEmpty()));
  EXPECT_THAT(alerts.Since("", T(0), 0),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("limit")));
}

TEST_P(AlertStoreTest, AcknowledgeRecordsOperatorOnceAndClearSetsTheFlag) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  AlertStore& alerts = (*storage)->alerts();
  ASSERT_THAT(alerts.Append(Alert("RDK-1", 60)), IsOkAndHolds(1));
  ASSERT_THAT(alerts.Append(Alert("RDK-1", 70)), IsOkAndHolds(2));

  absl::StatusOr<AlertRecord> acked = alerts.Acknowledge("RDK-1", 1, "ivanova", T(500));
  ASSERT_THAT(acked, IsOk());
  EXPECT_TRUE(acked->acknowledged);
  EXPECT_EQ(acked->acknowledged_by, "ivanova");
  EXPECT_EQ(acked->acknowledged_time, T(500));
  EXPECT_FALSE(acked->cleared);
  // A second acknowledgement does not overwrite the first.
  absl::StatusOr<AlertRecord> again = alerts.Acknowledge("RDK-1", 1, "petrov", T(900));
  ASSERT_THAT(again, IsOk());
  EXPECT_EQ(again->acknowledged_by, "ivanova");
  EXPECT_EQ(again->acknowledged_time, T(500));

  absl::StatusOr<AlertRecord> cleared = alerts.Clear("RDK-1", 1);
  ASSERT_THAT(cleared, IsOk());
  EXPECT_TRUE(cleared->cleared);
  EXPECT_TRUE(cleared->acknowledged);
  // The other alert is untouched, and the state persists in the history.
  absl::StatusOr<std::vector<AlertRecord>> history = alerts.Since("RDK-1", T(0), 10);
  ASSERT_THAT(history, IsOk());
  ASSERT_EQ(history->size(), 2u);
  EXPECT_TRUE((*history)[0].cleared);
  EXPECT_FALSE((*history)[1].acknowledged);
  EXPECT_FALSE((*history)[1].cleared);

  EXPECT_THAT(alerts.Acknowledge("RDK-1", 9, "ivanova", T(1)),
              StatusIs(absl::StatusCode::kNotFound, ::testing::_));
  EXPECT_THAT(alerts.Acknowledge("RDK-1", 2, "", T(1)),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("operator")));
  EXPECT_THAT(alerts.Clear("RDK-9", 1), StatusIs(absl::StatusCode::kNotFound, ::testing::_));
}

TEST_P(AlertStoreTest, UpdateRepeatCollapsesRepeatsIntoTheAlert) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  AlertStore& alerts = (*storage)->alerts();
  ASSERT_THAT(alerts.Append(Alert("RDK-1", 60)), IsOkAndHolds(1));
  ASSERT_THAT(alerts.UpdateRepeat("RDK-1", 1, 5, T(360)), IsOk());
  absl::StatusOr<AlertRecord> got = alerts.Get("RDK-1", 1);
  ASSERT_THAT(got, IsOk());
  EXPECT_EQ(got->repeat_count, 5);
  EXPECT_EQ(got->first_time, T(60));
  EXPECT_EQ(got->measurement_time, T(360));
  EXPECT_THAT(alerts.UpdateRepeat("RDK-1", 2, 2, T(1)), StatusIs(absl::StatusCode::kNotFound, ::testing::_));
  EXPECT_THAT(alerts.UpdateRepeat("RDK-1", 1, 0, T(1)),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("repeat_count")));
}

TEST_P(AlertStoreTest, RejectsIncompleteAlerts) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  AlertStore& alerts = (*storage)->alerts();
  AlertRecord a = Alert("RDK-1", 0);
  a.severity.clear();
  EXPECT_THAT(alerts.Append(a), StatusIs(absl::StatusCode::kInvalidArgument,
                                         HasSubstr("alert.severity")));
  a = Alert("RDK-1", 0);
  a.reason.clear();
  EXPECT_THAT(alerts.Append(a), StatusIs(absl::StatusCode::kInvalidArgument,
                                         HasSubstr("alert.reason")));
  a = Alert("RDK-1", 0);
  a.repeat_count = 0;
  EXPECT_THAT(alerts.Append(a), StatusIs(absl::StatusCode::kInvalidArgument,
                                         HasSubstr("alert.repeat_count")));
  EXPECT_THAT(alerts.Since("", absl::InfinitePast(), 10), IsOkAndHolds(IsEmpty()));
}

}  // namespace
}  // namespace esg::storage
