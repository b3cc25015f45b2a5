// Tests of storage/diagnosis_store.h: round trip, per-spacecraft listing, NotFound, errors.
#include "storage/diagnosis_store.h"

#include <algorithm>
#include <memory>
#include <string>
#include <vector>

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
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::ElementsAre;
using ::testing::Field;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

DiagnosisRecord Diagnosis(const std::string& id, const std::string& verdict, double from_s) {
  DiagnosisRecord d;
  d.spacecraft_id = id;
  d.from_time = T(from_s);
  d.to_time = T(from_s + 86400);
  d.compute_time = T(from_s + 90000);
  d.verdict = verdict;
  d.report_json = R"({"candidates":[{"name":")" + verdict + R"(","gain":0.8}]})";
  d.frames = 1441 + static_cast<int64_t>(from_s / 60);
  return d;
}

// The DiagnosisStore tests run on both engines (tests/storage/backend.h).
class DiagnosisStoreTest : public BackendTest {};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(DiagnosisStoreTest);

TEST_P(DiagnosisStoreTest, PutGetAndListRoundTrip) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  DiagnosisStore& diagnoses = (*storage)->diagnoses();
  absl::StatusOr<int64_t> first = diagnoses.Put(Diagnosis("RDK-1", "gyro_misalignment", 0));
  absl::StatusOr<int64_t> other = diagnoses.Put(Diagnosis("RDK-2", "unexplained", 0));
  absl::StatusOr<int64_t> second = diagnoses.Put(Diagnosis("RDK-1", "unexplained", 86400));
  ASSERT_THAT(first, IsOk());
  ASSERT_THAT(other, IsOk());
  ASSERT_THAT(second, IsOk());
  EXPECT_LT(*first, *other);
  EXPECT_LT(*other, *second);

  absl::StatusOr<DiagnosisRecord> got = diagnoses.Get(*second);
  ASSERT_THAT(got, IsOk());
  const DiagnosisRecord expected = Diagnosis("RDK-1", "unexplained", 86400);
  EXPECT_EQ(got->id, *second);
  EXPECT_EQ(got->spacecraft_id, "RDK-1");
  EXPECT_EQ(got->from_time, expected.from_time);
  EXPECT_EQ(got->to_time, expected.to_time);
  EXPECT_EQ(got->compute_time, expected.compute_time);
  EXPECT_EQ(got->verdict, "unexplained");
  EXPECT_EQ(got->report_json, expected.report_json);
  EXPECT_EQ(got->frames, expected.frames);
  // Summaries carry the frame count too (only the report is left out).
  absl::StatusOr<std::vector<DiagnosisRecord>> summaries = diagnoses.ListSummaries("RDK-1", 0, 10);
  ASSERT_THAT(summaries, IsOk());
  ASSERT_EQ(summaries->size(), 2u);
  EXPECT_EQ((*summaries)[0].frames, Diagnosis("RDK-1", "gyro_misalignment", 0).frames);
  EXPECT_EQ((*summaries)[1].frames, expected.frames);
  EXPECT_EQ((*summaries)[1].report_json, "");

  EXPECT_THAT(diagnoses.List("RDK-1"),
              IsOkAndHolds(ElementsAre(Field(&DiagnosisRecord::id, *first),
                                       Field(&DiagnosisRecord::id, *second))));
  EXPECT_THAT(diagnoses.List("nobody"), IsOkAndHolds(IsEmpty()));
  EXPECT_THAT(diagnoses.Get(*second + 100),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("diagnosis")));
}

// The bound per spacecraft (docs/service.md "Limits"): beyond it the oldest diagnoses of that
// spacecraft are deleted with the Put; the newest stay with their ids, other spacecraft keep
// theirs, and a dropped id reads NotFound.
TEST_P(DiagnosisStoreTest, KeepsTheNewestPerSpacecraftBeyondItsBound) {
  const std::string path = NewDatabase();
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path);
  ASSERT_THAT(storage, IsOk());
  DiagnosisStore& diagnoses = (*storage)->diagnoses();
  EXPECT_EQ(diagnoses.max_per_spacecraft(), 0);  // a bare store: no bound
  diagnoses.set_max_per_spacecraft(3);
  absl::StatusOr<int64_t> other = diagnoses.Put(Diagnosis("RDK-2", "unexplained", 0));
  ASSERT_THAT(other, IsOk());
  std::vector<int64_t> ids;
  for (int i = 0; i < 8; ++i) {
    absl::StatusOr<int64_t> id =
        diagnoses.Put(Diagnosis("RDK-1", "unexplained", 86400.0 * i));
    ASSERT_THAT(id, IsOk());
    ids.push_back(*id);
    absl::StatusOr<std::vector<DiagnosisRecord>> kept = diagnoses.List("RDK-1");
    ASSERT_THAT(kept, IsOk());
    EXPECT_EQ(kept->size(), std::min<size_t>(i + 1, 3)) << i;
  }
  EXPECT_THAT(diagnoses.List("RDK-1"),
              IsOkAndHolds(ElementsAre(Field(&DiagnosisRecord::id, ids[5]),
                                       Field(&DiagnosisRecord::id, ids[6]),
                                       Field(&DiagnosisRecord::id, ids[7]))));
  EXPECT_THAT(diagnoses.Get(ids[0]), StatusIs(absl::StatusCode::kNotFound, HasSubstr("diagnosis")));
  EXPECT_THAT(diagnoses.Get(ids[4]), StatusIs(absl::StatusCode::kNotFound, HasSubstr("diagnosis")));
  EXPECT_THAT(diagnoses.Get(*other), IsOk());
  // A paged list goes on after the oldest were dropped: ids after the last one seen.
  EXPECT_THAT(diagnoses.ListSummaries("RDK-1", ids[1], 10),
              IsOkAndHolds(ElementsAre(Field(&DiagnosisRecord::id, ids[5]),
                                       Field(&DiagnosisRecord::id, ids[6]),
                                       Field(&DiagnosisRecord::id, ids[7]))));
  // Lowering the bound applies from the next Put.
  diagnoses.set_max_per_spacecraft(1);
  absl::StatusOr<int64_t> last = diagnoses.Put(Diagnosis("RDK-1", "gyro_misalignment", 1e6));
  ASSERT_THAT(last, IsOk());
  EXPECT_THAT(diagnoses.List("RDK-1"),
              IsOkAndHolds(ElementsAre(Field(&DiagnosisRecord::id, *last))));
  EXPECT_THAT(diagnoses.List("RDK-2"), IsOkAndHolds(ElementsAre(Field(&DiagnosisRecord::id, *other))));
}

// Beyond the bound the service's own diagnoses (requested_by "service") go first, oldest first,
// then the operators' oldest; the one just stored is never dropped, even an automatic one
// stored beside operators' that fill the bound.
TEST_P(DiagnosisStoreTest, DropsTheServicesDiagnosesBeforeTheOperatorsBeyondTheBound) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  DiagnosisStore& diagnoses = (*storage)->diagnoses();
  diagnoses.set_max_per_spacecraft(3);
  const auto put = [&](bool automatic, double from_s) -> int64_t {
    DiagnosisRecord d = Diagnosis("RDK-1", "unexplained", from_s);
    if (automatic) {
      d.requested_by = kRequestedByService;
      d.answers_alert = 7;
    }
    absl::StatusOr<int64_t> id = diagnoses.Put(d);
    EXPECT_THAT(id, IsOk());
    return id.ok() ? *id : 0;
  };
  const auto kept = [&] {
    std::vector<int64_t> ids;
    absl::StatusOr<std::vector<DiagnosisRecord>> list = diagnoses.List("RDK-1");
    EXPECT_THAT(list, IsOk());
    if (list.ok()) {
      for (const DiagnosisRecord& d : *list) ids.push_back(d.id);
    }
    return ids;
  };
  const int64_t op1 = put(false, 0);
  const int64_t auto1 = put(true, 1);
  const int64_t auto2 = put(true, 2);
  const int64_t op2 = put(false, 3);  // beyond the bound: the oldest automatic goes
  EXPECT_EQ(kept(), (std::vector<int64_t>{op1, auto2, op2}));
  const int64_t op3 = put(false, 4);  // the other automatic goes, not op1
  EXPECT_EQ(kept(), (std::vector<int64_t>{op1, op2, op3}));
  const int64_t auto3 = put(true, 5);  // kept itself; the oldest operator's goes
  EXPECT_EQ(kept(), (std::vector<int64_t>{op2, op3, auto3}));
  const int64_t op4 = put(false, 6);  // the automatic goes again
  EXPECT_EQ(kept(), (std::vector<int64_t>{op2, op3, op4}));
  EXPECT_THAT(diagnoses.Get(auto1), StatusIs(absl::StatusCode::kNotFound, HasSubstr("diagnosis")));
}

// An operator's cancel of the automatic diagnosis: stored per spacecraft and configuration
// version (the first kept), read back; bad records refused naming the field.
TEST_P(DiagnosisStoreTest, StoresAnOperatorsCancelPerConfigurationVersion) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  DiagnosisStore& diagnoses = (*storage)->diagnoses();
  ASSERT_THAT(diagnoses.PutAutoCancel({"RDK-1", 3, 12, T(60)}), IsOk());
  ASSERT_THAT(diagnoses.PutAutoCancel({"RDK-1", 3, 15, T(90)}), IsOk());
  EXPECT_THAT(diagnoses.AutoCancelled("RDK-1", 3), IsOkAndHolds(true));
  EXPECT_THAT(diagnoses.AutoCancelled("RDK-1", 4), IsOkAndHolds(false));
  EXPECT_THAT(diagnoses.AutoCancelled("RDK-2", 3), IsOkAndHolds(false));
  EXPECT_THAT(diagnoses.PutAutoCancel({"", 3, 12, T(60)}),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("auto_cancel.spacecraft_id")));
  EXPECT_THAT(diagnoses.PutAutoCancel({"RDK-1", 0, 12, T(60)}),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("auto_cancel.config_version")));
  EXPECT_THAT(diagnoses.PutAutoCancel({"RDK-1", 1, 12, absl::InfiniteFuture()}),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("auto_cancel.cancel_time")));
}

// An automatic diagnosis (docs/service.md "Automatic diagnosis") keeps who asked for it and the
// alert it answers, in the full record and in the summaries; a requested one reads back empty/0.
TEST_P(DiagnosisStoreTest, KeepsWhoAskedAndTheAlertAnswered) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  DiagnosisStore& diagnoses = (*storage)->diagnoses();
  DiagnosisRecord automatic = Diagnosis("RDK-1", "rotor_displacement", 0);
  automatic.requested_by = kRequestedByService;
  automatic.answers_alert = 7;
  absl::StatusOr<int64_t> requested = diagnoses.Put(Diagnosis("RDK-1", "none", 0));
  absl::StatusOr<int64_t> answered = diagnoses.Put(automatic);
  ASSERT_THAT(requested, IsOk());
  ASSERT_THAT(answered, IsOk());
  absl::StatusOr<DiagnosisRecord> got = diagnoses.Get(*answered);
  ASSERT_THAT(got, IsOk());
  EXPECT_EQ(got->requested_by, "service");
  EXPECT_EQ(got->answers_alert, 7);
  absl::StatusOr<std::vector<DiagnosisRecord>> summaries = diagnoses.ListSummaries("RDK-1", 0, 10);
  ASSERT_THAT(summaries, IsOk());
  ASSERT_EQ(summaries->size(), 2u);
  EXPECT_EQ((*summaries)[0].requested_by, "");
  EXPECT_EQ((*summaries)[0].answers_alert, 0);
  EXPECT_EQ((*summaries)[1].requested_by, "service");
  EXPECT_EQ((*summaries)[1].answers_alert, 7);
}

TEST_P(DiagnosisStoreTest, RejectsInvalidRecords) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  DiagnosisStore& diagnoses = (*storage)->diagnoses();
  EXPECT_THAT(diagnoses.Put(Diagnosis("RDK-1", "", 0)),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("verdict")));
  DiagnosisRecord reversed = Diagnosis("RDK-1", "unexplained", 0);
  std::swap(reversed.from_time, reversed.to_time);
  EXPECT_THAT(diagnoses.Put(reversed),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("to_time")));
  EXPECT_THAT(diagnoses.Put(Diagnosis("", "unexplained", 0)),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("spacecraft_id")));
  DiagnosisRecord negative = Diagnosis("RDK-1", "unexplained", 0);
  negative.frames = -1;
  EXPECT_THAT(diagnoses.Put(negative),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("diagnosis.frames")));
  DiagnosisRecord no_alert = Diagnosis("RDK-1", "unexplained", 0);
  no_alert.answers_alert = -2;
  EXPECT_THAT(diagnoses.Put(no_alert),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("diagnosis.answers_alert")));
  EXPECT_THAT(diagnoses.List("RDK-1"), IsOkAndHolds(IsEmpty()));
}

}  // namespace
}  // namespace esg::storage
