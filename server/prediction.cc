// PredictAttitude (see estimation_core.h and docs/service.md "PredictAttitude"): samples at or
// before the last archived frame from the archived gyro readings (ATTITUDE_SOURCE_RECORDED),
// whether the filter has applied those frames yet or not; later ones from a copy of the session
// with the planned attitude (PLANNED) or an inertial hold of its last estimate (INERTIAL_HOLD).
// The response and the AEM say which, in words (proto/attitude_source_words.h).
//
// The 1-sigma steps down at the switch, and that is the physics, not a lost covariance: the
// recorded samples come from a fresh session that withholds the star tracker after its fix, so
// their 1-sigma is that of the gyros alone since the fix; the plan or the hold starts from the
// filter's last estimate, which used the star tracker at every frame up to it, and propagates
// that estimate's covariance (its 1-sigma at the first later sample is never below the
// estimate's). Starting the hold from the recorded run's covariance would state an uncertainty
// of another, worse estimate than the one held. The assumption names both 1-sigmas.
#include <algorithm>
#include <cmath>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/string_view.h"
#include "absl/time/clock.h"
#include "estimator/rotation.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"
#include "formats/aem.h"
#include "proto/attitude_source_words.h"
#include "proto/convert.h"
#include "server/core_internal.h"
#include "server/estimation_core.h"
#include "server/planned_profile.h"
#include "server/proto_mapping.h"

namespace esg::server {

using estimator::AttitudeEstimate;
using estimator::EstimationSession;

namespace {

// Frames looked back from the first recorded epoch for a star-tracker fix.
constexpr int64_t kFixLookbackFrames = 4096;
// Archived frames read per query of a recorded-readings run.
constexpr int64_t kReadChunkFrames = 4096;

// One predicted epoch, whatever its source.
struct Predicted {
  absl::Time time;
  AttitudeEstimate attitude;
  std::vector<std::pair<int, Eigen::Vector3d>> h_in;
};

// The configuration of a recorded-readings run: the configured one with the session's
// calibrated drift model as the prior (coefficients, their 1-sigma, the misalignment folded
// into C_b_k with its largest 1-sigma), so a fresh session started from a star-tracker fix
// propagates with what the session has learned. Correlations between coefficients are not
// carried (the prior is diagonal).
estimator::SpacecraftConfig CalibratedConfig(const estimator::SpacecraftConfig& config,
                                             const EstimationSession& session,
                                             double* residual_drift_sigma) {
  estimator::SpacecraftConfig out = config;
  *residual_drift_sigma = 0.0;
  for (const estimator::GyroEstimate& g : session.Gyros()) {
    for (estimator::GyroConfig& c : out.gyros) {
      if (c.id != g.id) continue;
      c.model = g.coefficients;
      c.model_sigma = g.sigma;
      // C_b_k(true) = Exp(phi_b) C_b_k(config) (session.h).
      c.C_b_k = estimator::ExpMatrix(g.misalignment_b) * c.C_b_k;
      c.misalignment_sigma = c.misalignment_sigma > 0.0 ? g.misalignment_sigma_b.maxCoeff() : 0.0;
      *residual_drift_sigma = std::max(*residual_drift_sigma, g.residual_drift_sigma.maxCoeff());
    }
  }
  return out;
}

Eigen::Vector3d SigmaArcsec(const AttitudeEstimate& a) {
  return a.sigma_b.unaryExpr([](double s) { return estimator::RadToArcsec(s); });
}

// The recorded part: `times` (sorted, all at or before the last applied frame) from a fresh
// session started at the latest star-tracker fix at or before times.front() with the calibrated
// model, run over the archived frames with the star tracker withheld. Between two frames the
// attitude is slerp-interpolated and the 1-sigma is the larger of the two (componentwise).
absl::StatusOr<std::vector<Predicted>> PredictRecorded(
    storage::Storage& storage, const std::string& id, const estimator::SpacecraftConfig& config_in,
    const estimator::ModelSpec& model, const EstimationSession& session,
    const std::vector<absl::Time>& times, absl::Duration max_horizon, absl::Time* fix_time) {
  const absl::Time first = times.front();
  ASSIGN_OR_RETURN(std::vector<storage::ArchivedFrame> back,
                   storage.archive().ReadAtOrBefore(id, first, kFixLookbackFrames));
  std::optional<estimator::TelemetryFrame> fix;
  for (const storage::ArchivedFrame& a : back) {
    esg::v1::TelemetryFrame proto;
    if (!proto.ParseFromString(a.payload)) {
      return absl::DataLossError(
          absl::StrCat("archived frame ", a.sequence, " of '", id, "' does not parse"));
    }
    if (!proto.has_star_tracker() || !proto.star_tracker().valid() || proto.gyros_size() < 2) {
      continue;
    }
    ASSIGN_OR_RETURN(estimator::TelemetryFrame frame, proto_convert::FrameFromProto(proto));
    fix = std::move(frame);
    break;
  }
  if (!fix.has_value()) {
    return absl::OutOfRangeError(
        absl::StrCat("from: ", FormatUtc(first), " has no archived star-tracker fix of '", id,
                     "' at or before it (within ", kFixLookbackFrames, " frames)"));
  }
  *fix_time = fix->time;
  if (times.back() - fix->time > max_horizon) {
    return absl::OutOfRangeError(
        absl::StrCat("to: ", FormatUtc(times.back()), " is more than ",
                     absl::FormatDuration(max_horizon), " after the star-tracker fix at ",
                     FormatUtc(fix->time), " the recorded readings start from"));
  }
  double residual_drift_sigma = 0.0;
  const estimator::SpacecraftConfig config =
      CalibratedConfig(config_in, session, &residual_drift_sigma);
  estimator::SessionOptions options{model};
  options.residual_drift_sigma = residual_drift_sigma;
  options.adaptive_noise = false;
  ASSIGN_OR_RETURN(EstimationSession replay, EstimationSession::Create(config, options));
  ASSIGN_OR_RETURN(estimator::StepReport start, replay.AddFrame(*fix));
  if (!replay.initialized() || !start.attitude.valid) {
    return absl::FailedPreconditionError(
        absl::StrCat("from: the star-tracker fix at ", FormatUtc(fix->time),
                     " does not initialise an attitude (", start.attitude.invalid_reason, ")"));
  }
  replay.SetStarTrackerUse(false);

  const absl::Duration max_gap = absl::Seconds(2.0 * config_in.filter.measurement_step);
  std::vector<Predicted> out;
  out.reserve(times.size());
  size_t k = 0;
  Predicted previous{fix->time, start.attitude, {}};
  auto emit_exact = [&](const Predicted& at) {
    while (k < times.size() && times[k] == at.time) {
      Predicted p = at;
      for (const estimator::GyroEstimate& g : replay.Gyros()) p.h_in.emplace_back(g.id, g.h_in);
      out.push_back(std::move(p));
      ++k;
    }
  };
  emit_exact(previous);
  // The frames after the fix, read in chunks (memory bounded whatever the telemetry rate), up to
  // the first one at or after the last requested time.
  absl::Time cursor = fix->time;
  std::vector<storage::ArchivedFrame> archived;
  size_t next = 0;
  while (k < times.size()) {
    if (next == archived.size()) {
      ASSIGN_OR_RETURN(archived, storage.archive().ReadAfter(id, cursor, kReadChunkFrames));
      next = 0;
      if (archived.empty()) break;
      cursor = archived.back().measurement_time;
    }
    const storage::ArchivedFrame& a = archived[next++];
    esg::v1::TelemetryFrame proto;
    if (!proto.ParseFromString(a.payload)) {
      return absl::DataLossError(
          absl::StrCat("archived frame ", a.sequence, " of '", id, "' does not parse"));
    }
    ASSIGN_OR_RETURN(estimator::TelemetryFrame frame, proto_convert::FrameFromProto(proto));
    absl::StatusOr<estimator::StepReport> report = replay.AddFrame(frame);
    if (!report.ok()) {
      return absl::InternalError(absl::StrCat("recorded readings: frame at ", FormatUtc(frame.time),
                                              ": ", report.status().message()));
    }
    const Predicted current{frame.time, report->attitude, {}};
    while (k < times.size() && times[k] < current.time) {
      const absl::Time t = times[k];
      if (current.time - previous.time > max_gap) {
        return absl::OutOfRangeError(absl::StrCat(
            "times: ", FormatUtc(t), " falls in a gap of the archived telemetry (frames at ",
            FormatUtc(previous.time), " and ", FormatUtc(current.time), ")"));
      }
      if (!previous.attitude.valid || !current.attitude.valid) {
        return absl::FailedPreconditionError(
            absl::StrCat("times: the recorded attitude at ", FormatUtc(t), " is not available (",
                         previous.attitude.valid ? current.attitude.invalid_reason
                                                 : previous.attitude.invalid_reason,
                         ")"));
      }
      const double s = absl::ToDoubleSeconds(t - previous.time) /
                       absl::ToDoubleSeconds(current.time - previous.time);
      Predicted p;
      p.time = t;
      p.attitude = current.attitude;
      p.attitude.time = t;
      p.attitude.q_in_b = previous.attitude.q_in_b.slerp(s, current.attitude.q_in_b).normalized();
      p.attitude.sigma_b = previous.attitude.sigma_b.cwiseMax(current.attitude.sigma_b);
      for (const estimator::GyroEstimate& g : replay.Gyros()) p.h_in.emplace_back(g.id, g.h_in);
      out.push_back(std::move(p));
      ++k;
    }
    if (k < times.size() && times[k] == current.time && !current.attitude.valid) {
      return absl::FailedPreconditionError(
          absl::StrCat("times: the recorded attitude at ", FormatUtc(current.time),
                       " is not available (", current.attitude.invalid_reason, ")"));
    }
    emit_exact(current);
    previous = current;
  }
  if (k != times.size()) {
    return absl::OutOfRangeError(absl::StrCat("times: ", FormatUtc(times[k]),
                                              " is after the last archived frame of '", id, "'"));
  }
  return out;
}

}  // namespace

absl::StatusOr<esg::v1::PredictResponse> EstimationCore::Predict(
    const esg::v1::PredictRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  ASSIGN_OR_RETURN(std::shared_ptr<Spacecraft> sc, Lookup(request.spacecraft_id()));

  // The requested epochs: the from/to grid plus the explicit times.
  std::vector<absl::Time> times;
  if (request.has_from() || request.has_to()) {
    if (!request.has_from()) return absl::InvalidArgumentError("from: required when to is given");
    if (!request.has_to()) return absl::InvalidArgumentError("to: required when from is given");
    // [from, to] read as every RPC reads it (proto_mapping.h RequestInterval).
    ASSIGN_OR_RETURN(const estimator::TimeInterval span, RequestInterval(request));
    const absl::Time from = span.from;
    const absl::Time to = span.to;
    if (!(request.step_s() > 0) || !std::isfinite(request.step_s())) {
      return absl::InvalidArgumentError(
          absl::StrCat("step_s: must be > 0 when from/to are given, got ", request.step_s()));
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
      return absl::InvalidArgumentError(
          absl::StrCat("times[", i, "]: ", FormatUtc(*t), " is not after times[", i - 1, "]"));
    }
    explicit_previous = *t;
    times.push_back(*t);
  }
  if (times.empty()) {
    return absl::InvalidArgumentError(
        "times: no epoch requested (give from, to and step_s, or times)");
  }
  if (static_cast<int>(times.size()) > options_.max_prediction_samples) {
    return absl::OutOfRangeError(absl::StrCat(
        "times: ", times.size(), " samples exceed the limit of ", options_.max_prediction_samples));
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

  // Copy the session under the lock; predict on the copy. The archive holds every frame up to
  // last_durable_time (it is raised after the commit), applied by the filter or not.
  std::optional<EstimationSession> session;
  std::shared_ptr<const Setup> setup;
  std::string quarantine_reason;
  absl::Time archived_until = absl::InfinitePast();
  {
    absl::MutexLock lock(&sc->state_mu);
    session = sc->session;
    setup = sc->setup;
    quarantine_reason = sc->apply.quarantine_reason;
    archived_until = sc->last_durable_time;
  }
  // A session whose output is not available refuses, naming its state (docs/service.md).
  if (!quarantine_reason.empty() || setup == nullptr) {
    return absl::FailedPreconditionError(absl::StrCat("spacecraft_id: '", sc->id,
                                                      "' is QUARANTINED (", quarantine_reason,
                                                      "): its attitude output is not available"));
  }
  if (!session.has_value() || !session->initialized()) {
    return absl::FailedPreconditionError(
        absl::StrCat("spacecraft_id: '", sc->id,
                     "' is NO_DATA: it has no attitude yet (no frame with a "
                     "valid star-tracker quaternion and a readable pair has been applied)"));
  }
  const AttitudeEstimate current = session->CurrentAttitude();
  if (session->state() == estimator::SessionState::kFaulted || !current.valid) {
    return absl::FailedPreconditionError(absl::StrCat(
        "spacecraft_id: '", sc->id, "' is ", estimator::SessionStateName(session->state()),
        ": its attitude output is not available",
        current.valid ? " (a gyro of the working pair was isolated; acknowledge and reconfigure)"
                      : absl::StrCat(" (", current.invalid_reason, ")")));
  }
  const absl::Time last = session->last_frame_time();
  if (times.back() - last > options_.max_prediction_horizon) {
    return absl::OutOfRangeError(absl::StrCat(request.has_to() ? "to" : "times", ": ",
                                              FormatUtc(times.back()),
                                              " is beyond the prediction horizon of ",
                                              absl::FormatDuration(options_.max_prediction_horizon),
                                              " after the last applied frame ", FormatUtc(last)));
  }
  // Epochs up to the last archived frame use the recorded readings, including frames the filter
  // has not applied yet (it runs behind ingest); later ones the plan or the hold, propagated
  // from the filter's last estimate at `last`.
  const absl::Time recorded_until = std::max(last, archived_until);
  const auto split = std::upper_bound(times.begin(), times.end(), recorded_until);
  const std::vector<absl::Time> recorded_times(times.begin(), split);
  const std::vector<absl::Time> future_times(split, times.end());

  std::vector<Predicted> predicted;
  absl::Time fix_time = absl::InfinitePast();
  if (!recorded_times.empty()) {
    ASSIGN_OR_RETURN(predicted,
                     PredictRecorded(*storage_, sc->id, setup->config, setup->model, *session,
                                     recorded_times, options_.max_prediction_horizon, &fix_time));
  }
  if (!future_times.empty()) {
    ASSIGN_OR_RETURN(std::vector<estimator::PredictedSample> ahead,
                     session->Predict(future_times, planned.has_value() ? &*planned : nullptr,
                                      planned.has_value() ? planned->start() : absl::UnixEpoch()));
    for (estimator::PredictedSample& p : ahead) {
      predicted.push_back({p.time, std::move(p.attitude), std::move(p.h_in)});
    }
  }

  // What the prediction assumes, in the response and in the AEM.
  const esg::v1::AttitudeSource source = future_times.empty() ? esg::v1::ATTITUDE_SOURCE_RECORDED
                                         : planned.has_value()
                                             ? esg::v1::ATTITUDE_SOURCE_PLANNED
                                             : esg::v1::ATTITUDE_SOURCE_INERTIAL_HOLD;
  // The sources in words (proto/attitude_source_words.h); the enum names stay in the proto
  // fields.
  const auto words = [](esg::v1::AttitudeSource s) {
    return std::string(proto_convert::AttitudeSourceWords(s));
  };
  const auto sigma_text = [](const AttitudeEstimate& a) {
    const Eigen::Vector3d s = SigmaArcsec(a);
    return absl::StrFormat("%.2f, %.2f, %.2f arcsec about body x, y, z", s.x(), s.y(), s.z());
  };
  std::string recorded_text;
  if (!recorded_times.empty()) {
    recorded_text = absl::StrCat(
        words(esg::v1::ATTITUDE_SOURCE_RECORDED), " until ", FormatUtc(recorded_until),
        " (the last archived frame): archived gyro readings propagated with the calibrated drift "
        "model (",
        setup->model_name, ") from the star-tracker fix at ", FormatUtc(fix_time),
        "; the star tracker is not used after it, so the 1-sigma is that of the gyros alone since "
        "the fix",
        recorded_until > last
            ? absl::StrCat("; includes the archived frames after ", FormatUtc(last),
                           " that the filter has not applied yet")
            : std::string());
  }
  // The plan or the hold starts from the filter's last estimate (which may be older than the
  // last archived frame) and propagates its covariance: the envelope starts from that estimate's
  // 1-sigma, not from the recorded samples' (see the head of this file).
  // `how`: along what the propagation runs, for the plan.
  const auto start_text = [&](absl::string_view how) {
    std::string text = absl::StrCat("the 1-sigma is propagated", how,
                                    " from the filter's last estimate at ", FormatUtc(last), " (",
                                    sigma_text(current), ", the star tracker used up to it)");
    if (!recorded_times.empty()) {
      const Predicted& last_recorded = predicted[recorded_times.size() - 1];
      absl::StrAppend(&text, ", not from the recorded samples' (",
                      sigma_text(last_recorded.attitude), " at ", FormatUtc(last_recorded.time),
                      "): the envelope steps there because the estimate changes, from the gyros "
                      "alone to the filter's");
    }
    return text;
  };
  std::string future_text;
  if (!future_times.empty()) {
    future_text =
        planned.has_value()
            ? absl::StrCat(words(esg::v1::ATTITUDE_SOURCE_PLANNED), " after ",
                           FormatUtc(recorded_until), ": the planned attitude given (",
                           request.planned_attitude_size(), " samples from ",
                           FormatUtc(planned->start()),
                           ", slerp between them, held beyond its ends); ",
                           start_text(" along the gyro readings the plan implies"))
            : absl::StrCat(words(esg::v1::ATTITUDE_SOURCE_INERTIAL_HOLD), " after ",
                           FormatUtc(recorded_until),
                           ": no planned attitude given, the attitude of the filter's last "
                           "estimate held inertially fixed; wrong by the body's motion if it "
                           "moves; ",
                           start_text(""));
  }
  esg::v1::PredictResponse response;
  response.set_attitude_source(source);
  response.set_recorded_samples(static_cast<int32_t>(recorded_times.size()));
  *response.mutable_last_applied_time() = proto_convert::TimeToProto(last);
  *response.mutable_last_archived_time() = proto_convert::TimeToProto(recorded_until);
  std::vector<std::string> assumption;
  if (!recorded_text.empty()) assumption.push_back(recorded_text);
  if (!future_text.empty()) assumption.push_back(future_text);
  response.set_assumption(absl::StrJoin(assumption, "; "));

  std::vector<storage::AemBlock> blocks;
  for (size_t i = 0; i < predicted.size(); ++i) {
    const Predicted& p = predicted[i];
    FillSample(p.time, p.attitude, p.h_in, response.add_samples());
    if (!request.aem()) continue;
    const bool recorded = i < recorded_times.size();
    if (blocks.empty() || (i == recorded_times.size() && i > 0)) {
      storage::AemBlock block;
      block.comments.push_back(recorded ? recorded_text : future_text);
      block.comments.push_back(
          "1-sigma about body x, y, z [arcsec] of every epoch: the SIGMA_ARCSEC comments at the "
          "start of the data section");
      block.interpolation_method = "LINEAR";
      block.interpolation_degree = 1;
      blocks.push_back(std::move(block));
    }
    blocks.back().samples.push_back(
        {p.time, p.attitude.q_in_b.normalized(), SigmaArcsec(p.attitude)});
  }
  if (request.aem()) {
    const absl::Time now = absl::Now();
    storage::AemHeader header;
    header.object_name = sc->id;
    header.object_id = sc->id;
    header.originator = "ESG-ESGD";
    header.creation_date = now;
    header.message_id = absl::StrCat(sc->id, "-PRED-",
                                     absl::FormatTime("%Y%m%dT%H%M%E6S", now, absl::UTCTimeZone()));
    header.comments.push_back(absl::StrCat("Predicted attitude q_in_b of ", sc->id,
                                           ", calibration model ", setup->model_name,
                                           ", state of the last applied frame ", FormatUtc(last),
                                           ", last archived frame ", FormatUtc(recorded_until)));
    ASSIGN_OR_RETURN(std::string text, storage::WriteAemBlocks(header, blocks));
    response.set_aem_text(std::move(text));
  }
  return response;
}

}  // namespace esg::server
