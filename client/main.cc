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
  app.add_option("--tls-ca", global.tls_ca,
                 "server verbs: CA bundle (PEM) of the server certificate; "
                 "any --tls-* option switches to TLS");
  app.add_option("--tls-cert", global.tls_cert,
                 "server verbs: client certificate (PEM) for mutual TLS");
  app.add_option("--tls-key", global.tls_key,
                 "server verbs: client private key (PEM) for mutual TLS");
  app.add_option("--token", global.token, "server verbs: bearer token (default: $ESG_TOKEN)")
      ->envname("ESG_TOKEN");
  int exit_code = 0;
  esg::client::RegisterSimulate(app, global, &exit_code);
  esg::client::RegisterCalibrate(app, global, &exit_code);
  esg::client::RegisterGap(app, global, &exit_code);
  esg::client::RegisterDiagnose(app, global, &exit_code);
  esg::client::RegisterConfigure(app, global, &exit_code);
  esg::client::RegisterReplay(app, global, &exit_code);
  esg::client::RegisterStatus(app, global, &exit_code);
  esg::client::RegisterPredict(app, global, &exit_code);
  esg::client::RegisterAlerts(app, global, &exit_code);
  esg::client::RegisterHistory(app, global, &exit_code);
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    const int rc = app.exit(e);
    return rc == 0 ? 0 : 2;
  }
  return exit_code;
}
