// The console's HTTP(S) server: /api/live upgrades to the WebSocket (live.js), /api/ goes to the
// REST endpoints (api.js), everything else to the static files (static.js). `stop()` is the
// graceful shutdown: no new connections, every gRPC call cancelled, every socket closed.
'use strict';

const http = require('node:http');
const https = require('node:https');
const { makeApi } = require('./api');
const { sendJson } = require('./respond');
const { serveStatic } = require('./static');
const { attachLive } = require('./live');

// options: {listen: {host, port}, tls: {cert, key} | null}; esgd: an Esgd; log(line).
// Resolves with {url, stop()} once listening.
function startServer(options, esgd, log) {
  const api = makeApi(esgd, log);
  const handler = (req, res) => {
    let url;
    try {
      url = new URL(req.url, 'http://localhost');
    } catch {
      sendJson(res, 400, { error: { code: 'INVALID_ARGUMENT', message: 'url: not a valid request target' } });
      return;
    }
    if (url.pathname === '/api' || url.pathname.startsWith('/api/')) {
      api(req, res, url).catch((err) => {
        log(`error: ${err.stack || err}`);
        res.destroy();
      });
    } else {
      serveStatic(req, res, url);
    }
  };
  const server = options.tls
    ? https.createServer({ cert: options.tls.cert, key: options.tls.key }, handler)
    : http.createServer(handler);
  const live = attachLive(server, esgd, log);

  return new Promise((resolve, reject) => {
    server.once('error', reject);
    server.listen(options.listen.port, options.listen.host, () => {
      server.off('error', reject);
      const { port } = server.address();
      const host = options.listen.host.includes(':') ? `[${options.listen.host}]` : options.listen.host;
      const url = `${options.tls ? 'https' : 'http'}://${host}:${port}/`;
      const stop = () => new Promise((done) => {
        server.close(() => done());
        live.close();
        esgd.close();
        // Keep-alive connections of browsers would hold close() open until they time out.
        server.closeIdleConnections();
        setTimeout(() => server.closeAllConnections(), 1000).unref();
      });
      resolve({ url, stop });
    });
  });
}

module.exports = { startServer };
