// What the service reports of one spacecraft's session (GetSession, ListSessions; docs/service.md
// "GetSession"), as plain values read under the spacecraft's locks. It carries no gRPC types
// except the configuration as it was given: proto_mapping.h SessionInfoToProto makes the message.
#ifndef ESG_SERVER_SESSION_SUMMARY_H_
#define ESG_SERVER_SESSION_SUMMARY_H_

#include <array>
#include <cstdint>
#include <map>
#include <optional>
#include <string>

#include "absl/time/time.h"
#include "esg/v1/estimation_service.pb.h"
#include "estimator/session.h"
#include "storage/service_queries.h"

namespace esg::server {

struct SessionSummary {
  std::string spacecraft_id;
  std::string served_by;  // the node holding the session's lease; empty without leases or none

  // Ingest counters and the newest accepted measurement (InfinitePast: none yet).
  int64_t frames_rejected = 0;
  int64_t frames_duplicate = 0;
  int64_t frames_conflicting = 0;
  int64_t frames_accepted = 0;
  absl::Time last_frame_time = absl::InfinitePast();
  std::map<std::string, int64_t> highest_durable;  // per station

  // The apply side: what the filter has taken, and why it stopped if it did.
  int64_t highest_applied_sequence = 0;
  int64_t frames_applied = 0;
  int64_t frames_apply_failed = 0;
  int64_t star_tracker_rejections = 0;
  std::string quarantine_reason;  // empty: not quarantined
  bool rebuilding = false;
  absl::Time last_compute_time = absl::InfinitePast();

  // The configuration in force (absent before the first configuration is read).
  struct Configured {
    std::string model_name;
    esg::v1::SpacecraftConfig config;
    std::array<int, 2> reserve_pair = {0, 0};
  };
  std::optional<Configured> configured;

  // A copy of the filter's session (absent while none is restored).
  std::optional<estimator::EstimationSession> session;

  std::optional<storage::AlertCounts> alerts;  // absent when the count could not be read
};

}  // namespace esg::server

#endif  // ESG_SERVER_SESSION_SUMMARY_H_
