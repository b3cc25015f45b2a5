// `esg`: the command-line client. Offline verbs (simulate, calibrate, gap, diagnose) run the
// estimator directly; server verbs talk to esgd over gRPC (--server, default 127.0.0.1:50051).
#include <iostream>

#include "CLI/CLI.hpp"
#include "client/commands/commands.h"

int main(int argc, char** argv) {
  CLI::App app{"esg: ESG attitude estimation service client and offline tools"};
  app.require_subcommand(1);
  app.fallthrough();  // --server accepted before or after the verb
  esg::client::GlobalOptions global;
  app.add_option("--server", global.server, "esgd address (host:port)")->capture_default_str();
  int exit_code = 0;
  esg::client::RegisterSimulate(app, global, &exit_code);
  esg::client::RegisterCalibrate(app, global, &exit_code);
  esg::client::RegisterGap(app, global, &exit_code);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : 2;
  }
  return exit_code;
}
