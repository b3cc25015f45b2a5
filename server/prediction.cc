// PredictAttitude: attitude across a gap from a copy of the session (see estimation_core.h and
// docs/service.md "PredictAttitude").
#include <algorithm>
#include <cmath>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "estimator/rotation.h"
#include "estimator/status_macros.h"
#include "proto/convert.h"
#include "server/core_internal.h"
#include "server/estimation_core.h"
#include "server/planned_profile.h"
#include "storage/aem.h"

namespace esg::server {

using estimator::EstimationSession;

absl::StatusOr<esg::v1::PredictResponse> EstimationCore::Predict(
    const esg::v1::PredictRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  std::shared_ptr<Spacecraft> sc = Find(request.spacecraft_id());
  if (sc == nullptr) return NotConfigured(request.spacecraft_id());

  // The requested epochs: the from/to grid plus the explicit times.
  std::vector<absl::Time> times;
  if (request.has_from() || request.has_to()) {
    if (!request.has_from()) return absl::InvalidArgumentError("from: required when to is given");
    if (!request.has_to()) return absl::InvalidArgumentError("to: required when from is given");
    ASSIGN_OR_RETURN(absl::Time from, proto_convert::TimeFromProto(request.from()));
    ASSIGN_OR_RETURN(absl::Time to, proto_convert::TimeFromProto(request.to()));
    if (!(request.step_s() > 0) || !std::isfinite(request.step_s())) {
      return absl::InvalidArgumentError(
          absl::StrCat("step_s: must be > 0 when from/to are given, got ", request.step_s()));
    }
    if (to < from) {
      return absl::InvalidArgumentError(absl::StrCat("to: ", FormatUtc(to),
                                                     " is before from ", FormatUtc(from)));
    }
    const double count = std::floor(absl::ToDoubleSeconds(to - from) / request.step_s()) + 1;
    if (count > options_.max_prediction_samples) {
      return absl::OutOfRangeError(absl::StrCat("step_s: ", count, " samples exceed the limit of ",
                                                options_.max_prediction_samples));
    }
    for (int64_t i = 0; i < static_cast<int64_t>(count); ++i) {
      times.push_back(from + absl::Seconds(request.step_s() * static_cast<double>(i)));
    }
  }
  absl::Time explicit_previous = absl::InfinitePast();
  for (int i = 0; i < request.times_size(); ++i) {
    absl::StatusOr<absl::Time> t = proto_convert::TimeFromProto(request.times(i));
    if (!t.ok()) {
      return absl::InvalidArgumentError(absl::StrCat("times[", i, "]: ", t.status().message()));
    }
    if (i > 0 && *t <= explicit_previous) {
      return absl::InvalidArgumentError(absl::StrCat("times[", i, "]: ", FormatUtc(*t),
                                                     " is not after times[", i - 1, "]"));
    }
    explicit_previous = *t;
    times.push_back(*t);
  }
  if (times.empty()) {
    return absl::InvalidArgumentError("times: no epoch requested (give from, to and step_s, or times)");
  }
  if (static_cast<int>(times.size()) > options_.max_prediction_samples) {
    return absl::OutOfRangeError(absl::StrCat("times: ", times.size(),
                                              " samples exceed the limit of ",
                                              options_.max_prediction_samples));
  }
  std::sort(times.begin(), times.end());
  times.erase(std::unique(times.begin(), times.end()), times.end());

  std::optional<SampledProfile> planned;
  if (request.planned_attitude_size() > options_.max_prediction_samples) {
    return absl::OutOfRangeError(absl::StrCat("planned_attitude: ", request.planned_attitude_size(),
                                              " samples exceed the limit of ",
                                              options_.max_prediction_samples));
  }
  if (request.planned_attitude_size() > 0) {
    std::vector<PlannedSample> samples;
    for (int i = 0; i < request.planned_attitude_size(); ++i) {
      const esg::v1::AttitudeSample& s = request.planned_attitude(i);
      if (!s.has_time()) {
        return absl::InvalidArgumentError(absl::StrCat("planned_attitude[", i, "].time: required"));
      }
      if (s.q_in_b_size() != 4) {
        return absl::InvalidArgumentError(absl::StrCat(
            "planned_attitude[", i, "].q_in_b: expected 4 values, got ", s.q_in_b_size()));
      }
      ASSIGN_OR_RETURN(absl::Time t, proto_convert::TimeFromProto(s.time()));
      samples.push_back({t, estimator::QuaternionFromScalarFirst(
                                {s.q_in_b(0), s.q_in_b(1), s.q_in_b(2), s.q_in_b(3)})});
    }
    ASSIGN_OR_RETURN(planned, SampledProfile::Create(std::move(samples)));
  }

  // Copy the session under the lock; predict on the copy.
  std::optional<EstimationSession> session;
  std::string model_name;
  {
    absl::MutexLock lock(&sc->state_mu);
    session = sc->session;
    if (sc->setup != nullptr) model_name = sc->setup->model_name;
  }
  if (!session.has_value() || !session->initialized()) {
    return absl::FailedPreconditionError(absl::StrCat(
        "spacecraft '", sc->id, "' has no attitude yet (no frame with a valid star-tracker "
                                "quaternion and a readable pair has been applied)"));
  }
  const absl::Time last = session->last_frame_time();
  if (times.front() <= last) {
    return absl::OutOfRangeError(absl::StrCat(
        request.has_from() ? "from" : "times", ": ", FormatUtc(times.front()),
        " is not after the last applied frame ", FormatUtc(last)));
  }
  if (times.back() - last > options_.max_prediction_horizon) {
    return absl::OutOfRangeError(absl::StrCat(
        request.has_to() ? "to" : "times", ": ", FormatUtc(times.back()),
        " is beyond the prediction horizon of ",
        absl::FormatDuration(options_.max_prediction_horizon), " after the last applied frame ",
        FormatUtc(last)));
  }
  ASSIGN_OR_RETURN(std::vector<estimator::PredictedSample> predicted,
                   session->Predict(times, planned.has_value() ? &*planned : nullptr,
                                    planned.has_value() ? planned->start() : absl::UnixEpoch()));
  esg::v1::PredictResponse response;
  std::vector<storage::AemSample> aem_samples;
  for (const estimator::PredictedSample& p : predicted) {
    FillSample(p.time, p.attitude, p.h_in, response.add_samples());
    if (request.aem()) aem_samples.push_back({p.time, p.attitude.q_in_b.normalized()});
  }
  if (request.aem()) {
    storage::AemHeader header;
    header.object_name = sc->id;
    header.object_id = sc->id;
    header.originator = "ESG-ESGD";
    header.creation_date = absl::Now();
    header.comments.push_back(absl::StrCat("Predicted attitude q_in_b, calibration model ",
                                           model_name, ", from the state at ", FormatUtc(last)));
    ASSIGN_OR_RETURN(std::string text, storage::WriteAem(header, aem_samples));
    response.set_aem_text(std::move(text));
  }
  return response;
}

}  // namespace esg::server
