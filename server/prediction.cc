// PredictAttitude and PredictAttitudeStream (see estimation_core.h, prediction_stream.h and
// docs/service.md "PredictAttitude"): samples at or before the last archived frame from the
// archived gyro readings (ATTITUDE_SOURCE_RECORDED), whether the filter has applied those frames
// yet or not; later ones with the planned attitude (PLANNED) or an inertial hold (INERTIAL_HOLD).
// The response and the AEM say which, in words (proto/attitude_source_words.h).
//
// The 1-sigma is continuous at the switch by construction (docs/physics.md "The prediction's
// envelope"): the recorded samples come from a fresh session started at a star-tracker fix that
// withholds the star tracker after it (the gyros alone since the fix); when a prediction has
// recorded samples, that session is run to the last archived frame and the plan or the hold is
// propagated from it, its attitude and covariance carried across, so the first later sample's
// 1-sigma is the recorded run's grown by the propagation, never below it. Only a prediction
// without recorded samples starts from the filter's last estimate (the star tracker used up to
// it). The samples are computed one chunk at a time (Prediction::Next).
#include <algorithm>
#include <cmath>
#include <limits>
#include <memory>
#include <optional>
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
#include "server/prediction_stream.h"
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
  size_t recorded_count = 0;  // the first samples that are recorded
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

// The assumption of the later samples, the plan's or the hold's. `start` is the attitude they
// are propagated from: with recorded samples the recorded run's at the last archived frame
// (carried across the switch), else the filter's last estimate.
std::string FutureAssumption(const PredictionBasis& b, const AttitudeEstimate& start) {
  std::string from;
  if (b.recorded_count > 0) {
    from = absl::StrCat(
        "the 1-sigma continues from the recorded readings' at the switch (", SigmaText(start),
        " at ", FormatUtc(b.recorded_until),
        "): their covariance is carried across and grows with the drift model's uncertainty, "
        "the star tracker not used");
  } else {
    from = absl::StrCat("the 1-sigma is propagated from the filter's last estimate at ",
                        FormatUtc(b.last), " (", SigmaText(start),
                        ", the star tracker used up to it) and grows with the drift model's "
                        "uncertainty");
  }
  const std::string switch_time = FormatUtc(b.recorded_count > 0 ? b.recorded_until : b.last);
  if (b.planned != nullptr) {
    return absl::StrCat(Words(esg::v1::ATTITUDE_SOURCE_PLANNED), " after ", switch_time,
                        ": the planned attitude given (", b.planned_samples, " samples from ",
                        FormatUtc(b.planned->start()),
                        ", slerp between them, held beyond its ends), propagated along the gyro "
                        "readings the plan implies; ",
                        from);
  }
  return absl::StrCat(Words(esg::v1::ATTITUDE_SOURCE_INERTIAL_HOLD), " after ", switch_time,
                      ": no planned attitude given, the attitude at ", switch_time,
                      b.recorded_count > 0 ? " (the recorded readings')" : " (the filter's)",
                      " held inertially fixed; wrong by the body's motion if it moves; ", from);
}

// One prediction, computed chunk by chunk. The recorded part advances a fresh session over the
// archived frames (read kReadChunkFrames at a time) only as far as the chunk asked for needs; at
// the switch that session, run to the last archived frame, gives the plan or the hold its
// start. The later samples come from one EstimationSession::Predict call (the session propagates
// a list of epochs in one call); what is kept of them is the estimator's values, the messages
// and the AEM are built per chunk.
class Prediction final : public PredictionStream {
 public:
  Prediction(storage::Storage* storage, std::string id, estimator::SpacecraftConfig config,
             estimator::ModelSpec model, EstimationSession session, PredictionBasis basis,
             std::vector<absl::Time> times, std::optional<SampledProfile> planned, bool aem)
      : storage_(storage),
        id_(std::move(id)),
        config_(std::move(config)),
        model_(std::move(model)),
        session_(std::move(session)),
        basis_(std::move(basis)),
        times_(std::move(times)),
        planned_(std::move(planned)),
        aem_(aem),
        max_gap_(absl::Seconds(2.0 * config_.filter.measurement_step)) {
    basis_.planned = planned_.has_value() ? &*planned_ : nullptr;
  }

  // The recorded run from its star-tracker fix (the latest at or before the first recorded
  // epoch), within `max_horizon` of the last recorded epoch. Errors name the field.
  absl::Status StartRecorded(absl::Duration max_horizon) {
    if (basis_.recorded_count == 0) return absl::OkStatus();
    ASSIGN_OR_RETURN(const estimator::TelemetryFrame fix,
                     LatestFix(*storage_, id_, times_.front()));
    basis_.fix_time = fix.time;
    const absl::Time last_recorded = times_[basis_.recorded_count - 1];
    if (last_recorded - fix.time > max_horizon) {
      return absl::OutOfRangeError(
          absl::StrCat("to: ", FormatUtc(last_recorded), " is more than ",
                       absl::FormatDuration(max_horizon), " after the star-tracker fix at ",
                       FormatUtc(fix.time), " the recorded readings start from"));
    }
    estimator::StepReport start;
    ASSIGN_OR_RETURN(EstimationSession replay,
                     StartFromFix(config_, model_, *session_, fix, &start));
    replay_ = std::move(replay);
    current_ = Predicted{fix.time, start.attitude, {}};
    previous_ = current_;
    cursor_ = fix.time;
    return absl::OkStatus();
  }

  absl::StatusOr<std::optional<esg::v1::PredictChunk>> Next(int max_samples) override {
    if (k_ == times_.size()) return std::nullopt;
    const size_t limit = static_cast<size_t>(std::max(1, max_samples));
    esg::v1::PredictChunk chunk;
    if (chunks_ == 0) {
      chunk.set_total_samples(static_cast<int32_t>(times_.size()));
      chunk.set_recorded_samples(static_cast<int32_t>(basis_.recorded_count));
      *chunk.mutable_last_applied_time() = proto_convert::TimeToProto(basis_.last);
      *chunk.mutable_last_archived_time() = proto_convert::TimeToProto(basis_.recorded_until);
    }
    std::vector<Predicted> out;
    const bool recorded = k_ < basis_.recorded_count;
    if (recorded) {
      if (k_ == 0) chunk.set_assumption(RecordedAssumption(basis_));
      RETURN_IF_ERROR(NextRecorded(limit, &out));
      chunk.set_attitude_source(esg::v1::ATTITUDE_SOURCE_RECORDED);
    } else {
      if (!future_started_) {
        RETURN_IF_ERROR(StartFuture());
        chunk.set_assumption(future_text_);
      }
      while (k_ < times_.size() && out.size() < limit) {
        estimator::PredictedSample& p = ahead_[k_ - basis_.recorded_count];
        out.push_back({p.time, std::move(p.attitude), std::move(p.h_in)});
        ++k_;
      }
      if (k_ == times_.size()) ahead_ = {};
      chunk.set_attitude_source(basis_.planned != nullptr ? esg::v1::ATTITUDE_SOURCE_PLANNED
                                                          : esg::v1::ATTITUDE_SOURCE_INERTIAL_HOLD);
    }
    for (const Predicted& p : out) FillSample(p.time, p.attitude, p.h_in, chunk.add_samples());
    if (aem_) {
      ASSIGN_OR_RETURN(std::string text,
                       AemPiece(recorded ? RecordedAssumption(basis_) : future_text_, out));
      chunk.set_aem_text(std::move(text));
    }
    ++chunks_;
    return chunk;
  }

 private:
  Predicted WithSpinAxes(Predicted p) const {
    for (const estimator::GyroEstimate& g : replay_->Gyros()) p.h_in.emplace_back(g.id, g.h_in);
    return p;
  }

  // Applies the next archived frame after the current one, up to the last archived frame when
  // the prediction started (frames archived since are not part of it). False at the end.
  absl::StatusOr<bool> ReadFrame() {
    if (next_ == archived_.size()) {
      if (archive_end_) return false;
      ASSIGN_OR_RETURN(archived_, storage_->archive().ReadAfter(id_, cursor_, kReadChunkFrames));
      next_ = 0;
      if (archived_.empty()) {
        archive_end_ = true;
        return false;
      }
      cursor_ = archived_.back().measurement_time;
    }
    const storage::ArchivedFrame& a = archived_[next_];
    if (a.measurement_time > basis_.recorded_until) {
      archive_end_ = true;
      archived_ = {};
      next_ = 0;
      return false;
    }
    ++next_;
    esg::v1::TelemetryFrame proto;
    if (!proto.ParseFromString(a.payload)) {
      return absl::DataLossError(
          absl::StrCat("archived frame ", a.sequence, " of '", id_, "' does not parse"));
    }
    ASSIGN_OR_RETURN(estimator::TelemetryFrame frame, proto_convert::FrameFromProto(proto));
    absl::StatusOr<estimator::StepReport> report = replay_->AddFrame(frame);
    if (!report.ok()) {
      return absl::InternalError(absl::StrCat("recorded readings: frame at ", FormatUtc(frame.time),
                                              ": ", report.status().message()));
    }
    previous_ = std::move(current_);
    current_ = Predicted{frame.time, report->attitude, {}};
    return true;
  }

  // Recorded samples until `limit` are in `out` or the recorded epochs end. Between two frames
  // the attitude is slerp-interpolated and the 1-sigma is the larger of the two (componentwise:
  // Interpolated).
  absl::Status NextRecorded(size_t limit, std::vector<Predicted>* out) {
    while (k_ < basis_.recorded_count && out->size() < limit) {
      const absl::Time t = times_[k_];
      if (t <= current_.time) {
        if (t == current_.time) {
          if (!current_.attitude.valid) {
            return absl::FailedPreconditionError(
                absl::StrCat("times: the recorded attitude at ", FormatUtc(t),
                             " is not available (", current_.attitude.invalid_reason, ")"));
          }
          out->push_back(WithSpinAxes(current_));
        } else {
          ASSIGN_OR_RETURN(Predicted p, Interpolated(previous_, current_, t, max_gap_));
          out->push_back(WithSpinAxes(std::move(p)));
        }
        ++k_;
        continue;
      }
      ASSIGN_OR_RETURN(const bool read, ReadFrame());
      if (!read) {
        return absl::OutOfRangeError(absl::StrCat(
            "times: ", FormatUtc(t), " is after the last archived frame of '", id_, "'"));
      }
    }
    return absl::OkStatus();
  }

  // The later samples: from the recorded run at the last archived frame (its attitude and
  // covariance carried across the switch) when there are recorded samples, else from the
  // filter's last estimate.
  absl::Status StartFuture() {
    future_started_ = true;
    const std::vector<absl::Time> future(times_.begin() + basis_.recorded_count, times_.end());
    const absl::Time planned_start = planned_.has_value() ? planned_->start() : absl::UnixEpoch();
    const EstimationSession* from = &*session_;
    if (replay_.has_value()) {
      while (current_.time < basis_.recorded_until) {
        ASSIGN_OR_RETURN(const bool read, ReadFrame());
        if (!read) break;
      }
      archived_ = {};
      if (!current_.attitude.valid) {
        return absl::FailedPreconditionError(
            absl::StrCat("times: the recorded attitude at ", FormatUtc(current_.time),
                         ", where the later samples start, is not available (",
                         current_.attitude.invalid_reason, ")"));
      }
      from = &*replay_;
    }
    const AttitudeEstimate start = from->CurrentAttitude();
    ASSIGN_OR_RETURN(ahead_, from->Predict(future, basis_.planned, planned_start));
    future_text_ = FutureAssumption(basis_, start);
    replay_.reset();
    session_.reset();
    return absl::OkStatus();
  }

  // This chunk's part of the AEM: the header before the first chunk's segment, then one segment
  // of the chunk's samples with its source's assumption.
  absl::StatusOr<std::string> AemPiece(const std::string& assumption,
                                       const std::vector<Predicted>& samples) {
    if (chunks_ == 0) {
      const absl::Time now = absl::Now();
      header_.object_name = id_;
      header_.object_id = id_;
      header_.originator = "ESG-ESGD";
      header_.creation_date = now;
      header_.message_id = absl::StrCat(
          id_, "-PRED-", absl::FormatTime("%Y%m%dT%H%M%E6S", now, absl::UTCTimeZone()));
      header_.comments.push_back(absl::StrCat(
          "Predicted attitude q_in_b of ", id_, ", calibration model ", basis_.model_name,
          ", state of the last applied frame ", FormatUtc(basis_.last), ", last archived frame ",
          FormatUtc(basis_.recorded_until)));
    }
    storage::AemBlock block;
    block.comments.push_back(assumption);
    block.comments.push_back(
        "1-sigma about body x, y, z [arcsec] of every epoch: the SIGMA_ARCSEC comments at the "
        "start of the data section");
    block.interpolation_method = "LINEAR";
    block.interpolation_degree = 1;
    for (const Predicted& p : samples) {
      block.samples.push_back({p.time, p.attitude.q_in_b.normalized(), SigmaArcsec(p.attitude)});
    }
    ASSIGN_OR_RETURN(std::string text, storage::WriteAemBlocks(header_, {std::move(block)}));
    if (chunks_ == 0) return text;
    // Later chunks: the segment only (from the blank line before META_START), so that the
    // pieces concatenated are one AEM with one segment per chunk.
    const size_t segment = text.find("\nMETA_START\n");
    if (segment == std::string::npos) return absl::InternalError("AEM segment without META_START");
    return text.substr(segment);
  }

  storage::Storage* const storage_;
  const std::string id_;
  const estimator::SpacecraftConfig config_;
  const estimator::ModelSpec model_;
  std::optional<EstimationSession> session_;  // the filter's, until the later samples start
  PredictionBasis basis_;
  const std::vector<absl::Time> times_;  // every epoch, sorted, without repeats
  const std::optional<SampledProfile> planned_;
  const bool aem_;
  const absl::Duration max_gap_;
  size_t k_ = 0;  // the next epoch to return
  int chunks_ = 0;
  // The recorded run: its session, its last two applied frames, the archive read ahead.
  std::optional<EstimationSession> replay_;
  Predicted previous_;
  Predicted current_;
  std::vector<storage::ArchivedFrame> archived_;
  size_t next_ = 0;
  absl::Time cursor_;
  bool archive_end_ = false;
  // The later samples.
  bool future_started_ = false;
  std::vector<estimator::PredictedSample> ahead_;
  std::string future_text_;
  storage::AemHeader header_;
};

}  // namespace

absl::StatusOr<std::unique_ptr<PredictionStream>> EstimationCore::StartPrediction(
    const esg::v1::PredictRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  ASSIGN_OR_RETURN(std::shared_ptr<Spacecraft> sc, Lookup(request.spacecraft_id()));
  ASSIGN_OR_RETURN(std::vector<absl::Time> times,
                   RequestedEpochs(request, options_.max_prediction_samples));
  ASSIGN_OR_RETURN(std::optional<SampledProfile> planned,
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
  // has not applied yet (it runs behind ingest); later ones the plan or the hold.
  basis.recorded_until = std::max(basis.last, archived_until);
  basis.recorded_count = static_cast<size_t>(
      std::upper_bound(times.begin(), times.end(), basis.recorded_until) - times.begin());
  basis.planned_samples = request.planned_attitude_size();
  basis.fix_time = absl::InfinitePast();
  auto prediction = std::make_unique<Prediction>(
      storage_, sc->id, setup->config, setup->model, std::move(*session), std::move(basis),
      std::move(times), std::move(planned), request.aem());
  RETURN_IF_ERROR(prediction->StartRecorded(options_.max_prediction_horizon));
  return std::unique_ptr<PredictionStream>(std::move(prediction));
}

absl::StatusOr<esg::v1::PredictResponse> EstimationCore::Predict(
    const esg::v1::PredictRequest& request) {
  ASSIGN_OR_RETURN(std::unique_ptr<PredictionStream> prediction, StartPrediction(request));
  esg::v1::PredictResponse response;
  response.set_attitude_source(esg::v1::ATTITUDE_SOURCE_RECORDED);
  std::vector<std::string> assumption;
  bool first = true;
  while (true) {
    // One chunk per source: the AEM has one segment per source.
    ASSIGN_OR_RETURN(std::optional<esg::v1::PredictChunk> chunk,
                     prediction->Next(std::numeric_limits<int>::max()));
    if (!chunk.has_value()) break;
    if (first) {
      response.set_recorded_samples(chunk->recorded_samples());
      *response.mutable_last_applied_time() = chunk->last_applied_time();
      *response.mutable_last_archived_time() = chunk->last_archived_time();
      response.mutable_samples()->Reserve(chunk->total_samples());
      first = false;
    }
    response.set_attitude_source(chunk->attitude_source());
    if (!chunk->assumption().empty()) assumption.push_back(chunk->assumption());
    response.mutable_aem_text()->append(chunk->aem_text());
    for (esg::v1::AttitudeSample& s : *chunk->mutable_samples()) {
      *response.add_samples() = std::move(s);
    }
  }
  response.set_assumption(absl::StrJoin(assumption, "; "));
  return response;
}

}  // namespace esg::server
