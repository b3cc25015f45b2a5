// The spacecraft's orbit deliveries (docs/service.md "Orbits"): UploadOrbit, ListOrbits, and the
// orbit a diagnosis takes from them.
#include <algorithm>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/time/clock.h"
#include "estimator/status_macros.h"
#include "estimator/utc_time.h"
#include "formats/oem.h"
#include "proto/convert.h"
#include "server/estimation_core.h"
#include "server/log.h"
#include "storage/orbit_store.h"

namespace esg::server {
namespace {

using estimator::FormatUtc;

esg::v1::OrbitDelivery DeliveryProto(const storage::OrbitRecord& r) {
  esg::v1::OrbitDelivery d;
  d.set_id(r.id);
  d.set_spacecraft_id(r.spacecraft_id);
  *d.mutable_from() = proto_convert::TimeToProto(r.from_time);
  *d.mutable_to() = proto_convert::TimeToProto(r.to_time);
  *d.mutable_upload_time() = proto_convert::TimeToProto(r.upload_time);
  d.set_uploaded_by(r.uploaded_by);
  d.set_states(r.states);
  return d;
}

}  // namespace

absl::StatusOr<esg::v1::OrbitDelivery> EstimationCore::UploadOrbit(
    const esg::v1::UploadOrbitRequest& request, const std::string& uploaded_by) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  RETURN_IF_ERROR(CheckSpacecraft(request.spacecraft_id()));
  if (request.oem().empty()) {
    return absl::InvalidArgumentError("oem: empty (the CCSDS OEM text, KVN)");
  }
  // Read and checked as `esg diagnose --orbit` reads a file (formats/oem.h ParseOemOrbit).
  absl::StatusOr<estimator::Orbit> orbit =
      storage::ParseOemOrbit(request.oem(), request.spacecraft_id());
  if (!orbit.ok()) {
    return absl::InvalidArgumentError(absl::StrCat("oem: ", orbit.status().message()));
  }
  storage::OrbitRecord record;
  record.spacecraft_id = request.spacecraft_id();
  record.from_time = absl::InfiniteFuture();
  record.to_time = absl::InfinitePast();
  for (const estimator::OrbitArc& arc : orbit->arcs()) {
    record.from_time = std::min(record.from_time, arc.from);
    record.to_time = std::max(record.to_time, arc.to);
    record.states += static_cast<int64_t>(arc.states.size());
  }
  record.upload_time = absl::Now();
  record.uploaded_by = uploaded_by;
  record.oem_text = request.oem();
  absl::StatusOr<int64_t> id = storage_->orbits().Put(record);
  if (!id.ok()) {
    // The checks above hold what Put checks of a request; anything else is the store's.
    if (id.status().code() == absl::StatusCode::kInvalidArgument) {
      return absl::InvalidArgumentError(absl::StrCat("oem: ", id.status().message()));
    }
    return id.status();
  }
  record.id = *id;
  LogEvent("INFO", "orbit_uploaded",
           absl::StrCat("orbit delivery #", record.id, " of ", record.spacecraft_id, " stored: ",
                        FormatUtc(record.from_time), " to ", FormatUtc(record.to_time), ", ",
                        record.states, " states, from ", uploaded_by),
           {{"spacecraftId", record.spacecraft_id}, {"orbitId", record.id}});
  return DeliveryProto(record);
}

absl::StatusOr<esg::v1::ListOrbitsResponse> EstimationCore::ListOrbits(
    const esg::v1::ListOrbitsRequest& request) {
  if (request.spacecraft_id().empty()) return absl::InvalidArgumentError("spacecraft_id: required");
  RETURN_IF_ERROR(CheckSpacecraft(request.spacecraft_id()));
  ASSIGN_OR_RETURN(std::vector<storage::OrbitRecord> records,
                   storage_->orbits().ListSummaries(request.spacecraft_id()));
  esg::v1::ListOrbitsResponse out;
  for (const storage::OrbitRecord& r : records) *out.add_deliveries() = DeliveryProto(r);
  return out;
}

absl::StatusOr<StoredOrbit> EstimationCore::OrbitFor(const std::string& spacecraft_id,
                                                     absl::Time from, absl::Time to) {
  ASSIGN_OR_RETURN(std::vector<storage::OrbitRecord> records,
                   storage_->orbits().Covering(spacecraft_id, from, to));
  StoredOrbit out;
  if (records.empty()) {
    out.note = "no orbit delivery of the spacecraft meets the span diagnosed (UploadOrbit)";
    return out;
  }
  std::vector<std::string> texts, names;
  std::vector<std::string> ids;
  for (storage::OrbitRecord& r : records) {
    texts.push_back(std::move(r.oem_text));
    names.push_back(absl::StrCat("orbit delivery ", r.id, ": "));
    ids.push_back(absl::StrCat(r.id));
  }
  const std::string source =
      absl::StrCat("orbit deliver", ids.size() == 1 ? "y " : "ies ", absl::StrJoin(ids, ", "));
  absl::StatusOr<estimator::Orbit> orbit =
      storage::OrbitFromDeliveries(texts, names, spacecraft_id);
  if (!orbit.ok()) {
    // Each delivery was read on upload, so this is not expected; should the orbit's checks of
    // the deliveries together refuse them, the diagnosis runs without and says why.
    out.note = absl::StrCat(source, " not used: ", orbit.status().message());
    return out;
  }
  const std::vector<estimator::TimeInterval> gaps = orbit->Gaps(from, to);
  if (!gaps.empty()) {
    out.note = absl::StrCat(source, " not used: they do not cover the span diagnosed (",
                            FormatUtc(from), " to ", FormatUtc(to), "): no state from ",
                            FormatUtc(gaps[0].from), " to ", FormatUtc(gaps[0].to),
                            gaps.size() > 1 ? absl::StrCat(" and ", gaps.size() - 1, " more gaps")
                                            : "");
    return out;
  }
  out.orbit = std::make_shared<const estimator::Orbit>(*std::move(orbit));
  out.note = source;
  return out;
}

}  // namespace esg::server
