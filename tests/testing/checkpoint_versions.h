// A session checkpoint of this build in the layout of version 8 or 7
// (estimator/session_checkpoint.cc): version 8 added the count of fixed drift coefficients before
// each gyro's theta, and nothing else; versions 9 and 10 added blocks at the end. Tests that cut
// a checkpoint down to an earlier version start from these layouts.
#ifndef ESG_TESTS_TESTING_CHECKPOINT_VERSIONS_H_
#define ESG_TESTS_TESTING_CHECKPOINT_VERSIONS_H_

#include <cstddef>
#include <cstdlib>
#include <utility>

#include "estimator/session.h"

namespace esg::testing {

// The values of one running gyro before its theta count: id, h_in (3), t1 (3), residual_drift (2).
inline constexpr size_t kGyroValuesBeforeTheta = 9;
// The per-gyro record of versions 1-7: those, theta (13), phi_b (3), faulty, has_reading,
// h_k_last (3); version 8 has one value more (the theta count).
inline constexpr size_t kGyroRecordVersion7 = 30;

inline size_t GyroRecordLength(const estimator::SessionCheckpoint& c) {
  return kGyroRecordVersion7 + (c.version >= 8 ? 1 : 0);
}

// `c` (version 10, of a session without channel terms) as version 8: the turns' axes (the last
// value is their count) and the empty channels' block (one 0) cut off; version 8 or earlier
// unchanged.
inline estimator::SessionCheckpoint AsVersion8(estimator::SessionCheckpoint c) {
  if (c.version < 10) return c;
  const size_t axes = static_cast<size_t>(c.values.back());
  c.values.resize(c.values.size() - axes - 1);
  if (c.values.back() != 0.0) std::abort();  // a channels' block that is not empty
  c.values.pop_back();
  c.version = 8;
  return c;
}

// `c` (version 10 or 8) with the theta counts taken out, as version 7; an earlier version
// unchanged.
inline estimator::SessionCheckpoint AsVersion7(estimator::SessionCheckpoint c) {
  c = AsVersion8(std::move(c));
  if (c.version < 8) return c;
  size_t pos = 22;  // the scalar fields before convergence_mark_sigma's length m
  const size_t m = static_cast<size_t>(c.values.at(pos));
  pos += 1 + m;
  const size_t gyros = static_cast<size_t>(c.values.at(pos++));
  for (size_t g = 0; g < gyros; ++g) {
    c.values.erase(c.values.begin() + static_cast<std::ptrdiff_t>(pos + kGyroValuesBeforeTheta));
    pos += kGyroRecordVersion7;
  }
  c.version = 7;
  return c;
}

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_CHECKPOINT_VERSIONS_H_
