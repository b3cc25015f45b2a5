// Results of model-discrepancy diagnoses (table diagnoses, schema.h; docs/discovery.md): the
// verdict over a time window and the full report as JSON, kept as a history per spacecraft.
//
// Bounded per spacecraft (docs/service.md "Limits"): with a bound set, storing a diagnosis
// beyond it deletes the spacecraft's oldest ones in the same transaction, the service's own
// (requested_by kRequestedByService) before any an operator asked for, never the one just
// stored: `max_per_spacecraft` stay. Oldest dropped rather than new ones refused: a report is
// read for its recent verdict, and refusing would also refuse the service's own diagnoses; the
// service's go first because an automatic diagnosis can be run again and an operator's report
// was asked for; the ids of the rest do not change, so a paged ListDiagnoses goes on after a
// drop.
#ifndef ESG_STORAGE_DIAGNOSIS_STORE_H_
#define ESG_STORAGE_DIAGNOSIS_STORE_H_

#include <atomic>
#include <cstdint>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "storage/records.h"
#include "storage/database.h"

namespace esg::storage {

// Thread-safe (through Database). Methods without a Transaction argument run in their own
// transaction; the overload taking one joins the caller's.
class DiagnosisStore {
 public:
  explicit DiagnosisStore(Database* db) : db_(db) {}

  // Diagnoses kept per spacecraft at most (<= 0: no bound, the default of a bare store; esgd
  // sets its --max-stored-diagnoses). Takes effect from the next Put.
  void set_max_per_spacecraft(int64_t n) { max_per_spacecraft_.store(n); }
  int64_t max_per_spacecraft() const { return max_per_spacecraft_.load(); }

  // Stores a diagnosis and returns its id (unique across all spacecraft, increasing;
  // record.id is ignored); beyond the bound, deletes the spacecraft's oldest automatic ones,
  // then its oldest others (never this one). InvalidArgument for an empty spacecraft_id or verdict, an unstorable
  // time, or to_time < from_time.
  absl::StatusOr<int64_t> Put(const DiagnosisRecord& record);
  absl::StatusOr<int64_t> Put(Transaction& txn, const DiagnosisRecord& record);

  // All diagnoses of the spacecraft, in id (insertion) order.
  absl::StatusOr<std::vector<DiagnosisRecord>> List(absl::string_view spacecraft_id);

  // Up to `limit` (> 0, else InvalidArgument naming limit) diagnoses of the spacecraft with
  // id > after_id, in id order, as summaries: report_json is left empty (not read). A page of
  // a paged list: the caller passes the last id it returned.
  absl::StatusOr<std::vector<DiagnosisRecord>> ListSummaries(absl::string_view spacecraft_id,
                                                             int64_t after_id, int64_t limit);

  // One diagnosis; NotFound if missing (never stored, or dropped beyond the bound).
  absl::StatusOr<DiagnosisRecord> Get(int64_t id);

  // Stores an operator's cancel of the automatic diagnosis (table auto_diagnosis_cancels); the
  // same spacecraft and configuration version stored again keeps the first. InvalidArgument for
  // an empty spacecraft_id, a config_version below 1 or an unstorable time.
  absl::Status PutAutoCancel(const AutoCancelRecord& record);
  // Whether an operator cancelled the automatic diagnosis of the spacecraft under
  // config_version.
  absl::StatusOr<bool> AutoCancelled(absl::string_view spacecraft_id, int64_t config_version);

 private:
  Database* db_;  // not owned
  std::atomic<int64_t> max_per_spacecraft_{0};
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_DIAGNOSIS_STORE_H_
