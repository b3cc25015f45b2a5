// The console's HTTP(S) server: /api/live upgrades to the WebSocket (live.js), /api/ goes to the
// REST endpoints (api.js), everything else to the static files (static.js). /api/ requests and
// the upgrade first pass the Host/Origin check (hosts.js); the static files are the same public
// page for anyone, and a health probe that names the gateway by its pod address still gets them.
// `stop()` is the graceful shutdown: no new connections, every gRPC call cancelled, every socket
// closed.
'use strict';

const http = require('node:http');
const https = require('node:https');
const { makeApi } = require('./api');
const { sendJson } = require('./respond');
const { serveStatic } = require('./static');
const { attachLive } = require('./live');
const { makeHostCheck } = require('./hosts');
const { TokenCheck } = require('./tokencheck');

// options: {listen: {host, port}, tls: {cert, key} | null, allowedHosts}; esgd: an Esgd;
// log(line). Resolves with {url, stop()} once listening.
function startServer(options, esgd, log) {
  const tokens = new TokenCheck(esgd);
  const api = makeApi(esgd, log, tokens);
  let server;
  const checkRequest = makeHostCheck(options.allowedHosts, () => server.address().port);
  const handler = (req, res) => {
    let url;
    try {
      url = new URL(req.url, 'http://localhost');
    } catch {
      sendJson(res, 400, { error: { code: 'INVALID_ARGUMENT', message: 'url: not a valid request target' } });
      return;
    }
    if (url.pathname === '/api' || url.pathname.startsWith('/api/')) {
      const refused = checkRequest(req);
      if (refused) {
        sendJson(res, refused.httpStatus, { error: { code: refused.code, message: refused.message } });
        return;
      }
      api(req, res, url).catch((err) => {
        log(`error: ${err.stack || err}`);
        res.destroy();
      });
    } else if (req.headers['content-length'] > 0 || req.headers['transfer-encoding']) {
      sendJson(res, 413, { error: { code: 'RESOURCE_EXHAUSTED', message: 'body: static files take no body' } });
    } else {
      serveStatic(req, res, url);
    }
  };
  server = options.tls
    ? https.createServer({ cert: options.tls.cert, key: options.tls.key }, handler)
    : http.createServer(handler);
  const live = attachLive(server, esgd, log, { tokens, checkRequest });

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
