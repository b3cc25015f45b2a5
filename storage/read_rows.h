// Every row of a prepared statement read into a record, for the stores' list queries.
#ifndef ESG_STORAGE_READ_ROWS_H_
#define ESG_STORAGE_READ_ROWS_H_

#include <type_traits>
#include <vector>

#include "absl/status/statusor.h"
#include "estimator/status_macros.h"
#include "storage/database.h"

namespace esg::storage {

// Steps `st` to its end and returns read(row) of each row, in order; the errors of Step.
template <typename Read>
auto ReadRows(Statement* st, Read read)
    -> absl::StatusOr<std::vector<std::decay_t<decltype(read(*st))>>> {
  std::vector<std::decay_t<decltype(read(*st))>> out;
  while (true) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    out.push_back(read(*st));
  }
  return out;
}

}  // namespace esg::storage

#endif  // ESG_STORAGE_READ_ROWS_H_
