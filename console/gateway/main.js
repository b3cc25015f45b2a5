// The console gateway: serves the Open MCT console to the browser and bridges it to esgd over
// gRPC (docs/console-gateway.md). Prints `console: listening on URL` on stdout when it serves;
// logs go to stderr; exits 2 on a bad flag, 1 when it cannot listen, 0 after SIGINT/SIGTERM.
'use strict';

const { parseArgs, UsageError, USAGE } = require('./cli');
const { Esgd } = require('./esgd');
const { startServer } = require('./server');

function log(line) {
  process.stderr.write(`${new Date().toISOString()} console: ${line}\n`);
}

async function main() {
  let options;
  try {
    options = parseArgs(process.argv.slice(2));
  } catch (err) {
    if (!(err instanceof UsageError)) throw err;
    process.stderr.write(`console gateway: ${err.message}\n${USAGE}`);
    process.exit(2);
  }
  if (options.help) {
    process.stdout.write(USAGE);
    return;
  }
  const esgd = new Esgd({ address: options.esgd.address, ca: options.esgdCa,
    serverName: options.esgdServerName });
  let server;
  try {
    server = await startServer(options, esgd, log);
  } catch (err) {
    process.stderr.write(`console gateway: --listen: cannot listen on ${options.listen.host}:${options.listen.port}: ${err.code || err.message}\n`);
    esgd.close();
    process.exit(1);
  }
  process.stdout.write(`console: listening on ${server.url}\n`);
  log(`esgd at ${options.esgd.address} (${options.esgdCa ? 'TLS' : 'plain text'})`);
  // The names browsers may use (a name without a port: the listen port, or none); a page reached
  // by any other name is refused with 421, and this line tells the operator why.
  log(`allowed hosts: ${options.allowedHosts.map((h) => (h.port ? `${h.name}:${h.port}` : h.name)).join(', ')}`);

  let stopping = false;
  const shutdown = (signal) => {
    if (stopping) return;
    stopping = true;
    log(`${signal}: stopping`);
    // Whatever a peer does, the process is gone within 5 s of the signal.
    setTimeout(() => process.exit(0), 5000).unref();
    server.stop().then(() => {
      log('stopped');
      process.exit(0);
    });
  };
  process.on('SIGINT', () => shutdown('SIGINT'));
  process.on('SIGTERM', () => shutdown('SIGTERM'));
}

main().catch((err) => {
  process.stderr.write(`console gateway: ${err.stack || err}\n`);
  process.exit(1);
});
