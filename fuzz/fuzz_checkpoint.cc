// Fuzz target: checkpoint decoding and session restore, as the server does it at start-up for
// each spacecraft (server/estimation_core.cc): DecodeCheckpoint (server formats 1 to 3), the
// model it names, EstimationSession::FromCheckpoint (session versions 1 to 10) on the example
// configuration deploy/examples/rdk1.json (propagated at 1 Hz), then the restored session at work.
// Property: a blob is refused with DataLoss, or decodes to a checkpoint that encodes to a fixed
// point; its session is refused with DataLoss "checkpoint...", or restores to a session that
// answers every view, takes the next frame (a step may fail with a status, never crash), predicts,
// and whose own checkpoint always restores, before and after that frame, to a session with the
// same checkpoint bit for bit.
#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "estimator/calibration_model.h"
#include "estimator/session.h"
#include "fuzz/fuzz_util.h"
#include "fuzz/next_frame.h"
#include "proto/convert.h"
#include "server/checkpoint_codec.h"

namespace {

using esg::estimator::EstimationSession;
using esg::estimator::SessionCheckpoint;
using esg::estimator::SessionOptions;
using esg::estimator::SpacecraftConfig;

const SpacecraftConfig& Config() {
  static const SpacecraftConfig* config = [] {
    absl::StatusOr<SpacecraftConfig> c =
        esg::proto_convert::ReadConfigFile(ESG_SOURCE_DIR "/deploy/examples/rdk1.json");
    ESG_FUZZ_CHECK(c.ok(), c.status().ToString());
    // Propagation at 1 Hz instead of 8: the same states and checkpoint layout (the rate is not
    // stored), an eighth of the work per frame, eight times the executions.
    c->filter.integration_rate_hz = 1.0;
    return new SpacecraftConfig(*c);
  }();
  return *config;
}

// The session's own checkpoint restores, and the restored session exports the same values.
void CheckOwnCheckpoint(const EstimationSession& s, const SessionOptions& options) {
  const SessionCheckpoint exported = s.ExportCheckpoint();
  absl::StatusOr<EstimationSession> again =
      EstimationSession::FromCheckpoint(Config(), options, exported);
  ESG_FUZZ_CHECK(again.ok(), again.status().ToString());
  const SessionCheckpoint twice = again->ExportCheckpoint();
  ESG_FUZZ_CHECK(twice.version == exported.version, "same version");
  bool same = twice.values.size() == exported.values.size();
  for (size_t i = 0; same && i < twice.values.size(); ++i) {
    same = esg::fuzz::SameBits(twice.values[i], exported.values[i]);
  }
  ESG_FUZZ_CHECK(same, "a restored session exports the checkpoint it was restored from");
}

void ExerciseViews(const EstimationSession& s) {
  (void)s.CurrentAttitude();
  (void)s.Gyros();
  (void)s.StarTrackerLatency();
  (void)s.StarTrackerMountShift();
  for (const auto& g : Config().gyros) (void)s.RelativeSigma(g.id);
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace esg;
  absl::StatusOr<server::ServerCheckpoint> decoded =
      server::DecodeCheckpoint(fuzz::AsAbslText(data, size));
  if (!decoded.ok()) {
    fuzz::CheckCleanError(decoded.status(), absl::StatusCode::kDataLoss);
    return 0;
  }
  const std::string encoded = server::EncodeCheckpoint(*decoded);
  absl::StatusOr<server::ServerCheckpoint> again = server::DecodeCheckpoint(encoded);
  ESG_FUZZ_CHECK(again.ok(), again.status().ToString());
  ESG_FUZZ_CHECK(server::EncodeCheckpoint(*again) == encoded, "encoding is a fixed point");
  if (!decoded->session.has_value()) return 0;

  // As the server: the checkpoint's model, or the default one when it names none or no known one.
  absl::StatusOr<estimator::ModelSpec> model =
      estimator::ParseModel(decoded->model.empty() ? "10+11" : decoded->model);
  if (!model.ok()) model = estimator::ParseModel("10+11");
  ESG_FUZZ_CHECK(model.ok(), model.status().ToString());
  SessionOptions options;
  options.model = *model;
  absl::StatusOr<EstimationSession> restored =
      EstimationSession::FromCheckpoint(Config(), options, *decoded->session);
  if (!restored.ok()) {
    fuzz::CheckCleanError(restored.status(), absl::StatusCode::kDataLoss);
    ESG_FUZZ_CHECK(restored.status().message().rfind("checkpoint", 0) == 0,
                   restored.status().ToString());
    return 0;
  }
  EstimationSession& s = *restored;
  ExerciseViews(s);
  CheckOwnCheckpoint(s, options);
  absl::StatusOr<estimator::StepReport> step = s.AddFrame(fuzz::NextFrame(s, Config()));
  if (!step.ok()) ESG_FUZZ_CHECK(!step.status().message().empty(), step.status().ToString());
  ExerciseViews(s);
  CheckOwnCheckpoint(s, options);
  const absl::Time last = s.last_frame_time();
  if (last != absl::InfinitePast()) {
    absl::StatusOr<std::vector<estimator::PredictedSample>> predicted =
        s.Predict({last + absl::Seconds(60), last + absl::Seconds(120)}, nullptr, last);
    if (!predicted.ok()) ESG_FUZZ_CHECK(!predicted.status().message().empty(), "a reason");
  }
  return 0;
}
