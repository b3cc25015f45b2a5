// Orbit deliveries uploaded per spacecraft (table orbits, schema.h version 14; docs/service.md
// "Orbits"): the CCSDS OEM text as received, with the span its segments cover, for the
// diagnosis's sun and shadow regressors (docs/discovery.md "A drift that follows the sun").
// Orbits arrive every day: each upload is a new delivery, never a configuration change. Where
// deliveries overlap, the later one is used (estimator/orbit.h Orbit::FromArcs).
//
// Bounded per spacecraft: with a bound set, storing a delivery beyond it deletes the
// spacecraft's oldest ones (by upload) in the same transaction, never the one just stored.
#ifndef ESG_STORAGE_ORBIT_STORE_H_
#define ESG_STORAGE_ORBIT_STORE_H_

#include <atomic>
#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "storage/database.h"

namespace esg::storage {

struct OrbitRecord {
  int64_t id = 0;  // assigned by Put, increasing in upload order
  std::string spacecraft_id;
  absl::Time from_time;    // the earliest useable span start of its segments (UTC)
  absl::Time to_time;      // the latest useable span end
  absl::Time upload_time;  // when the service received it
  int64_t states = 0;      // state vectors over all segments
  std::string uploaded_by;  // the caller's principal ('' without tokens)
  std::string oem_text;     // as received; empty in summaries
};

// Thread-safe (through Database).
class OrbitStore {
 public:
  explicit OrbitStore(Database* db) : db_(db) {}

  // Deliveries kept per spacecraft at most (<= 0: no bound). Takes effect from the next Put.
  void set_max_per_spacecraft(int64_t n) { max_per_spacecraft_.store(n); }
  int64_t max_per_spacecraft() const { return max_per_spacecraft_.load(); }

  // Stores a delivery and returns its id (record.id ignored); beyond the bound deletes the
  // spacecraft's oldest others. InvalidArgument naming the field for an empty spacecraft id or
  // text, an unstorable time, to_time < from_time or states < 2.
  absl::StatusOr<int64_t> Put(const OrbitRecord& record);

  // The spacecraft's deliveries in upload order, without their text.
  absl::StatusOr<std::vector<OrbitRecord>> ListSummaries(absl::string_view spacecraft_id);

  // The spacecraft's deliveries whose span meets [from, to], in upload order, with their text.
  absl::StatusOr<std::vector<OrbitRecord>> Covering(absl::string_view spacecraft_id,
                                                    absl::Time from, absl::Time to);

 private:
  Database* db_;  // not owned
  std::atomic<int64_t> max_per_spacecraft_{0};
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_ORBIT_STORE_H_
