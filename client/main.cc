// `esg`: the command-line client (docs/cli.md). Offline verbs (simulate, calibrate, gap, diagnose
// of a recording) run the estimator directly; server verbs talk to esgd over gRPC (--server,
// default $ESG_SERVER, else 127.0.0.1:50051). The global options are accepted before or after the
// verb and are listed in every verb's --help.
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include "CLI/CLI.hpp"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/commands/commands.h"
#include "client/verbs.h"

#ifndef ESG_VERSION
#error "ESG_VERSION must be the project version (client/CMakeLists.txt)"
#endif
#ifndef ESG_GIT_COMMIT
#define ESG_GIT_COMMIT ""
#endif

namespace {

// "esg 0.1.0 (commit 2f75f1b)", or without the commit when the build was configured outside git.
std::string VersionText() {
  const std::string commit = ESG_GIT_COMMIT;
  return absl::StrCat("esg ", ESG_VERSION,
                      commit.empty() ? "" : absl::StrCat(" (commit ", commit, ")"));
}

// The global options of `app` as a help section, for the footer of every verb's --help.
std::string GlobalOptionsHelp(const CLI::App& app) {
  std::string text = "Global options (before or after the verb):\n";
  for (const CLI::Option* option : app.get_options()) {
    if (option->get_name() == "--help" || option->get_name() == "--version") continue;
    std::string name = option->get_name();
    if (option->get_type_size() != 0) name += " " + option->get_type_name();
    absl::StrAppend(&text, absl::StrFormat("  %-26s %s\n", name, option->get_description()));
  }
  return text;
}

void AddFooter(CLI::App* app, const std::string& footer) {
  for (CLI::App* sub : app->get_subcommands({})) {
    sub->footer(footer);
    AddFooter(sub, footer);
  }
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{"esg: ESG attitude estimation service client and offline tools"};
  app.require_subcommand(1);
  app.fallthrough();  // global options accepted before or after the verb
  app.set_version_flag("--version", VersionText(), "print the version (and git commit) and exit");
  esg::client::GlobalOptions global;
  app.add_option("--server", global.server,
                 "server verbs: esgd address host:port (default: $ESG_SERVER, else "
                 "127.0.0.1:50051; the flag wins over the variable)")
      ->envname("ESG_SERVER")
      ->type_name("ADDR");
  app.add_option("--tls-ca", global.tls_ca,
                 "server verbs: CA bundle (PEM) of the server certificate; "
                 "any --tls-* option switches to TLS")
      ->type_name("FILE");
  app.add_option("--tls-cert", global.tls_cert,
                 "server verbs: client certificate (PEM) for mutual TLS")
      ->type_name("FILE");
  app.add_option("--tls-key", global.tls_key,
                 "server verbs: client private key (PEM) for mutual TLS")
      ->type_name("FILE");
  app.add_option("--token", global.token,
                 "server verbs: bearer token (default: $ESG_TOKEN; the flag wins over the "
                 "variable)")
      ->envname("ESG_TOKEN")
      ->type_name("TOKEN");
  int exit_code = 0;
  esg::client::RegisterSimulate(app, global, &exit_code);
  esg::client::RegisterCalibrate(app, global, &exit_code);
  esg::client::RegisterGap(app, global, &exit_code);
  esg::client::RegisterDiagnose(app, global, &exit_code);
  esg::client::RegisterDiagnoses(app, global, &exit_code);
  esg::client::RegisterOrbit(app, global, &exit_code);
  esg::client::RegisterConfigure(app, global, &exit_code);
  esg::client::RegisterReplay(app, global, &exit_code);
  esg::client::RegisterStatus(app, global, &exit_code);
  esg::client::RegisterPredict(app, global, &exit_code);
  esg::client::RegisterAlerts(app, global, &exit_code);
  esg::client::RegisterHistory(app, global, &exit_code);
  esg::client::RegisterEstimates(app, global, &exit_code);
  esg::client::RegisterExport(app, global, &exit_code);
  esg::client::RegisterModel(app, global, &exit_code);
  esg::client::RegisterGyro(app, global, &exit_code);
  esg::client::RegisterComplete(app, global, &exit_code);
  AddFooter(&app, GlobalOptionsHelp(app));
  if (const std::optional<int> handled = esg::client::HandleVerbHabits(
          app, std::vector<std::string>(argv + 1, argv + argc), VersionText());
      handled.has_value()) {
    return *handled;
  }
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : 2;
  }
  return exit_code;
}
