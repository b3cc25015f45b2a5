// esg_fleet_client: sets up many sessions on one esgd at once, for measuring a node with a fleet
// (scripts/session_memory.sh; docs/performance.md "Sessions per node"). Configures COUNT copies
// of a spacecraft configuration (ids PREFIX00001, PREFIX00002, ...) with CONCURRENCY
// ConfigureSpacecraft calls in flight, then optionally streams the first FRAMES frames of a
// recording to each (STREAMS StreamTelemetry calls, spacecraft i on stream i mod STREAMS, every
// frame acknowledged durable) and waits until the filter has applied them (ListSessions).
// Prints one line per phase with its wall time.
//   esg_fleet_client --server HOST:PORT --config FILE --count N [--prefix MEM-]
//                    [--concurrency 64] [--recording CSV --frames 60 [--streams 4]]
// Exit codes: 0 every call succeeded, 1 a call failed (named on stderr), 2 bad arguments.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "esg/v1/estimation_service.grpc.pb.h"
#include "estimator/calibration_model.h"
#include "formats/recording_csv.h"
#include "grpcpp/create_channel.h"
#include "proto/convert.h"

namespace {

struct Options {
  std::string server;
  std::string config;
  int count = 0;
  std::string prefix = "MEM-";
  int concurrency = 64;
  std::string recording;
  int frames = 0;
  int streams = 4;
};

double SecondsSince(std::chrono::steady_clock::time_point start) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

int Usage(const std::string& why) {
  std::fprintf(stderr,
               "esg_fleet_client: %s\nusage: esg_fleet_client --server HOST:PORT --config FILE "
               "--count N [--prefix P] [--concurrency C] [--recording CSV --frames K "
               "[--streams S]]\n",
               why.c_str());
  return 2;
}

bool ParseArgs(int argc, char** argv, Options* o, std::string* error) {
  for (int i = 1; i < argc; ++i) {
    const std::string flag = argv[i];
    if (i + 1 >= argc) {
      *error = flag + ": value missing";
      return false;
    }
    const std::string value = argv[++i];
    auto number = [&](int* out) {
      if (absl::SimpleAtoi(value, out) && *out > 0) return true;
      *error = flag + ": '" + value + "' is not a positive integer";
      return false;
    };
    if (flag == "--server") {
      o->server = value;
    } else if (flag == "--config") {
      o->config = value;
    } else if (flag == "--prefix") {
      o->prefix = value;
    } else if (flag == "--recording") {
      o->recording = value;
    } else if (flag == "--count") {
      if (!number(&o->count)) return false;
    } else if (flag == "--concurrency") {
      if (!number(&o->concurrency)) return false;
    } else if (flag == "--frames") {
      if (!number(&o->frames)) return false;
    } else if (flag == "--streams") {
      if (!number(&o->streams)) return false;
    } else {
      *error = "unknown option " + flag;
      return false;
    }
  }
  if (o->server.empty() || o->config.empty() || o->count <= 0) {
    *error = "--server, --config and --count are required";
    return false;
  }
  if (o->recording.empty() != (o->frames == 0)) {
    *error = "--recording and --frames go together";
    return false;
  }
  return true;
}

std::string IdOf(const Options& o, int i) { return absl::StrFormat("%s%05d", o.prefix, i + 1); }

}  // namespace

int main(int argc, char** argv) {
  std::setvbuf(stdout, nullptr, _IOLBF, 0);  // each phase's line as it ends, also into a file
  Options o;
  std::string error;
  if (!ParseArgs(argc, argv, &o, &error)) return Usage(error);
  absl::StatusOr<esg::estimator::SpacecraftConfig> config =
      esg::proto_convert::ReadConfigFile(o.config);
  if (!config.ok()) return Usage(std::string(config.status().message()));
  std::vector<esg::v1::TelemetryFrame> frames;
  if (!o.recording.empty()) {
    absl::StatusOr<esg::estimator::Recording> recording =
        esg::storage::ReadRecordingCsv(o.recording);
    if (!recording.ok()) return Usage(std::string(recording.status().message()));
    if (static_cast<int>(recording->frames.size()) < o.frames) {
      return Usage(absl::StrFormat("%s holds %d frames, fewer than --frames %d", o.recording,
                                   recording->frames.size(), o.frames));
    }
    for (int k = 0; k < o.frames; ++k) {
      frames.push_back(esg::proto_convert::FrameToProto(recording->frames[k], "", k + 1));
    }
  }
  std::shared_ptr<grpc::Channel> channel =
      grpc::CreateChannel(o.server, grpc::InsecureChannelCredentials());
  std::unique_ptr<esg::v1::EstimationService::Stub> stub =
      esg::v1::EstimationService::NewStub(channel);

  // Configure: CONCURRENCY threads take the next index until COUNT.
  const esg::v1::SpacecraftConfig proto = esg::proto_convert::ConfigToProto(*config);
  std::atomic<int> next{0};
  std::atomic<int> failed{0};
  auto start = std::chrono::steady_clock::now();
  {
    std::vector<std::thread> threads;
    for (int t = 0; t < std::min(o.concurrency, o.count); ++t) {
      threads.emplace_back([&] {
        esg::v1::ConfigureRequest request;
        *request.mutable_config() = proto;
        request.set_model("10+11");
        for (int i = next++; i < o.count; i = next++) {
          request.mutable_config()->set_spacecraft_id(IdOf(o, i));
          grpc::ClientContext context;
          context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
          esg::v1::ConfigureResponse response;
          const grpc::Status status = stub->ConfigureSpacecraft(&context, request, &response);
          if (!status.ok() && failed++ == 0) {
            std::fprintf(stderr, "esg_fleet_client: configure %s: %s\n", IdOf(o, i).c_str(),
                         status.error_message().c_str());
          }
        }
      });
    }
    for (std::thread& t : threads) t.join();
  }
  const double configure_s = SecondsSince(start);
  std::printf("configured %d sessions in %.2f s (%.0f per second, %d calls in flight)\n", o.count,
              configure_s, o.count / configure_s, std::min(o.concurrency, o.count));
  if (failed > 0) return 1;
  if (frames.empty()) return 0;

  // Stream: frame k of every spacecraft of a stream before frame k + 1 of any.
  start = std::chrono::steady_clock::now();
  std::atomic<int64_t> acked{0};
  {
    std::vector<std::thread> threads;
    for (int s = 0; s < std::min(o.streams, o.count); ++s) {
      threads.emplace_back([&, s] {
        grpc::ClientContext context;
        auto stream = stub->StreamTelemetry(&context);
        std::thread reader([&] {
          esg::v1::TelemetryAck ack;
          while (stream->Read(&ack)) {
            if (ack.accepted()) {
              ++acked;
            } else if (failed++ == 0) {
              std::fprintf(stderr, "esg_fleet_client: %s sequence %lld not accepted: %s\n",
                           ack.spacecraft_id().c_str(), static_cast<long long>(ack.sequence()),
                           ack.rejection().reason().c_str());
            }
          }
        });
        for (const esg::v1::TelemetryFrame& f : frames) {
          esg::v1::TelemetryFrame frame = f;
          for (int i = s; i < o.count; i += o.streams) {
            frame.set_spacecraft_id(IdOf(o, i));
            if (!stream->Write(frame)) break;
          }
        }
        stream->WritesDone();
        reader.join();
        const grpc::Status status = stream->Finish();
        if (!status.ok() && failed++ == 0) {
          std::fprintf(stderr, "esg_fleet_client: stream %d: %s\n", s,
                       status.error_message().c_str());
        }
      });
    }
    for (std::thread& t : threads) t.join();
  }
  const double stream_s = SecondsSince(start);
  std::printf("%lld frames acknowledged durable in %.2f s (%.0f per second)\n",
              static_cast<long long>(acked.load()), stream_s, acked / stream_s);
  if (failed > 0) return 1;

  // Applied: every session's filter past the last frame sent (frames it could not apply count).
  int64_t done = 0;
  const auto apply_deadline = std::chrono::steady_clock::now() + std::chrono::minutes(30);
  for (;;) {
    done = 0;
    std::string token;
    do {
      esg::v1::ListSessionsRequest request;
      request.set_page_size(500);
      request.set_page_token(token);
      esg::v1::ListSessionsResponse response;
      grpc::ClientContext context;
      const grpc::Status status = stub->ListSessions(&context, request, &response);
      if (!status.ok()) {
        std::fprintf(stderr, "esg_fleet_client: ListSessions: %s\n",
                     status.error_message().c_str());
        return 1;
      }
      for (const esg::v1::SessionInfo& s : response.sessions()) {
        if (s.spacecraft_id().rfind(o.prefix, 0) == 0 &&
            s.highest_applied_sequence() >= o.frames) {
          ++done;
        }
      }
      token = response.next_page_token();
    } while (!token.empty());
    if (done >= o.count) break;
    if (std::chrono::steady_clock::now() > apply_deadline) {
      std::fprintf(stderr, "esg_fleet_client: %lld of %d sessions applied after 30 min\n",
                   static_cast<long long>(done), o.count);
      return 1;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
  }
  std::printf("all %d sessions applied their %d frames %.2f s after the first was sent\n", o.count,
              o.frames, SecondsSince(start));
  return 0;
}
