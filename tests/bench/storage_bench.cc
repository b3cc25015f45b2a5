// Storage::CommitBatch throughput (storage/storage.h): one ingest batch = N telemetry frames
// (300-byte payloads) + 4 coefficient estimates + 1 alert + a 2 KiB checkpoint, committed in
// one transaction, per synchronous setting (sqlite_db.h durability table). A real file in a
// temporary directory; frames/s is N x batches/s.
#include <cstdint>
#include <memory>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "benchmark/benchmark.h"
#include "storage/storage.h"
#include "tests/testing/temp_dir.h"

namespace esg::storage {
namespace {

Batch MakeBenchBatch(int64_t first_sequence, int frames) {
  const absl::Time t0 = absl::FromUnixSeconds(1551398400);
  Batch batch;
  batch.spacecraft_id = "BENCH-1";
  for (int i = 0; i < frames; ++i) {
    ArchivedFrame f;
    f.spacecraft_id = batch.spacecraft_id;
    f.sequence = first_sequence + i;
    f.measurement_time = t0 + absl::Seconds(60 * f.sequence);
    f.payload.assign(300, static_cast<char>(f.sequence & 0x7f));
    batch.frames.push_back(std::move(f));
  }
  const int64_t last = first_sequence + frames - 1;
  const absl::Time t_last = t0 + absl::Seconds(60 * last);
  for (int gyro = 1; gyro <= 4; ++gyro) {
    CoefficientRecord c;
    c.spacecraft_id = batch.spacecraft_id;
    c.gyro_id = gyro;
    c.measurement_time = t_last;
    c.compute_time = t_last;
    c.model_name = "model10";
    c.values.assign(kNumCoefficientValues, 0.1);
    c.sigmas.assign(kNumCoefficientValues, 0.01);
    batch.coefficients.push_back(std::move(c));
  }
  AlertRecord a;
  a.spacecraft_id = batch.spacecraft_id;
  a.severity = "WARNING";
  a.reason = "INNOVATION_TEST";
  a.subsystem = "star_tracker";
  a.first_time = a.measurement_time = a.compute_time = t_last;
  batch.alerts.push_back(std::move(a));
  CheckpointRecord checkpoint;
  checkpoint.spacecraft_id = batch.spacecraft_id;
  checkpoint.last_sequence = last;
  checkpoint.measurement_time = checkpoint.compute_time = t_last;
  checkpoint.state_blob.assign(2048, 's');
  batch.checkpoint = std::move(checkpoint);
  return batch;
}

// range(0): frames per batch; range(1): Synchronous as int (1 NORMAL, 2 FULL).
void BM_StorageCommitBatch(benchmark::State& state) {
  const int frames = static_cast<int>(state.range(0));
  esg::testing::TempDir dir;
  DatabaseOptions options;
  options.synchronous = static_cast<Synchronous>(state.range(1));
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(dir.File("bench.db"), options);
  if (!storage.ok()) {
    state.SkipWithError(std::string(storage.status().message()).c_str());
    return;
  }
  int64_t next_sequence = 0;
  for (auto _ : state) {
    state.PauseTiming();
    const Batch batch = MakeBenchBatch(next_sequence, frames);
    next_sequence += frames;
    state.ResumeTiming();
    absl::StatusOr<BatchResult> result = (*storage)->CommitBatch(batch);
    if (!result.ok()) {
      state.SkipWithError(std::string(result.status().message()).c_str());
      return;
    }
  }
  state.SetItemsProcessed(state.iterations() * frames);
  state.SetLabel(options.synchronous == Synchronous::kFull ? "synchronous=FULL"
                                                           : "synchronous=NORMAL");
}
BENCHMARK(BM_StorageCommitBatch)
    ->ArgsProduct({{1, 10, 100}, {static_cast<int>(Synchronous::kNormal),
                                  static_cast<int>(Synchronous::kFull)}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace esg::storage
