// Tests of storage/coefficient_store.h: round trip of all 16 values and sigmas with NaN, the
// per-gyro and time-window filters, the SI <-> deg/h, arcsec conversions, argument errors.
#include "storage/coefficient_store.h"

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/schema.h"
#include "storage/storage.h"
#include "tests/storage/backend.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/status_matchers.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::BackendTest;
using ::esg::storage::testing::IsOkAndHolds;
using ::esg::storage::testing::QueryDouble;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::IsEmpty;

CoefficientRecord Record(const std::string& id, int gyro, double at_seconds) {
  CoefficientRecord r;
  r.spacecraft_id = id;
  r.gyro_id = gyro;
  r.measurement_time = T(at_seconds);
  r.compute_time = T(at_seconds + 1.5);
  r.model_name = "model10";
  for (int i = 0; i < kNumCoefficientValues; ++i) {
    r.values.push_back(0.01 * (i + 1) + gyro + at_seconds * 1e-6);
    r.sigmas.push_back(0.001 * (i + 1));
  }
  return r;
}

std::vector<int> Gyros(const std::vector<CoefficientRecord>& records) {
  std::vector<int> out;
  for (const CoefficientRecord& r : records) out.push_back(r.gyro_id);
  return out;
}

// The CoefficientStore tests run on both engines (tests/storage/backend.h).
class CoefficientStoreTest : public BackendTest {};
ESG_INSTANTIATE_BACKEND_TEST_SUITE(CoefficientStoreTest);

TEST_P(CoefficientStoreTest, RoundTripsValuesSigmasAndNaN) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientRecord written = Record("RDK-1", 2, 600);
  written.values[kCoefficientMu] = std::nan("");   // not estimated
  written.sigmas[kCoefficientNu + 1] = std::nan("");  // unknown
  ASSERT_THAT((*storage)->coefficients().Append(written), IsOk());

  absl::StatusOr<std::vector<CoefficientRecord>> read = (*storage)->coefficients().History(
      "RDK-1", 0, absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_THAT(read, IsOk());
  ASSERT_EQ(read->size(), 1u);
  const CoefficientRecord& r = (*read)[0];
  EXPECT_EQ(r.spacecraft_id, "RDK-1");
  EXPECT_EQ(r.gyro_id, 2);
  EXPECT_EQ(r.measurement_time, T(600));
  EXPECT_EQ(r.compute_time, T(601.5));
  EXPECT_EQ(r.model_name, "model10");
  ASSERT_EQ(r.values.size(), written.values.size());
  ASSERT_EQ(r.sigmas.size(), written.sigmas.size());
  for (int i = 0; i < kNumCoefficientValues; ++i) {
    if (std::isnan(written.values[i])) {
      EXPECT_TRUE(std::isnan(r.values[i])) << i;
    } else {
      // SI -> the column's unit -> SI: equal up to the two conversions.
      EXPECT_DOUBLE_EQ(r.values[i], written.values[i]) << i;
    }
    if (std::isnan(written.sigmas[i])) {
      EXPECT_TRUE(std::isnan(r.sigmas[i])) << i;
    } else {
      EXPECT_DOUBLE_EQ(r.sigmas[i], written.sigmas[i]) << i;
    }
  }
}

TEST_P(CoefficientStoreTest, EachComponentLandsInItsNamedColumn) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientRecord written = Record("RDK-1", 1, 0);
  ASSERT_THAT((*storage)->coefficients().Append(written), IsOk());
  // What a user of plain SQL sees: the record's SI values in the unit each column names.
  using estimator::RadPerSecToDegPerHour;
  using estimator::RadToArcsec;
  using ::testing::DoubleEq;
  EXPECT_THAT(QueryDouble((*storage)->database(), "SELECT k0_deg_h FROM coefficients"),
              IsOkAndHolds(DoubleEq(RadPerSecToDegPerHour(written.values[kCoefficientK0]))));
  EXPECT_THAT(QueryDouble((*storage)->database(), "SELECT c2y_deg_h FROM coefficients"),
              IsOkAndHolds(DoubleEq(RadPerSecToDegPerHour(written.values[kCoefficientC2 + 1]))));
  EXPECT_THAT(
      QueryDouble((*storage)->database(), "SELECT misalignment_z_arcsec FROM coefficients"),
      IsOkAndHolds(DoubleEq(RadToArcsec(written.values[kCoefficientMisalignment + 2]))));
  EXPECT_THAT(QueryDouble((*storage)->database(), "SELECT nu31_sigma_deg_h FROM coefficients"),
              IsOkAndHolds(DoubleEq(RadPerSecToDegPerHour(written.sigmas[kCoefficientNu + 1]))));
}

TEST_P(CoefficientStoreTest, EmptySigmasReadBackEmpty) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientRecord written = Record("RDK-1", 1, 0);
  written.sigmas.clear();
  ASSERT_THAT((*storage)->coefficients().Append(written), IsOk());
  absl::StatusOr<std::vector<CoefficientRecord>> read = (*storage)->coefficients().History(
      "RDK-1", 1, absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_THAT(read, IsOk());
  ASSERT_EQ(read->size(), 1u);
  EXPECT_THAT((*read)[0].sigmas, IsEmpty());
  EXPECT_THAT((*read)[0].values, ::testing::Pointwise(::testing::DoubleEq(), written.values));
}

TEST_P(CoefficientStoreTest, HistoryFiltersByGyroAndHalfOpenWindowInTimeOrder) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientStore& store = (*storage)->coefficients();
  // Inserted out of time order on purpose.
  for (const auto& [gyro, at] : std::vector<std::pair<int, double>>{
           {2, 120}, {1, 120}, {1, 0}, {2, 60}, {3, 240}, {1, 60}}) {
    ASSERT_THAT(store.Append(Record("RDK-1", gyro, at)), IsOk());
  }
  ASSERT_THAT(store.Append(Record("RDK-2", 1, 60)), IsOk());

  absl::StatusOr<std::vector<CoefficientRecord>> all =
      store.History("RDK-1", 0, absl::InfinitePast(), absl::InfiniteFuture());
  ASSERT_THAT(all, IsOk());
  EXPECT_THAT(Gyros(*all), ElementsAre(1, 1, 2, 1, 2, 3));  // by (time, gyro)
  for (size_t i = 1; i < all->size(); ++i) {
    EXPECT_LE((*all)[i - 1].measurement_time, (*all)[i].measurement_time);
  }
  absl::StatusOr<std::vector<CoefficientRecord>> gyro1 = store.History("RDK-1", 1, T(60), T(120));
  ASSERT_THAT(gyro1, IsOk());
  ASSERT_EQ(gyro1->size(), 1u);  // T(120) is excluded
  EXPECT_EQ((*gyro1)[0].measurement_time, T(60));
  EXPECT_THAT(store.History("RDK-1", 4, absl::InfinitePast(), absl::InfiniteFuture()),
              IsOkAndHolds(IsEmpty()));
  EXPECT_THAT(store.History("RDK-1", -1, T(0), T(1)),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("gyro_id")));
}

TEST_P(CoefficientStoreTest, RejectsMalformedRecords) {
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(NewDatabase());
  ASSERT_THAT(storage, IsOk());
  CoefficientStore& store = (*storage)->coefficients();
  CoefficientRecord r = Record("RDK-1", 0, 0);
  EXPECT_THAT(store.Append(r),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("gyro_id = 0")));
  r = Record("RDK-1", 1, 0);
  r.values.pop_back();
  EXPECT_THAT(store.Append(r),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("values: 15 entries")));
  r = Record("RDK-1", 1, 0);
  r.sigmas.resize(13);
  EXPECT_THAT(store.Append(r), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("sigmas")));
  r = Record("RDK-1", 1, 0);
  r.model_name.clear();
  EXPECT_THAT(store.Append(r),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("model_name")));
  r = Record("", 1, 0);
  EXPECT_THAT(store.Append(r),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("spacecraft_id")));
  EXPECT_THAT(store.History("RDK-1", 0, absl::InfinitePast(), absl::InfiniteFuture()),
              IsOkAndHolds(IsEmpty()));
}

TEST(CoefficientValues, ConvertsEstimatorSiToTheStoredUnitsAndBack) {
  estimator::DriftCoefficients drift;
  drift.k0 = estimator::DegPerHourToRadPerSec(0.12);
  drift.C1 = Eigen::Vector3d(estimator::DegPerHourToRadPerSec(0.1),
                             estimator::DegPerHourToRadPerSec(-0.2),
                             estimator::DegPerHourToRadPerSec(0.05));
  drift.C2 = Eigen::Vector3d(estimator::DegPerHourToRadPerSec(-0.5), 0.0, 0.0);
  drift.mu = Eigen::Vector3d(0.0, estimator::DegPerHourToRadPerSec(0.01), 0.0);
  drift.nu = Eigen::Vector3d(0.0, 0.0, estimator::DegPerHourToRadPerSec(0.02));
  const Eigen::Vector3d misalignment_b(estimator::ArcsecToRad(10.0), estimator::ArcsecToRad(-20.0),
                                       estimator::ArcsecToRad(30.0));
  const std::vector<double> values = ToCoefficientValues(drift, misalignment_b);
  ASSERT_EQ(values.size(), static_cast<size_t>(kNumCoefficientValues));
  // SI, in the layout of records.h.
  EXPECT_EQ(values[kCoefficientK0], drift.k0);
  EXPECT_EQ(values[kCoefficientC1 + 1], drift.C1[1]);
  EXPECT_EQ(values[kCoefficientC2], drift.C2[0]);
  EXPECT_EQ(values[kCoefficientMu + 1], drift.mu[1]);  // mu23
  EXPECT_EQ(values[kCoefficientNu + 2], drift.nu[2]);  // nu12
  EXPECT_EQ(values[kCoefficientMisalignment + 1], misalignment_b[1]);

  estimator::DriftCoefficients back;
  Eigen::Vector3d misalignment_back;
  ASSERT_THAT(FromCoefficientValues(values, &back, &misalignment_back), IsOk());
  EXPECT_TRUE(back.AsVector().isApprox(drift.AsVector(), 1e-14));
  EXPECT_TRUE(misalignment_back.isApprox(misalignment_b, 1e-14));
  EXPECT_THAT(FromCoefficientValues(absl::MakeConstSpan(values).subspan(1), &back,
                                    &misalignment_back),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("15 entries")));
}

}  // namespace
}  // namespace esg::storage
