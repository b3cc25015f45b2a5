// `esg __complete spacecraft`: the spacecraft ids esgd knows (ListSessions), one a line, for the
// bash completion (deploy/completion/esg.bash) to offer after --spacecraft. Hidden from `esg
// help`. A completion must never hang the user's shell nor print into it: the call has a 0.5 s
// deadline and fails fast when nothing listens, and on any failure (server down, token refused,
// bad options) the verb prints nothing and exits 0.
#include <cstdio>
#include <memory>
#include <string>

#include "absl/time/time.h"
#include "client/commands/commands.h"
#include "client/commands/server_common.h"

namespace esg::client {
namespace {

constexpr char kVerb[] = "__complete";
constexpr absl::Duration kCompletionDeadline = absl::Milliseconds(500);

int ListIds(const std::string& what, const GlobalOptions& global) {
  if (what != "spacecraft") return kExitOk;
  ClientOptions options = ClientOptionsFrom(global);
  options.rpc_timeout = kCompletionDeadline;
  absl::StatusOr<std::unique_ptr<EsgClient>> client = EsgClient::Create(options);
  if (!client.ok()) return kExitOk;
  absl::StatusOr<esg::v1::ListSessionsResponse> sessions = (*client)->ListSessions();
  if (!sessions.ok()) return kExitOk;
  for (const esg::v1::SessionInfo& s : sessions->sessions()) {
    std::printf("%s\n", s.spacecraft_id().c_str());
  }
  return kExitOk;
}

}  // namespace

void RegisterComplete(CLI::App& app, GlobalOptions& global, int* exit_code) {
  auto what = std::make_shared<std::string>();
  CLI::App* cmd = app.add_subcommand(kVerb, "values for the bash completion");
  cmd->group("");  // hidden from `esg help`
  cmd->add_option("what", *what, "spacecraft")->required();
  cmd->callback([what, &global, exit_code] { *exit_code = ListIds(*what, global); });
}

}  // namespace esg::client
