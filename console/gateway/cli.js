// Command line of the console gateway (docs/console-gateway.md "Flags"). Parses and checks every
// flag before anything starts, so a mistake ends the process with a message naming the flag
// instead of a half-started server.
'use strict';

const fs = require('node:fs');
const { parseAllowedHosts, defaultHosts } = require('./hosts');

const USAGE = `usage: node console/gateway/main.js --esgd HOST:PORT [--listen HOST:PORT]
       [--tls-cert FILE --tls-key FILE] [--esgd-ca FILE] [--esgd-server-name NAME]
       [--allowed-hosts HOST[:PORT],...]

  --esgd HOST:PORT          esgd's gRPC address (required)
  --listen HOST:PORT        where the console is served (default 127.0.0.1:8080; port 0: any free port)
  --tls-cert FILE           PEM certificate chain: serve HTTPS and WSS (needs --tls-key)
  --tls-key FILE            PEM private key of --tls-cert
  --esgd-ca FILE            PEM CA bundle: talk TLS to esgd and check its certificate against it
  --esgd-server-name NAME   name to check esgd's certificate against (default: the host of --esgd)
  --allowed-hosts LIST      the names browsers reach the console by (Host and Origin headers),
                            comma-separated; without a port: the --listen port or none
                            (default 127.0.0.1,localhost,[::1] and the --listen address)
  --help                    this text
`;

class UsageError extends Error {}

const VALUE_FLAGS = ['--esgd', '--listen', '--tls-cert', '--tls-key', '--esgd-ca',
  '--esgd-server-name', '--allowed-hosts'];

// Splits "HOST:PORT" ("[::1]:8080" for IPv6) into {host, port}; throws UsageError naming `flag`.
function parseHostPort(flag, value) {
  const m = /^(?:\[([^\]]+)\]|([^:\[\]]+)):(\d{1,5})$/.exec(value);
  if (!m) throw new UsageError(`${flag}: expected HOST:PORT, got '${value}'`);
  const port = Number(m[3]);
  if (port > 65535) throw new UsageError(`${flag}: port ${port} is not in 0..65535`);
  return { host: m[1] || m[2], port };
}

function readPem(flag, file) {
  try {
    return fs.readFileSync(file);
  } catch (err) {
    throw new UsageError(`${flag}: cannot read '${file}': ${err.code || err.message}`);
  }
}

// Returns {help: true} or the options: esgd {host, port, address}, listen {host, port},
// tls {cert, key} | null (PEM buffers), esgdCa (PEM buffer) | null, esgdServerName | null,
// allowedHosts [{name, port | null}].
// Throws UsageError on anything wrong.
function parseArgs(argv) {
  const given = {};
  for (let i = 0; i < argv.length; i++) {
    let arg = argv[i];
    if (arg === '--help' || arg === '-h') return { help: true };
    let value;
    const eq = arg.indexOf('=');
    if (arg.startsWith('--') && eq > 0) {
      value = arg.slice(eq + 1);
      arg = arg.slice(0, eq);
    }
    if (!VALUE_FLAGS.includes(arg)) throw new UsageError(`${arg}: unknown flag (see --help)`);
    if (value === undefined) {
      if (i + 1 >= argv.length || argv[i + 1].startsWith('--')) {
        throw new UsageError(`${arg}: missing value`);
      }
      value = argv[++i];
    }
    if (value === '') throw new UsageError(`${arg}: empty value`);
    if (arg in given) throw new UsageError(`${arg}: given twice`);
    given[arg] = value;
  }
  if (!given['--esgd']) throw new UsageError('--esgd: required (esgd\'s address, HOST:PORT)');
  const esgd = parseHostPort('--esgd', given['--esgd']);
  if (esgd.port === 0) throw new UsageError('--esgd: port 0 is not an address to connect to');
  esgd.address = given['--esgd'];
  const listen = parseHostPort('--listen', given['--listen'] || '127.0.0.1:8080');

  let tls = null;
  if (given['--tls-cert'] || given['--tls-key']) {
    if (!given['--tls-cert']) throw new UsageError('--tls-cert: required with --tls-key');
    if (!given['--tls-key']) throw new UsageError('--tls-key: required with --tls-cert');
    tls = { cert: readPem('--tls-cert', given['--tls-cert']),
      key: readPem('--tls-key', given['--tls-key']) };
  }
  const esgdCa = given['--esgd-ca'] ? readPem('--esgd-ca', given['--esgd-ca']) : null;
  const esgdServerName = given['--esgd-server-name'] || null;
  if (esgdServerName && !esgdCa) {
    throw new UsageError('--esgd-server-name: only meaningful with --esgd-ca (TLS to esgd)');
  }
  let allowedHosts = defaultHosts(listen.host);
  if (given['--allowed-hosts']) {
    try {
      allowedHosts = parseAllowedHosts(given['--allowed-hosts']);
    } catch (err) {
      throw new UsageError(`--allowed-hosts: ${err.message}`);
    }
  }
  return { help: false, esgd, listen, tls, esgdCa, esgdServerName, allowedHosts };
}

module.exports = { parseArgs, UsageError, USAGE };
