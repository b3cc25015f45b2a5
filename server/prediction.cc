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

// The latest archived frame of `id` at or before `first` with a valid star-tracker quaternion
// and at least two gyro readings (within kFixLookbackFrames), where the recorded readings start.
absl::StatusOr<estimator::TelemetryFrame> LatestFix(storage::Storage& storage,
                                                    const std::string& id, absl::Time first) {
  ASSIGN_OR_RETURN(std::vector<storage::ArchivedFrame> back,
                   storage.archive().ReadAtOrBefore(id, first, kFixLookbackFrames));
  for (const storage::ArchivedFrame& a : back) {
    esg::v1::TelemetryFrame proto;
    if (!proto.ParseFromString(a.payload)) {
      return absl::DataLossError(
          absl::StrCat("archived frame ", a.sequence, " of '", id, "' does not parse"));
    }
    if (!proto.has_star_tracker() || !proto.star_tracker().valid() || proto.gyros_size() < 2) {
      continue;
    }
    return proto_convert::FrameFromProto(proto);
  }
  return absl::OutOfRangeError(
      absl::StrCat("from: ", FormatUtc(first), " has no archived star-tracker fix of '", id,
                   "' at or before it (within ", kFixLookbackFrames, " frames)"));
}

// A fresh session with the calibrated drift model (CalibratedConfig) started from the fix, the
// star tracker withheld after it; `start` is its step at the fix.
absl::StatusOr<EstimationSession> StartFromFix(const estimator::SpacecraftConfig& config_in,
                                               const estimator::ModelSpec& model,
                                               const EstimationSession& session,
                                               const estimator::TelemetryFrame& fix,
                                               estimator::StepReport* start) {
  double residual_drift_sigma = 0.0;
  const estimator::SpacecraftConfig config =
      CalibratedConfig(config_in, session, &residual_drift_sigma);
  estimator::SessionOptions options{model};
  options.residual_drift_sigma = residual_drift_sigma;
  options.adaptive_noise = false;
  ASSIGN_OR_RETURN(EstimationSession replay, EstimationSession::Create(config, options));
  ASSIGN_OR_RETURN(*start, replay.AddFrame(fix));
  if (!replay.initialized() || !start->attitude.valid) {
    return absl::FailedPreconditionError(
        absl::StrCat("from: the star-tracker fix at ", FormatUtc(fix.time),
                     " does not initialise an attitude (", start->attitude.invalid_reason, ")"));
  }
  replay.SetStarTrackerUse(false);
  return replay;
}

// The attitude at `t` between two recorded steps: slerp of the quaternions, the larger 1-sigma
// of the two per axis. Refused across a gap longer than `max_gap` or from an invalid attitude.
absl::StatusOr<Predicted> Interpolated(const Predicted& previous, const Predicted& current,
                                       absl::Time t, absl::Duration max_gap) {
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
  return p;
}

// The recorded part: `times` (sorted, all at or before the last applied frame) from a fresh
// session started at the latest star-tracker fix at or before times.front() with the calibrated
// model, run over the archived frames with the star tracker withheld. Between two frames the
// attitude is slerp-interpolated and the 1-sigma is the larger of the two (componentwise).
absl::StatusOr<std::vector<Predicted>> PredictRecorded(
    storage::Storage& storage, const std::string& id, const estimator::SpacecraftConfig& config_in,
    const estimator::ModelSpec& model, const EstimationSession& session,
    const std::vector<absl::Time>& times, absl::Duration max_horizon, absl::Time* fix_time) {
  ASSIGN_OR_RETURN(const estimator::TelemetryFrame fix, LatestFix(storage, id, times.front()));
  *fix_time = fix.time;
  if (times.back() - fix.time > max_horizon) {
    return absl::OutOfRangeError(
        absl::StrCat("to: ", FormatUtc(times.back()), " is more than ",
                     absl::FormatDuration(max_horizon), " after the star-tracker fix at ",
                     FormatUtc(fix.time), " the recorded readings start from"));
  }
  estimator::StepReport start;
  ASSIGN_OR_RETURN(EstimationSession replay,
                   StartFromFix(config_in, model, session, fix, &start));

  const absl::Duration max_gap = absl::Seconds(2.0 * config_in.filter.measurement_step);
  std::vector<Predicted> out;
  out.reserve(times.size());
  size_t k = 0;
  Predicted previous{fix.time, start.attitude, {}};
  const auto with_spin_axes = [&](Predicted p) {
    for (const estimator::GyroEstimate& g : replay.Gyros()) p.h_in.emplace_back(g.id, g.h_in);
    return p;
  };
  auto emit_exact = [&](const Predicted& at) {
    while (k < times.size() && times[k] == at.time) {
      out.push_back(with_spin_axes(at));
      ++k;
    }
  };
  emit_exact(previous);
  // The frames after the fix, read in chunks (memory bounded whatever the telemetry rate), up to
  // the first one at or after the last requested time.
  absl::Time cursor = fix.time;
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
      ASSIGN_OR_RETURN(Predicted p, Interpolated(previous, current, times[k], max_gap));
      out.push_back(with_spin_axes(std::move(p)));
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

// The requested epochs, sorted and without repeats: the from/to grid plus the explicit times.
// Errors name the field; at most `max_samples`.
absl::StatusOr<std::vector<absl::Time>> RequestedEpochs(const esg::v1::PredictRequest& request,
                                                        int max_samples) {
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
    if (count > max_samples) {
      return absl::OutOfRangeError(
          absl::StrCat("step_s: ", count, " samples exceed the limit of ", max_samples));
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
  if (static_cast<int>(times.size()) > max_samples) {
    return absl::OutOfRangeError(
        absl::StrCat("times: ", times.size(), " samples exceed the limit of ", max_samples));
  }
  std::sort(times.begin(), times.end());
  times.erase(std::unique(times.begin(), times.end()), times.end());
  return times;
}

// The planned attitude of the request, if it gives one. Errors name the field; at most
// `max_samples`.
absl::StatusOr<std::optional<SampledProfile>> PlannedAttitude(
    const esg::v1::PredictRequest& request, int max_samples) {
  if (request.planned_attitude_size() > max_samples) {
    return absl::OutOfRangeError(absl::StrCat("planned_attitude: ", request.planned_attitude_size(),
                                              " samples exceed the limit of ", max_samples));
  }
  if (request.planned_attitude_size() == 0) return std::nullopt;
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
  ASSIGN_OR_RETURN(SampledProfile planned, SampledProfile::Create(std::move(samples)));
  return std::optional<SampledProfile>(std::move(planned));
}

// What a prediction rests on, for the words of its assumption and its AEM.
struct PredictionBasis {
  std::string model_name;
  absl::Time last;            // the filter's last applied frame (its estimate `current`)
  AttitudeEstimate current;
  absl::Time recorded_until;  // the last archived frame
  absl::Time fix_time;        // the star-tracker fix of the recorded samples
  size_t recorded_count = 0;  // the first samples of `predicted` that are recorded
  const SampledProfile* planned = nullptr;
  int planned_samples = 0;
};

std::string SigmaText(const AttitudeEstimate& a) {
  const Eigen::Vector3d s = SigmaArcsec(a);
  return absl::StrFormat("%.2f, %.2f, %.2f arcsec about body x, y, z", s.x(), s.y(), s.z());
}

// The sources in words (proto/attitude_source_words.h); the enum names stay in the proto fields.
std::string Words(esg::v1::AttitudeSource s) {
  return std::string(proto_convert::AttitudeSourceWords(s));
}

// The assumption of the recorded samples (empty without any).
std::string RecordedAssumption(const PredictionBasis& b) {
  if (b.recorded_count == 0) return "";
  return absl::StrCat(
      Words(esg::v1::ATTITUDE_SOURCE_RECORDED), " until ", FormatUtc(b.recorded_until),
      " (the last archived frame): archived gyro readings propagated with the calibrated drift "
      "model (",
      b.model_name, ") from the star-tracker fix at ", FormatUtc(b.fix_time),
      "; the star tracker is not used after it, so the 1-sigma is that of the gyros alone since "
      "the fix",
      b.recorded_until > b.last ? absl::StrCat("; includes the archived frames after ",
                                               FormatUtc(b.last),
                                               " that the filter has not applied yet")
                                : std::string());
}

// The assumption of the later samples, the plan's or the hold's (empty without any). They start
// from the filter's last estimate (which may be older than the last archived frame) and
// propagate its covariance: the envelope starts from that estimate's 1-sigma, not from the
// recorded samples' (see the head of this file).
std::string FutureAssumption(const PredictionBasis& b, const std::vector<Predicted>& predicted) {
  if (predicted.size() == b.recorded_count) return "";
  // `how`: along what the propagation runs, for the plan.
  const auto start_text = [&](absl::string_view how) {
    std::string text = absl::StrCat("the 1-sigma is propagated", how,
                                    " from the filter's last estimate at ", FormatUtc(b.last),
                                    " (", SigmaText(b.current), ", the star tracker used up to it)");
    if (b.recorded_count > 0) {
      const Predicted& last_recorded = predicted[b.recorded_count - 1];
      absl::StrAppend(&text, ", not from the recorded samples' (",
                      SigmaText(last_recorded.attitude), " at ", FormatUtc(last_recorded.time),
                      "): the envelope steps there because the estimate changes, from the gyros "
                      "alone to the filter's");
    }
    return text;
  };
  if (b.planned != nullptr) {
    return absl::StrCat(Words(esg::v1::ATTITUDE_SOURCE_PLANNED), " after ",
                        FormatUtc(b.recorded_until), ": the planned attitude given (",
                        b.planned_samples, " samples from ", FormatUtc(b.planned->start()),
                        ", slerp between them, held beyond its ends); ",
                        start_text(" along the gyro readings the plan implies"));
  }
  return absl::StrCat(Words(esg::v1::ATTITUDE_SOURCE_INERTIAL_HOLD), " after ",
                      FormatUtc(b.recorded_until),
                      ": no planned attitude given, the attitude of the filter's last estimate "
                      "held inertially fixed; wrong by the body's motion if it moves; ",
                      start_text(""));
}

// The response: the samples, what they assume, and with `aem` the AEM of them, one block per
// source.
absl::StatusOr<esg::v1::PredictResponse> PredictionResponse(const std::string& spacecraft_id,
                                                            const PredictionBasis& b,
                                                            const std::vector<Predicted>& predicted,
                                                            bool aem) {
  const bool any_future = predicted.size() > b.recorded_count;
  // What the prediction assumes, in the response and in the AEM.
  const esg::v1::AttitudeSource source = !any_future ? esg::v1::ATTITUDE_SOURCE_RECORDED
                                         : b.planned != nullptr
                                             ? esg::v1::ATTITUDE_SOURCE_PLANNED
                                             : esg::v1::ATTITUDE_SOURCE_INERTIAL_HOLD;
  const std::string recorded_text = RecordedAssumption(b);
  const std::string future_text = FutureAssumption(b, predicted);
  esg::v1::PredictResponse response;
  response.set_attitude_source(source);
  response.set_recorded_samples(static_cast<int32_t>(b.recorded_count));
  *response.mutable_last_applied_time() = proto_convert::TimeToProto(b.last);
  *response.mutable_last_archived_time() = proto_convert::TimeToProto(b.recorded_until);
  std::vector<std::string> assumption;
  if (!recorded_text.empty()) assumption.push_back(recorded_text);
  if (!future_text.empty()) assumption.push_back(future_text);
  response.set_assumption(absl::StrJoin(assumption, "; "));

  std::vector<storage::AemBlock> blocks;
  for (size_t i = 0; i < predicted.size(); ++i) {
    const Predicted& p = predicted[i];
    FillSample(p.time, p.attitude, p.h_in, response.add_samples());
    if (!aem) continue;
    const bool recorded = i < b.recorded_count;
    if (blocks.empty() || (i == b.recorded_count && i > 0)) {
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
  if (aem) {
    const absl::Time now = absl::Now();
    storage::AemHeader header;
    header.object_name = spacecraft_id;
    header.object_id = spacecraft_id;
    header.originator = "ESG-ESGD";
    header.creation_date = now;
    header.message_id = absl::StrCat(spacecraft_id, "-PRED-",
                                     absl::FormatTime("%Y%m%dT%H%M%E6S", now, absl::UTCTimeZone()));
    header.comments.push_back(absl::StrCat("Predicted attitude q_in_b of ", spacecraft_id,
                                           ", calibration model ", b.model_name,
                                           ", state of the last applied frame ", FormatUtc(b.last),
                                           ", last archived frame ", FormatUtc(b.recorded_until)));
    ASSIGN_OR_RETURN(std::string text, storage::WriteAemBlocks(header, blocks));
    response.set_aem_text(std::move(text));
  }
  return response;
}

}  // namespace

absl::StatusOr<esg::v1::PredictResponse> EstimationCore::Predict(
    const esg::v1::PredictRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  ASSIGN_OR_RETURN(std::shared_ptr<Spacecraft> sc, Lookup(request.spacecraft_id()));
  ASSIGN_OR_RETURN(const std::vector<absl::Time> times,
                   RequestedEpochs(request, options_.max_prediction_samples));
  ASSIGN_OR_RETURN(const std::optional<SampledProfile> planned,
                   PlannedAttitude(request, options_.max_prediction_samples));

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
  PredictionBasis basis;
  basis.model_name = setup->model_name;
  basis.current = session->CurrentAttitude();
  if (session->state() == estimator::SessionState::kFaulted || !basis.current.valid) {
    return absl::FailedPreconditionError(absl::StrCat(
        "spacecraft_id: '", sc->id, "' is ", estimator::SessionStateName(session->state()),
        ": its attitude output is not available",
        basis.current.valid
            ? " (a gyro of the working pair was isolated; acknowledge and reconfigure)"
            : absl::StrCat(" (", basis.current.invalid_reason, ")")));
  }
  basis.last = session->last_frame_time();
  if (times.back() - basis.last > options_.max_prediction_horizon) {
    return absl::OutOfRangeError(absl::StrCat(
        request.has_to() ? "to" : "times", ": ", FormatUtc(times.back()),
        " is beyond the prediction horizon of ",
        absl::FormatDuration(options_.max_prediction_horizon), " after the last applied frame ",
        FormatUtc(basis.last)));
  }
  // Epochs up to the last archived frame use the recorded readings, including frames the filter
  // has not applied yet (it runs behind ingest); later ones the plan or the hold, propagated
  // from the filter's last estimate at `last`.
  basis.recorded_until = std::max(basis.last, archived_until);
  const auto split = std::upper_bound(times.begin(), times.end(), basis.recorded_until);
  const std::vector<absl::Time> recorded_times(times.begin(), split);
  const std::vector<absl::Time> future_times(split, times.end());
  basis.recorded_count = recorded_times.size();
  basis.planned = planned.has_value() ? &*planned : nullptr;
  basis.planned_samples = request.planned_attitude_size();

  std::vector<Predicted> predicted;
  basis.fix_time = absl::InfinitePast();
  if (!recorded_times.empty()) {
    ASSIGN_OR_RETURN(predicted, PredictRecorded(*storage_, sc->id, setup->config, setup->model,
                                                *session, recorded_times,
                                                options_.max_prediction_horizon, &basis.fix_time));
  }
  if (!future_times.empty()) {
    ASSIGN_OR_RETURN(std::vector<estimator::PredictedSample> ahead,
                     session->Predict(future_times, basis.planned,
                                      planned.has_value() ? planned->start() : absl::UnixEpoch()));
    for (estimator::PredictedSample& p : ahead) {
      predicted.push_back({p.time, std::move(p.attitude), std::move(p.h_in)});
    }
  }
  return PredictionResponse(sc->id, basis, predicted, request.aem());
}

}  // namespace esg::server
