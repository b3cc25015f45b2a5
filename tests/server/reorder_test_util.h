// Helpers of the reorder-window tests (server and end to end): the frames of a simulated run as
// passes of ground stations, and the stored coefficient history compared with an offline run.
#ifndef ESG_TESTS_SERVER_REORDER_TEST_UTIL_H_
#define ESG_TESTS_SERVER_REORDER_TEST_UTIL_H_

#include <cmath>
#include <cstdint>
#include <string>
#include <vector>

#include "esg/v1/telemetry.pb.h"
#include "estimator/units.h"
#include "gtest/gtest.h"
#include "storage/records.h"
#include "tests/server/server_test_util.h"

namespace esg::testing {

// The current coefficient history `stored` equals the offline run's, estimate by estimate (time
// and gyro), the drift coefficients to 1e-12 deg/h (where the offline run has one). Fatal
// failures stop the comparison: call it inside ASSERT_NO_FATAL_FAILURE.
inline void ExpectDriftCoefficientsEqualOffline(
    const std::vector<storage::CoefficientRecord>& stored,
    const std::vector<OfflineSnapshot>& offline) {
  ASSERT_EQ(stored.size(), offline.size());
  for (size_t k = 0; k < offline.size(); ++k) {
    ASSERT_EQ(stored[k].measurement_time, offline[k].time) << k;
    ASSERT_EQ(stored[k].gyro_id, offline[k].gyro_id) << k;
    for (int i = 0; i < storage::kCoefficientMisalignment; ++i) {
      if (std::isnan(offline[k].values[i])) continue;
      EXPECT_NEAR(stored[k].values[i], offline[k].values[i],
                  estimator::DegPerHourToRadPerSec(1e-12))
          << "estimate " << k << " drift coefficient " << i;
    }
  }
}

// Frames [from, to) of the run, as sent by ground station `station` numbering them
// first_sequence, first_sequence + 1, ...
inline std::vector<esg::v1::TelemetryFrame> StationPass(const SimulatedRun& run, int from, int to,
                                                        const std::string& station,
                                                        int64_t first_sequence) {
  std::vector<esg::v1::TelemetryFrame> out;
  for (int i = from; i < to; ++i) {
    esg::v1::TelemetryFrame f = run.frames[i];
    f.set_station_id(station);
    f.set_sequence(first_sequence + (i - from));
    out.push_back(f);
  }
  return out;
}

}  // namespace esg::testing

#endif  // ESG_TESTS_SERVER_REORDER_TEST_UTIL_H_
