// The spacecraft registry of the server: spacecraft id -> the record of that spacecraft
// (EstimationCore::Spacecraft, server/core_internal.h), shared with the threads that work on it.
// Records are never removed while the server runs; a caller keeps the shared_ptr it found, so a
// record outlives a replacement. Thread-safe; the registry's lock is held only inside its
// methods, never while a record's own locks are taken (the lock order of estimation_core.h does
// not involve it).
#ifndef ESG_SERVER_SPACECRAFT_REGISTRY_H_
#define ESG_SERVER_SPACECRAFT_REGISTRY_H_

#include <cstdint>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/synchronization/mutex.h"

namespace esg::server {

// `Record` has a member `const std::string id`.
template <typename Record>
class SpacecraftRegistry {
 public:
  // The record of `spacecraft_id`, or null.
  std::shared_ptr<Record> Find(const std::string& spacecraft_id) const {
    absl::MutexLock lock(&mu_);
    auto it = records_.find(spacecraft_id);
    return it == records_.end() ? nullptr : it->second;
  }

  // Adds `record` under its id, replacing a record of the same id.
  void Put(std::shared_ptr<Record> record) {
    absl::MutexLock lock(&mu_);
    const std::string id = record->id;
    records_[id] = std::move(record);
  }

  // Every record, in id order (a snapshot: records added later are not in it).
  std::vector<std::shared_ptr<Record>> All() const {
    absl::MutexLock lock(&mu_);
    std::vector<std::shared_ptr<Record>> out;
    out.reserve(records_.size());
    for (const auto& [id, record] : records_) out.push_back(record);
    return out;
  }

  // At most `limit` records with ids after `after` ("" : from the first), in id order; `*more`
  // tells whether further records follow the page.
  std::vector<std::shared_ptr<Record>> Page(const std::string& after, int64_t limit,
                                            bool* more) const {
    absl::MutexLock lock(&mu_);
    std::vector<std::shared_ptr<Record>> page;
    *more = false;
    for (auto it = records_.upper_bound(after); it != records_.end(); ++it) {
      if (static_cast<int64_t>(page.size()) >= limit) {
        *more = true;
        break;
      }
      page.push_back(it->second);
    }
    return page;
  }

  int64_t size() const {
    absl::MutexLock lock(&mu_);
    return static_cast<int64_t>(records_.size());
  }

 private:
  mutable absl::Mutex mu_;
  std::map<std::string, std::shared_ptr<Record>> records_ ABSL_GUARDED_BY(mu_);
};

}  // namespace esg::server

#endif  // ESG_SERVER_SPACECRAFT_REGISTRY_H_
