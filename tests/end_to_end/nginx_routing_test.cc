// Routing by spacecraft (docs/deploy.md, docs/service.md "Routing by spacecraft") through a real
// nginx running the shipped deploy/nginx/esg.conf in front of three real esgd child processes,
// each with its own SQLite file: every call about a spacecraft carries x-esg-spacecraft, nginx
// hashes on it, so each spacecraft's configuration and frames live on exactly one node.
//
// Checked, querying each esgd directly: all frames of each of 12 spacecraft are stored on exactly
// one node (configured through nginx, streamed through nginx, partly with the esg CLI); `esg
// status --spacecraft X` through nginx answers from that node; a routed stream carrying another
// spacecraft's frame gets that frame refused (INVALID_ARGUMENT, spacecraft_id) and keeps its own;
// one stream longer than nginx's default 1 MB body limit goes through; each node owns at least
// one spacecraft; ListSessions without metadata lists one node's spacecraft; after kill -9 of a
// node, nginx takes it out and its spacecraft's calls reach another node, which (today, without a
// shared database) answers NOT_FOUND, while the other spacecraft are served as before.
//
// The nodes listen on 127.0.0.11-13 at one fixed port, because nginx places a server on its hash
// ring by the address written in the configuration: fixed addresses make the assignment of the
// 12 spacecraft to nodes the same in every run (measured: printed as `spread`), where ports
// chosen by the OS would give a new assignment, now and then one that leaves a node empty.
//
// Also: a call nginx cannot pass to any node (nodes down, or a node that closes the connection
// in the middle of the call) is answered by nginx as a gRPC UNAVAILABLE, not an HTML error page.
#include <poll.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <atomic>
#include <chrono>
#include <cstdio>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "formats/recording_csv.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "proto/convert.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/nginx.h"
#include "tests/testing/run_process.h"

namespace esg {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::Daemon;
using ::esg::testing::Nginx;
using ::esg::testing::NginxBinary;
using ::esg::testing::RunBinary;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;

constexpr int kNodes = 3;
constexpr int kSpacecraft = 12;
// Spacecraft 0..kByCli-1 go through the esg CLI (configure, replay), the others through a stub.
constexpr int kByCli = 4;
// The node port, the same on 127.0.0.11, .12 and .13 (see the top of the file).
constexpr int kNodePort = 29051;
// nginx's default client_max_body_size: a telemetry stream longer than this needs the shipped
// `client_max_body_size 0`.
constexpr int64_t kNginxDefaultBodyLimit = 1024 * 1024;
// Frames held back from each spacecraft's first stream, sent later on the misrouting check.
constexpr int kHeldBack = 3;

std::string NodeHost(int node) { return absl::StrCat("127.0.0.", 11 + node); }
std::string SpacecraftId(int i) { return absl::StrFormat("RT-%02d", i); }

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

grpc::Status GetSession(esg::v1::EstimationService::Stub& stub, const std::string& id,
                        bool routed, esg::v1::SessionInfo* info) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
  if (routed) ctx.AddMetadata("x-esg-spacecraft", id);
  esg::v1::GetSessionRequest request;
  request.set_spacecraft_id(id);
  return stub.GetSession(&ctx, request, info);
}

// The node whose esgd has `id` configured, asking each node directly; -1 when none or several
// have it (a test failure is recorded then).
int Owner(std::vector<std::unique_ptr<esg::v1::EstimationService::Stub>>& nodes,
          const std::string& id, int64_t* frames_accepted) {
  int owner = -1;
  for (int n = 0; n < static_cast<int>(nodes.size()); ++n) {
    if (nodes[n] == nullptr) continue;
    esg::v1::SessionInfo info;
    const grpc::Status status = GetSession(*nodes[n], id, /*routed=*/false, &info);
    if (status.ok()) {
      EXPECT_EQ(owner, -1) << id << " is configured on node " << owner << " and node " << n;
      owner = n;
      *frames_accepted = info.frames_accepted();
    } else {
      EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND)
          << id << " on node " << n << ": " << status.error_message();
    }
  }
  return owner;
}

TEST(NginxRouting, EachSpacecraftLivesOnOneNodeAndAKilledNodesSpacecraftAreNotFoundElsewhere) {
  ASSERT_FALSE(NginxBinary().empty())
      << "nginx not found ($ESG_NGINX, /usr/sbin/nginx, /usr/bin/nginx): this test needs "
         "Debian's package nginx (scripts/install-deps.sh installs it)";
  const auto test_start = std::chrono::steady_clock::now();
  TempDir dir;

  // Three nodes, each with its own database, and nginx in front of them.
  std::vector<std::unique_ptr<Daemon>> daemons;
  std::vector<std::string> node_addresses;
  for (int n = 0; n < kNodes; ++n) {
    const std::string listen = absl::StrCat(NodeHost(n), ":", kNodePort);
    daemons.push_back(std::make_unique<Daemon>(dir.File(absl::StrCat("node", n, "/esg.db")),
                                               dir.File(absl::StrCat("node", n, ".log")),
                                               testing::DaemonLimits{},
                                               std::vector<std::string>{}, listen));
    ASSERT_EQ(daemons.back()->port(), kNodePort)
        << "esgd did not start on " << listen << " (is the port taken?): "
        << testing::ReadFile(dir.File(absl::StrCat("node", n, ".log")));
    node_addresses.push_back(listen);
  }
  std::vector<std::unique_ptr<esg::v1::EstimationService::Stub>> nodes;
  for (const auto& d : daemons) nodes.push_back(d->Stub());
  Nginx nginx(dir.File("nginx"), node_addresses);
  ASSERT_TRUE(nginx.running());
  auto router = esg::v1::EstimationService::NewStub(
      grpc::CreateChannel(nginx.address(), grpc::InsecureChannelCredentials()));
  std::printf("[ measured ] start of 3 esgd and nginx: %.2f s\n", Seconds(test_start));

  // The spacecraft: an hour of the calibration profile each (61 frames at 60 s); the last one
  // long enough that its one stream's body exceeds nginx's default limit.
  std::vector<SimulatedRun> runs;
  for (int i = 0; i < kSpacecraft; ++i) {
    runs.push_back(SimulateRun(SpacecraftId(i), 1.0, 100 + i));
  }
  {
    const int64_t frame_bytes = static_cast<int64_t>(runs[0].frames[0].ByteSizeLong());
    // A stream's body: each message with its 5-byte gRPC prefix.
    const double hours = 1.5 * kNginxDefaultBodyLimit / (frame_bytes + 5) / 60.0;
    runs.back() = SimulateRun(SpacecraftId(kSpacecraft - 1), hours, 100 + kSpacecraft - 1);
  }

  // Configure and stream through nginx, all but the last kHeldBack frames of each.
  const auto ingest_start = std::chrono::steady_clock::now();
  int64_t longest_stream_bytes = 0;
  for (int i = 0; i < kSpacecraft; ++i) {
    const SimulatedRun& run = runs[i];
    const std::string id = SpacecraftId(i);
    const std::vector<esg::v1::TelemetryFrame> first(run.frames.begin(),
                                                     run.frames.end() - kHeldBack);
    if (i < kByCli) {
      // The CLI sets the routing metadata itself: configure from the configuration's id, replay
      // from the recording's `# spacecraft_id:`.
      const std::string config = dir.File(id + ".json");
      ASSERT_TRUE(proto_convert::WriteConfigFile(config, run.config).ok());
      estimator::Recording recording;
      recording.metadata["spacecraft_id"] = id;
      for (const esg::v1::TelemetryFrame& f : first) {
        auto frame = proto_convert::FrameFromProto(f);
        ASSERT_TRUE(frame.ok()) << frame.status();
        recording.frames.push_back(*frame);
      }
      const std::string csv = dir.File(id + ".csv");
      ASSERT_TRUE(storage::WriteRecordingCsv(csv, recording).ok());
      const auto configured = RunBinary(
          dir, ESG_BINARY, absl::StrCat("--server ", nginx.address(), " configure --config ", config));
      ASSERT_EQ(configured.exit_code, 0) << configured.err;
      const auto replayed = RunBinary(
          dir, ESG_BINARY, absl::StrCat("--server ", nginx.address(), " replay --recording ", csv));
      ASSERT_EQ(replayed.exit_code, 0) << replayed.err;
    } else {
      grpc::ClientContext ctx;
      ctx.AddMetadata("x-esg-spacecraft", id);
      esg::v1::ConfigureResponse configured;
      const grpc::Status status =
          router->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &configured);
      ASSERT_TRUE(status.ok()) << id << ": " << status.error_message();
      const auto streamed = StreamFrames(*router, first, "", /*routed_by=*/id);
      ASSERT_TRUE(streamed.status.ok()) << id << ": " << streamed.status.error_message();
      ASSERT_EQ(streamed.acks.size(), first.size()) << id;
      for (const esg::v1::TelemetryAck& ack : streamed.acks) {
        ASSERT_TRUE(ack.accepted()) << id << " " << ack.sequence() << ": "
                                    << ack.rejection().reason();
      }
      int64_t bytes = 0;
      for (const esg::v1::TelemetryFrame& f : first) bytes += f.ByteSizeLong() + 5;
      longest_stream_bytes = std::max(longest_stream_bytes, bytes);
    }
  }
  EXPECT_GT(longest_stream_bytes, kNginxDefaultBodyLimit);
  std::printf("[ measured ] configure + stream of %d spacecraft through nginx: %.2f s; longest "
              "stream %lld bytes of frames (%zu frames)\n",
              kSpacecraft, Seconds(ingest_start), static_cast<long long>(longest_stream_bytes),
              runs.back().frames.size() - kHeldBack);

  // Each spacecraft on exactly one node, with all its frames; each node owns at least one.
  std::map<std::string, int> owner;
  std::vector<int> owned(kNodes, 0);
  for (int i = 0; i < kSpacecraft; ++i) {
    const std::string id = SpacecraftId(i);
    int64_t accepted = -1;
    const int n = Owner(nodes, id, &accepted);
    ASSERT_GE(n, 0) << id << " is configured on no node";
    EXPECT_EQ(accepted, static_cast<int64_t>(runs[i].frames.size()) - kHeldBack) << id;
    owner[id] = n;
    ++owned[n];
  }
  std::printf("[ measured ] spread over 3 nodes: %d, %d, %d spacecraft of %d\n", owned[0],
              owned[1], owned[2], kSpacecraft);
  for (int n = 0; n < kNodes; ++n) EXPECT_GE(owned[n], 1) << "node " << n << " owns nothing";

  // Every later call of a spacecraft reaches the same node: GetSession through nginx and `esg
  // status --spacecraft` through nginx answer with that node's frame count.
  for (int i = 0; i < kSpacecraft; ++i) {
    const std::string id = SpacecraftId(i);
    const int64_t expected = static_cast<int64_t>(runs[i].frames.size()) - kHeldBack;
    esg::v1::SessionInfo info;
    const grpc::Status status = GetSession(*router, id, /*routed=*/true, &info);
    ASSERT_TRUE(status.ok()) << id << ": " << status.error_message();
    EXPECT_EQ(info.frames_accepted(), expected) << id;
    const auto cli = RunBinary(dir, ESG_BINARY,
                               absl::StrCat("--server ", nginx.address(), " status --spacecraft ",
                                            id, " --format json"));
    ASSERT_EQ(cli.exit_code, 0) << id << ": " << cli.err;
    const nlohmann::json doc = nlohmann::json::parse(cli.out, nullptr, false);
    ASSERT_FALSE(doc.is_discarded()) << cli.out;
    EXPECT_EQ(doc.value("spacecraftId", ""), id);
    // int64 fields are strings in the proto JSON mapping.
    EXPECT_EQ(doc.value("framesAccepted", ""), std::to_string(expected)) << cli.out;
  }

  // A stream routed by one spacecraft that carries a frame of another: that frame is refused,
  // the stream's own frames are accepted, and the other spacecraft's archive is unchanged.
  const std::string own_id = SpacecraftId(kByCli);  // streamed by the stub
  const std::string other_id = SpacecraftId(kByCli + 1);
  {
    const SimulatedRun& own = runs[kByCli];
    const SimulatedRun& other = runs[kByCli + 1];
    std::vector<esg::v1::TelemetryFrame> frames(own.frames.end() - kHeldBack, own.frames.end());
    frames.insert(frames.begin() + 1, other.frames[other.frames.size() - kHeldBack]);
    const auto streamed = StreamFrames(*router, frames, "", /*routed_by=*/own_id);
    ASSERT_TRUE(streamed.status.ok()) << streamed.status.error_message();
    ASSERT_EQ(streamed.acks.size(), frames.size());
    for (size_t k = 0; k < frames.size(); ++k) {
      if (k == 1) continue;
      EXPECT_TRUE(streamed.acks[k].accepted()) << k << ": "
                                               << streamed.acks[k].rejection().reason();
      EXPECT_FALSE(streamed.acks[k].duplicate()) << k;
    }
    const esg::v1::TelemetryAck& refused = streamed.acks[1];
    EXPECT_FALSE(refused.accepted());
    EXPECT_EQ(refused.spacecraft_id(), other_id);
    EXPECT_EQ(refused.rejection().code(), static_cast<int>(grpc::StatusCode::INVALID_ARGUMENT));
    EXPECT_EQ(refused.rejection().field(), "spacecraft_id");
    EXPECT_THAT(refused.rejection().reason(), HasSubstr(other_id));
    EXPECT_THAT(refused.rejection().reason(), HasSubstr(own_id));
    int64_t accepted = -1;
    EXPECT_EQ(Owner(nodes, own_id, &accepted), owner[own_id]);
    EXPECT_EQ(accepted, static_cast<int64_t>(own.frames.size()));
    EXPECT_EQ(Owner(nodes, other_id, &accepted), owner[other_id]);
    EXPECT_EQ(accepted, static_cast<int64_t>(other.frames.size()) - kHeldBack);
  }

  // A call over all spacecraft carries no metadata: nginx sends it to any node (round robin), and
  // ListSessions through the router lists that one node's spacecraft (docs/service.md).
  {
    std::vector<std::set<std::string>> by_node(kNodes);
    for (const auto& [id, n] : owner) by_node[n].insert(id);
    std::set<int> answered_by;
    for (int call = 0; call < 2 * kNodes; ++call) {
      grpc::ClientContext ctx;
      esg::v1::ListSessionsResponse response;
      ASSERT_TRUE(router->ListSessions(&ctx, {}, &response).ok());
      std::set<std::string> listed;
      for (const esg::v1::SessionInfo& s : response.sessions()) listed.insert(s.spacecraft_id());
      int node = -1;
      for (int n = 0; n < kNodes; ++n) {
        if (listed == by_node[n]) node = n;
      }
      EXPECT_GE(node, 0) << "ListSessions through nginx listed " << listed.size()
                         << " spacecraft, not one node's";
      answered_by.insert(node);
    }
    EXPECT_GE(answered_by.size(), 2u);
    std::printf("[ measured ] %d ListSessions through nginx without metadata: each listed one "
                "node's spacecraft, %zu different nodes answered\n",
                2 * kNodes, answered_by.size());
  }

  // kill -9 of the node that owns the first spacecraft: nginx takes it out, its spacecraft's
  // calls reach another node, which has no configuration for them (NOT_FOUND); the others are
  // answered by their nodes as before.
  const int killed = owner[SpacecraftId(0)];
  daemons[killed]->Stop(SIGKILL);
  nodes[killed].reset();
  const auto failover_start = std::chrono::steady_clock::now();
  int not_found = 0;
  for (int i = 0; i < kSpacecraft; ++i) {
    const std::string id = SpacecraftId(i);
    esg::v1::SessionInfo info;
    const grpc::Status status = GetSession(*router, id, /*routed=*/true, &info);
    if (owner[id] == killed) {
      EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND)
          << id << ": " << status.error_message();
      EXPECT_THAT(status.error_message(), HasSubstr("is not configured")) << id;
      ++not_found;
    } else {
      ASSERT_TRUE(status.ok()) << id << ": " << status.error_message();
      // Only the routed stream's own spacecraft got its held-back frames.
      const int64_t expected =
          static_cast<int64_t>(runs[i].frames.size()) - (id == own_id ? 0 : kHeldBack);
      EXPECT_EQ(info.frames_accepted(), expected) << id;
    }
  }
  EXPECT_EQ(not_found, owned[killed]);
  std::printf("[ measured ] after kill -9 of node %d: %d spacecraft NOT_FOUND through nginx, %d "
              "served, in %.3f s\n",
              killed, not_found, kSpacecraft - not_found, Seconds(failover_start));
  std::printf("[ measured ] whole test: %.2f s\n", Seconds(test_start));
}

// A node that dies in the middle of every call: it accepts the connection, reads what nginx
// sends (the HTTP/2 preface and the call), then closes it without answering.
class ClosingNode {
 public:
  ClosingNode() {
    fd_ = socket(AF_INET, SOCK_STREAM, 0);
    sockaddr_in address{};
    address.sin_family = AF_INET;
    address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
    socklen_t length = sizeof address;
    EXPECT_EQ(bind(fd_, reinterpret_cast<sockaddr*>(&address), sizeof address), 0);
    EXPECT_EQ(listen(fd_, 16), 0);
    EXPECT_EQ(getsockname(fd_, reinterpret_cast<sockaddr*>(&address), &length), 0);
    port_ = ntohs(address.sin_port);
    thread_ = std::thread([this] {
      while (!stop_) {
        pollfd p{fd_, POLLIN, 0};
        if (poll(&p, 1, 50) <= 0) continue;
        const int conn = accept(fd_, nullptr, nullptr);
        if (conn < 0) continue;
        pollfd c{conn, POLLIN, 0};
        char buffer[4096];
        if (poll(&c, 1, 2000) > 0 && read(conn, buffer, sizeof buffer) > 0) ++calls_;
        close(conn);
      }
    });
  }
  ~ClosingNode() {
    stop_ = true;
    thread_.join();
    close(fd_);
  }
  std::string address() const { return absl::StrCat("127.0.0.1:", port_); }
  int calls() const { return calls_; }

 private:
  int fd_ = -1;
  int port_ = 0;
  std::atomic<bool> stop_{false};
  std::atomic<int> calls_{0};
  std::thread thread_;
};

// The shipped configuration's answer when no node answers (deploy/nginx/esg.conf, error_page):
// gRPC UNAVAILABLE with its message, as a unary call and a telemetry stream see it, and on the
// wire HTTP 200 with content-type application/grpc, grpc-status 14 and no HTML body; once with
// every node down (connection refused, then nginx's "no live upstreams") and once with nodes
// that close the connection in the middle of the call.
TEST(NginxRouting, ACallThatReachesNoNodeGetsGrpcUnavailableNotAnHtmlErrorPage) {
  ASSERT_FALSE(NginxBinary().empty())
      << "nginx not found ($ESG_NGINX, /usr/sbin/nginx, /usr/bin/nginx): this test needs "
         "Debian's package nginx (scripts/install-deps.sh installs it)";
  constexpr char kRouterMessage[] = "esg router (nginx): no esgd node answered the call; retry";
  TempDir dir;
  const SimulatedRun run = SimulateRun("NA-1", 0.1, 7);
  auto check = [&](const std::string& name, const std::vector<std::string>& nodes) {
    SCOPED_TRACE(name);
    Nginx nginx(dir.File(name), nodes);
    ASSERT_TRUE(nginx.running());
    auto router = esg::v1::EstimationService::NewStub(
        grpc::CreateChannel(nginx.address(), grpc::InsecureChannelCredentials()));
    // Twice: the first call finds the nodes failing, the second finds them taken out.
    for (int attempt = 0; attempt < 2; ++attempt) {
      esg::v1::SessionInfo info;
      const grpc::Status status = GetSession(*router, "NA-1", /*routed=*/true, &info);
      EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAVAILABLE) << status.error_message();
      EXPECT_EQ(status.error_message(), kRouterMessage);
    }
    const auto streamed = StreamFrames(*router, run.frames, "", /*routed_by=*/"NA-1");
    EXPECT_TRUE(streamed.acks.empty());
    EXPECT_EQ(streamed.status.error_code(), grpc::StatusCode::UNAVAILABLE)
        << streamed.status.error_message();
    EXPECT_EQ(streamed.status.error_message(), kRouterMessage);
    // On the wire: a trailers-only gRPC response, no HTML.
    const auto raw =
        RunBinary(dir, "curl",
                  absl::StrCat("-sS -i --max-time 10 --http2-prior-knowledge -X POST -H "
                               "'content-type: application/grpc' -H 'x-esg-spacecraft: NA-1' "
                               "--data-binary '' http://",
                               nginx.address(), "/esg.v1.EstimationService/GetSession"));
    EXPECT_EQ(raw.exit_code, 0) << raw.err;
    EXPECT_THAT(raw.out, HasSubstr("HTTP/2 200"));
    EXPECT_THAT(raw.out, HasSubstr("content-type: application/grpc\r\n"));
    EXPECT_THAT(raw.out, HasSubstr("grpc-status: 14\r\n"));
    EXPECT_THAT(raw.out, HasSubstr(absl::StrCat("grpc-message: ", kRouterMessage, "\r\n")));
    EXPECT_THAT(raw.out, ::testing::Not(HasSubstr("html")));
    EXPECT_THAT(raw.out, ::testing::EndsWith("\r\n\r\n")) << "a body after the headers";
  };
  // Down: nothing listens on these ports.
  std::vector<std::string> down;
  for (int n = 0; n < kNodes; ++n) {
    down.push_back(absl::StrCat("127.0.0.1:", testing::FreeLoopbackPort()));
  }
  check("down", down);
  // Dying mid-call.
  std::vector<std::unique_ptr<ClosingNode>> closing;
  std::vector<std::string> closing_addresses;
  for (int n = 0; n < kNodes; ++n) {
    closing.push_back(std::make_unique<ClosingNode>());
    closing_addresses.push_back(closing.back()->address());
  }
  check("closing", closing_addresses);
  int reached = 0;
  for (const auto& node : closing) reached += node->calls();
  EXPECT_GE(reached, 1) << "no call reached a closing node: the test shows nothing";
}

}  // namespace
}  // namespace esg
