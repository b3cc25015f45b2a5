// A prediction computed one chunk at a time (prediction.cc; docs/service.md
// "PredictAttitudeStream"): PredictAttitudeStream sends each chunk as it is computed, and
// PredictAttitude gathers the chunks into one PredictResponse. The samples of a chunk are
// computed by the Next call that returns it, not before.
#ifndef ESG_SERVER_PREDICTION_STREAM_H_
#define ESG_SERVER_PREDICTION_STREAM_H_

#include <optional>

#include "absl/status/statusor.h"
#include "esg/v1/estimation_service.pb.h"

namespace esg::server {

// Samples per chunk of PredictAttitudeStream: with AEM about 0.6 MB of message, well under the
// service's 8 MiB message limit.
inline constexpr int kPredictChunkSamples = 2000;

class PredictionStream {
 public:
  virtual ~PredictionStream() = default;

  // The next chunk of at most `max_samples` (>= 1) samples in time order, never spanning a
  // change of attitude_source; nullopt once every sample was returned. The first chunk carries
  // total_samples, recorded_samples, last_applied_time and last_archived_time; the first chunk
  // of each source its assumption. An error (the statuses of PredictAttitude, docs/service.md)
  // ends the prediction: do not call Next again.
  virtual absl::StatusOr<std::optional<esg::v1::PredictChunk>> Next(int max_samples) = 0;
};

}  // namespace esg::server

#endif  // ESG_SERVER_PREDICTION_STREAM_H_
