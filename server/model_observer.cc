// What the automatic diagnosis (server/auto_diagnosis.h) needs of the core: the model observer
// told of new MODEL_INCONSISTENT alerts and of reconfigurations, and the service alerts it
// raises (see estimation_core.h "The automatic diagnosis").
#include <algorithm>
#include <utility>

#include "server/core_internal.h"
#include "server/estimation_core.h"

namespace esg::server {

void EstimationCore::SetModelObserver(
    std::function<void(const storage::AlertRecord&)> on_model_alert,
    std::function<void(const std::string&)> on_configured) {
  absl::MutexLock lock(&observer_mu_);
  on_model_alert_ = std::move(on_model_alert);
  on_configured_ = std::move(on_configured);
}

void EstimationCore::NotifyModelAlerts(const std::vector<storage::AlertRecord>& published) {
  absl::MutexLock lock(&observer_mu_);
  if (!on_model_alert_) return;
  for (const storage::AlertRecord& a : published) {
    // New alerts only (a job's new_alerts, repeats within the job included): later repeats
    // and the clearing are the same mismatch.
    if (a.reason == "MODEL_INCONSISTENT") on_model_alert_(a);
  }
}

void EstimationCore::NotifyConfigured(const std::string& spacecraft_id) {
  absl::MutexLock lock(&observer_mu_);
  if (on_configured_) on_configured_(spacecraft_id);
}

absl::Status EstimationCore::RaiseServiceAlert(const std::string& spacecraft_id,
                                               AlertOccurrence occurrence) {
  std::shared_ptr<Spacecraft> sc = Find(spacecraft_id);
  if (sc == nullptr) return NotConfigured(spacecraft_id);
  {
    absl::MutexLock state(&sc->state_mu);
    if (sc->apply.applied_time != absl::InfinitePast()) {
      occurrence.time = std::max(occurrence.time, sc->apply.applied_time);
    }
    sc->service_alerts.push_back(std::move(occurrence));
  }
  Schedule(sc);
  return absl::OkStatus();
}

absl::StatusOr<absl::Time> EstimationCore::LastDurableTime(const std::string& spacecraft_id) {
  std::shared_ptr<Spacecraft> sc = Find(spacecraft_id);
  if (sc == nullptr) return NotConfigured(spacecraft_id);
  absl::MutexLock state(&sc->state_mu);
  return sc->last_durable_time;
}

}  // namespace esg::server
