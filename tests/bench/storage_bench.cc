// The server's two per-frame transactions (storage/storage.h), per synchronous setting
// (sqlite_db.h durability table), on a real file in a temporary directory, and on PostgreSQL on
// loopback (range(1) = kPostgres: a fresh database of tests/testing/postgres_server.h):
// BM_StorageArchiveFrames, the group commit of N telemetry frames (300-byte payloads) that
// acknowledgements wait for (frames/s is N x commits/s); BM_StorageFilterEffects, one filter
// job's effects: 4 coefficient estimates + 1 alert + a 2 KiB checkpoint; BM_StorageFilterJob, a
// full apply job of 32 measurement steps (3 gyros: 96 coefficient estimates, a 2 KiB checkpoint)
// without (range(0) = 0) and with (1) its 32 per-step estimates, the cost of the estimate archive
// per job (docs/service.md "Per-step estimates"). BM_LeaseRenewal: one renewal round of a server
// holding 500 session leases (docs/service.md "Several servers"), one transaction per lease
// (range(0) = 0, LeaseStore::Renew) against one for all (1, LeaseStore::RenewAll); PostgreSQL
// only, since leases exist only there (an SQLite file has one server). BM_CoefficientHistory:
// reading a 10-day coefficient history (57 600 records) whole and in pages of 1000, as the
// history and export RPCs read it.
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "benchmark/benchmark.h"
#include "storage/storage.h"
#include "tests/testing/postgres_server.h"
#include "tests/testing/temp_dir.h"

namespace esg::storage {
namespace {

const absl::Time kT0 = absl::FromUnixSeconds(1551398400);

std::vector<ArchivedFrame> MakeBenchFrames(int64_t first_sequence, int frames) {
  std::vector<ArchivedFrame> out;
  for (int i = 0; i < frames; ++i) {
    ArchivedFrame f;
    f.spacecraft_id = "BENCH-1";
    f.sequence = first_sequence + i;
    f.measurement_time = kT0 + absl::Seconds(60 * f.sequence);
    f.payload.assign(300, static_cast<char>(f.sequence & 0x7f));
    out.push_back(std::move(f));
  }
  return out;
}

// A filter job's checkpoint after step `last` at `t_last`: a 2 KiB state.
std::function<CheckpointRecord(const std::vector<int64_t>&)> BenchCheckpoint(int64_t last,
                                                                             absl::Time t_last) {
  return [last, t_last](const std::vector<int64_t>&) {
    CheckpointRecord checkpoint;
    checkpoint.spacecraft_id = "BENCH-1";
    checkpoint.last_sequence = last;
    checkpoint.measurement_time = checkpoint.compute_time = t_last;
    checkpoint.state_blob.assign(2048, 's');
    return checkpoint;
  };
}

FilterEffects MakeBenchEffects(int64_t last) {
  const absl::Time t_last = kT0 + absl::Seconds(60 * last);
  FilterEffects effects;
  effects.spacecraft_id = "BENCH-1";
  for (int gyro = 1; gyro <= 4; ++gyro) {
    CoefficientRecord c;
    c.spacecraft_id = effects.spacecraft_id;
    c.gyro_id = gyro;
    c.measurement_time = t_last;
    c.compute_time = t_last;
    c.model_name = "model10";
    c.values.assign(kNumCoefficientValues, 1e-7);
    c.sigmas.assign(kNumCoefficientValues, 1e-8);
    effects.coefficients.push_back(std::move(c));
  }
  AlertRecord a;
  a.spacecraft_id = effects.spacecraft_id;
  a.severity = "WARNING";
  a.reason = "INNOVATION_TEST";
  a.subsystem = "star_tracker";
  a.first_time = a.measurement_time = a.compute_time = t_last;
  effects.new_alerts.push_back(std::move(a));
  effects.checkpoint = BenchCheckpoint(last, t_last);
  return effects;
}

// range(1) of the storage benchmarks that selects PostgreSQL on loopback (a fresh database of
// the shared test server, synchronous_commit=on) instead of an SQLite file.
constexpr int kPostgres = 0;

std::unique_ptr<Storage> OpenBenchStorage(benchmark::State& state, const std::string& path) {
  if (state.range(1) == kPostgres) {
    std::string error;
    esg::testing::PostgresServer* pg = esg::testing::PostgresServer::Shared(&error);
    absl::StatusOr<std::string> uri =
        pg != nullptr ? pg->CreateDatabase() : absl::UnavailableError(error);
    absl::StatusOr<std::unique_ptr<Storage>> storage =
        uri.ok() ? Storage::Open(*uri) : absl::StatusOr<std::unique_ptr<Storage>>(uri.status());
    state.SetLabel("postgresql");
    if (!storage.ok()) {
      state.SkipWithError(std::string(storage.status().message()).c_str());
      return nullptr;
    }
    return std::move(*storage);
  }
  DatabaseOptions options;
  options.synchronous = static_cast<Synchronous>(state.range(1));
  state.SetLabel(options.synchronous == Synchronous::kFull ? "synchronous=FULL"
                                                           : "synchronous=NORMAL");
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(path, options);
  if (!storage.ok()) {
    state.SkipWithError(std::string(storage.status().message()).c_str());
    return nullptr;
  }
  return std::move(*storage);
}

// range(0): frames per commit; range(1): Synchronous as int (1 NORMAL, 2 FULL), or kPostgres.
void BM_StorageArchiveFrames(benchmark::State& state) {
  const int frames = static_cast<int>(state.range(0));
  esg::testing::TempDir dir;
  std::unique_ptr<Storage> storage = OpenBenchStorage(state, dir.File("bench.db"));
  if (storage == nullptr) return;
  int64_t next_sequence = 0;
  for (auto _ : state) {
    state.PauseTiming();
    const std::vector<ArchivedFrame> batch = MakeBenchFrames(next_sequence, frames);
    next_sequence += frames;
    state.ResumeTiming();
    const absl::Status status = storage->ArchiveFrames(batch);
    if (!status.ok()) {
      state.SkipWithError(std::string(status.message()).c_str());
      return;
    }
  }
  state.SetItemsProcessed(state.iterations() * frames);
}
BENCHMARK(BM_StorageArchiveFrames)
    ->ArgsProduct({{1, 10, 100}, {static_cast<int>(Synchronous::kNormal),
                                  static_cast<int>(Synchronous::kFull), kPostgres}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// range(0): unused (1); range(1): Synchronous as int, or kPostgres.
void BM_StorageFilterEffects(benchmark::State& state) {
  esg::testing::TempDir dir;
  std::unique_ptr<Storage> storage = OpenBenchStorage(state, dir.File("bench.db"));
  if (storage == nullptr) return;
  int64_t last = 0;
  for (auto _ : state) {
    state.PauseTiming();
    const FilterEffects effects = MakeBenchEffects(last++);
    state.ResumeTiming();
    const absl::StatusOr<std::vector<int64_t>> result = storage->CommitFilterEffects(effects);
    if (!result.ok()) {
      state.SkipWithError(std::string(result.status().message()).c_str());
      return;
    }
  }
}
BENCHMARK(BM_StorageFilterEffects)
    ->ArgsProduct({{1}, {static_cast<int>(Synchronous::kNormal),
                         static_cast<int>(Synchronous::kFull), kPostgres}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// One apply job of 32 measurement steps at 60 s ending at step `last`: 3 gyros' coefficient
// estimates per step and, with `estimates`, the step's per-step estimate (valid attitude, the
// innovations of 3 gyros).
FilterEffects MakeBenchJob(int64_t last, bool estimates) {
  FilterEffects effects;
  effects.spacecraft_id = "BENCH-1";
  for (int64_t step = last - 31; step <= last; ++step) {
    const absl::Time t = kT0 + absl::Seconds(60 * step);
    for (int gyro = 1; gyro <= 3; ++gyro) {
      CoefficientRecord c;
      c.spacecraft_id = effects.spacecraft_id;
      c.gyro_id = gyro;
      c.measurement_time = c.compute_time = t;
      c.model_name = "model10+11";
      c.values.assign(kNumCoefficientValues, 1e-7 * step);
      c.sigmas.assign(kNumCoefficientValues, 1e-8);
      effects.coefficients.push_back(std::move(c));
    }
    if (!estimates) continue;
    EstimateRecord e;
    e.spacecraft_id = effects.spacecraft_id;
    e.measurement_time = e.compute_time = t;
    e.state = "CONVERGED";
    e.attitude_valid = true;
    e.q_in_b = {0.5, 0.5, 0.5, 0.5};
    e.sigma_b = {1e-5, 1e-5, 2e-5};
    e.output_pair = {1, 2};
    e.star_tracker_used = true;
    for (int gyro = 1; gyro <= 3; ++gyro) {
      e.star_tracker_innovations.push_back({gyro, {1e-5 * step, -1e-5}, {2e-5, 2e-5}});
    }
    e.star_tracker_test_ratio = 0.5;
    e.last_star_tracker_time = t;
    effects.estimates.push_back(std::move(e));
  }
  const absl::Time t_last = kT0 + absl::Seconds(60 * last);
  effects.checkpoint = BenchCheckpoint(last, t_last);
  return effects;
}

// range(0): without (0) or with (1) the per-step estimates; range(1): Synchronous as int.
void BM_StorageFilterJob(benchmark::State& state) {
  esg::testing::TempDir dir;
  std::unique_ptr<Storage> storage = OpenBenchStorage(state, dir.File("bench.db"));
  if (storage == nullptr) return;
  int64_t last = 31;
  for (auto _ : state) {
    state.PauseTiming();
    const FilterEffects effects = MakeBenchJob(last, state.range(0) == 1);
    last += 32;
    state.ResumeTiming();
    const absl::StatusOr<std::vector<int64_t>> result = storage->CommitFilterEffects(effects);
    if (!result.ok()) {
      state.SkipWithError(std::string(result.status().message()).c_str());
      return;
    }
  }
  state.SetItemsProcessed(state.iterations() * 32);
  state.SetLabel(absl::StrCat(state.range(0) == 1 ? "with estimates, " : "without estimates, ",
                              state.range(1) == static_cast<int>(Synchronous::kFull)
                                  ? "synchronous=FULL"
                                  : "synchronous=NORMAL"));
}
BENCHMARK(BM_StorageFilterJob)
    ->ArgsProduct({{0, 1}, {static_cast<int>(Synchronous::kNormal),
                            static_cast<int>(Synchronous::kFull)}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// range(0): 0 renews each lease in its own transaction (Renew), 1 all in one (RenewAll);
// range(1): kPostgres (leases need PostgreSQL). Items: leases renewed.
void BM_LeaseRenewal(benchmark::State& state) {
  constexpr int kLeases = 500;
  constexpr absl::Duration kLease = absl::Seconds(15);
  esg::testing::TempDir dir;
  std::unique_ptr<Storage> storage = OpenBenchStorage(state, dir.File("bench.db"));
  if (storage == nullptr) return;
  std::map<std::string, LeaseFence> fences;
  for (int i = 0; i < kLeases; ++i) {
    const std::string id = absl::StrCat("LEASE-", i);
    const absl::StatusOr<SessionLease> lease =
        storage->leases().Acquire(id, "bench-node", kT0, kLease);
    if (!lease.ok()) {
      state.SkipWithError(std::string(lease.status().message()).c_str());
      return;
    }
    fences[id] = {"bench-node", lease->epoch};
  }
  const bool all_at_once = state.range(0) == 1;
  absl::Time now = kT0;
  for (auto _ : state) {
    now += absl::Seconds(5);
    if (all_at_once) {
      const absl::StatusOr<std::vector<std::string>> lost =
          storage->leases().RenewAll(fences, now, kLease);
      if (!lost.ok() || !lost->empty()) {
        state.SkipWithError(lost.ok() ? "a lease was lost"
                                      : std::string(lost.status().message()).c_str());
        return;
      }
      continue;
    }
    for (const auto& [id, fence] : fences) {
      const absl::Status renewed = storage->leases().Renew(id, fence, now, kLease);
      if (!renewed.ok()) {
        state.SkipWithError(std::string(renewed.message()).c_str());
        return;
      }
    }
  }
  state.SetItemsProcessed(state.iterations() * kLeases);
  state.SetLabel(all_at_once ? "postgresql, RenewAll: one transaction"
                             : "postgresql, Renew: a transaction per lease");
}
BENCHMARK(BM_LeaseRenewal)
    ->ArgsProduct({{0, 1}, {kPostgres}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// A history of `steps` measurement steps at 60 s of 4 gyros (with sigmas, every fourth record
// with a basis term column), written in transactions of 1000 records.
absl::Status WriteBenchHistory(Storage& storage, int steps) {
  std::vector<CoefficientRecord> batch;
  for (int step = 0; step < steps; ++step) {
    for (int gyro = 1; gyro <= 4; ++gyro) {
      CoefficientRecord c;
      c.spacecraft_id = "BENCH-1";
      c.gyro_id = gyro;
      c.measurement_time = c.compute_time = kT0 + absl::Seconds(60 * step);
      c.model_name = "model10";
      c.values.assign(kNumCoefficientValues, 1e-7 * (step + gyro));
      c.sigmas.assign(kNumCoefficientValues, 1e-8);
      batch.push_back(std::move(c));
    }
    if (batch.size() < 1000 && step + 1 < steps) continue;
    absl::StatusOr<Transaction> txn = storage.database().Begin(TransactionMode::kImmediate);
    if (!txn.ok()) return txn.status();
    for (const CoefficientRecord& c : batch) {
      const absl::Status appended = storage.coefficients().Append(*txn, c);
      if (!appended.ok()) return appended;
    }
    const absl::Status committed = txn->Commit();
    if (!committed.ok()) return committed;
    batch.clear();
  }
  return absl::OkStatus();
}

// Reading a whole coefficient history of range(0) steps (4 gyros, so 4 x range(0) records: 14 400
// steps are 10 days at 60 s), as the history and export RPCs read it: range(2) = 0 in one
// History call, 1 in pages of 1000 records (HistoryPage, the RPCs' page size). range(1):
// Synchronous as int, or kPostgres. Items: records read.
void BM_CoefficientHistory(benchmark::State& state) {
  const int steps = static_cast<int>(state.range(0));
  esg::testing::TempDir dir;
  std::unique_ptr<Storage> storage = OpenBenchStorage(state, dir.File("bench.db"));
  if (storage == nullptr) return;
  const absl::Status written = WriteBenchHistory(*storage, steps);
  if (!written.ok()) {
    state.SkipWithError(std::string(written.message()).c_str());
    return;
  }
  const bool paged = state.range(2) == 1;
  size_t read = 0;
  for (auto _ : state) {
    read = 0;
    if (!paged) {
      const absl::StatusOr<std::vector<CoefficientRecord>> history =
          storage->coefficients().History("BENCH-1", 0, absl::InfinitePast(),
                                          absl::InfiniteFuture());
      if (!history.ok()) {
        state.SkipWithError(std::string(history.status().message()).c_str());
        return;
      }
      read = history->size();
      continue;
    }
    std::optional<CoefficientCursor> after;
    do {
      const absl::StatusOr<CoefficientPage> page = storage->coefficients().HistoryPage(
          "BENCH-1", 0, absl::InfinitePast(), absl::InfiniteFuture(), after, 1000);
      if (!page.ok()) {
        state.SkipWithError(std::string(page.status().message()).c_str());
        return;
      }
      read += page->records.size();
      after = page->next;
    } while (after.has_value());
  }
  if (read != static_cast<size_t>(4 * steps)) {
    state.SkipWithError(absl::StrCat("read ", read, " records of ", 4 * steps).c_str());
    return;
  }
  state.SetItemsProcessed(state.iterations() * read);
  state.SetLabel(absl::StrCat(state.range(1) == kPostgres ? "postgresql" : "sqlite",
                              paged ? ", pages of 1000" : ", one History call"));
}
BENCHMARK(BM_CoefficientHistory)
    ->ArgsProduct({{14400}, {static_cast<int>(Synchronous::kNormal), kPostgres}, {0, 1}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace esg::storage
