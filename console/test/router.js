// A real nginx in front of esgd nodes for the console's tests, with the shipped configuration
// deploy/nginx/esg.conf (docs/deploy.md "Routing by spacecraft"): the file is copied into a temp
// dir with only its listen address and its upstream server addresses replaced, wrapped in a
// minimal nginx.conf whose paths all lie in that dir, and run in the foreground
// (`nginx -p DIR -c DIR/nginx.conf -g 'daemon off; ...'`), so nothing under /etc or /var is read
// or written. The access log has one line per call: the x-esg-spacecraft value, the node, the
// status and the request URI. The binary: $ESG_NGINX, else /usr/sbin/nginx or /usr/bin/nginx
// (Debian's package nginx, installed by scripts/install-deps.sh).
'use strict';

const { spawn } = require('node:child_process');
const fs = require('node:fs');
const net = require('node:net');
const path = require('node:path');
const { REPO } = require('./helpers');

function nginxBinary() {
  const candidates = process.env.ESG_NGINX ? [process.env.ESG_NGINX]
    : ['/usr/sbin/nginx', '/usr/bin/nginx'];
  const found = candidates.find((c) => { try { fs.accessSync(c, fs.constants.X_OK); return true; } catch { return false; } });
  if (!found) throw new Error('nginx not found ($ESG_NGINX, /usr/sbin/nginx, /usr/bin/nginx): install Debian\'s package nginx (scripts/install-deps.sh does)');
  return found;
}

// A TCP port on 127.0.0.1 that was free a moment ago.
function freePort() {
  return new Promise((resolve, reject) => {
    const server = net.createServer();
    server.on('error', reject);
    server.listen(0, '127.0.0.1', () => {
      const { port } = server.address();
      server.close(() => resolve(port));
    });
  });
}

// deploy/nginx/esg.conf with its listen line at 127.0.0.1:port and its upstream server lines,
// in order, at `nodes` (host:port). Throws when the shipped file has not exactly one listen line
// and one server line per node: the test would no longer run what is shipped.
function routingConfig(port, nodes) {
  let listens = 0;
  let servers = 0;
  const lines = fs.readFileSync(path.join(REPO, 'deploy', 'nginx', 'esg.conf'), 'utf8').split('\n')
    .map((line) => {
      let m = /^(\s*)listen\s+\d+\s+http2;/.exec(line);
      if (m) { listens += 1; return `${m[1]}listen 127.0.0.1:${port} http2;`; }
      m = /^(\s*)server\s+[0-9.]+:\d+(\s.*)$/.exec(line);
      if (m) { servers += 1; return servers <= nodes.length ? `${m[1]}server ${nodes[servers - 1]}${m[2]}` : line; }
      return line;
    });
  if (listens !== 1 || servers !== nodes.length) {
    throw new Error(`deploy/nginx/esg.conf: expected one 'listen PORT http2;' line and ${nodes.length} upstream server lines, found ${listens} and ${servers}`);
  }
  return lines.join('\n');
}

// Starts nginx routing to `nodes` in `dir`; resolves with {child, address, accessLog()} once it
// accepts connections (10 s at most).
async function startRouter(dir, nodes) {
  const binary = nginxBinary();
  const port = await freePort();
  fs.mkdirSync(path.join(dir, 'temp'), { recursive: true });
  fs.chmodSync(dir, 0o755); // the workers run unprivileged when nginx starts as root
  fs.writeFileSync(path.join(dir, 'esg.conf'), routingConfig(port, nodes));
  const temp = (name) => `  ${name}_temp_path ${path.join(dir, 'temp', name)};\n`;
  fs.writeFileSync(path.join(dir, 'nginx.conf'), 'worker_processes 1;\n'
    + 'events { worker_connections 512; }\n'
    + 'http {\n'
    + "  log_format routing '$http_x_esg_spacecraft $upstream_addr $status $request_uri';\n"
    + `  access_log ${path.join(dir, 'access.log')} routing;\n`
    + `  client_body_temp_path ${path.join(dir, 'temp', 'body')};\n`
    + temp('proxy') + temp('fastcgi') + temp('uwsgi') + temp('scgi')
    + `  include ${path.join(dir, 'esg.conf')};\n`
    + '}\n');
  const log = fs.openSync(path.join(dir, 'nginx.log'), 'a');
  const child = spawn(binary, ['-p', dir, '-c', path.join(dir, 'nginx.conf'), '-g',
    `daemon off; pid ${path.join(dir, 'nginx.pid')}; error_log stderr;`],
  { stdio: ['ignore', log, log] });
  fs.closeSync(log);
  const deadline = Date.now() + 10_000;
  for (;;) {
    if (child.exitCode !== null) throw new Error(`nginx exited at start: ${fs.readFileSync(path.join(dir, 'nginx.log'), 'utf8')}`);
    const accepts = await new Promise((resolve) => {
      const socket = net.connect(port, '127.0.0.1', () => { socket.destroy(); resolve(true); });
      socket.on('error', () => resolve(false));
    });
    if (accepts) break;
    if (Date.now() > deadline) throw new Error(`nginx does not accept on port ${port}`);
    await new Promise((r) => setTimeout(r, 20));
  }
  return {
    child,
    address: `127.0.0.1:${port}`,
    accessLog: () => fs.readFileSync(path.join(dir, 'access.log'), 'utf8'),
  };
}

module.exports = { startRouter };
