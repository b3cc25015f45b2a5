// Dispatch of /api/ requests to the routes of routes.js: path matching, the operator's token
// taken from the Authorization header, the JSON answer, the error mapping, and cancelling the
// request's gRPC calls when the browser goes away before the answer. Before a route runs, and so
// before any body is read, the request's announced size is checked against the route's bound
// (limits.js) and its token with esgd (tokencheck.js): a request nobody may make costs the
// gateway its head only.
'use strict';

const { Calls } = require('./esgd');
const { ApiError, toHttp } = require('./errors');
const { makeRoutes } = require('./routes');
const { StreamedJson } = require('./large');
const { sendJson } = require('./respond');
const { checkAnnouncedLength } = require('./limits');

// '/api/spacecraft/:id/history' -> a RegExp with one group per ':name' segment.
function compile(pattern) {
  const names = [];
  const source = pattern.split('/').map((part) => {
    if (!part.startsWith(':')) return part.replace(/[.*+?^${}()|[\]\\]/g, '\\$&');
    names.push(part.slice(1));
    return '([^/]+)';
  }).join('/');
  return { regex: new RegExp(`^${source}$`), names };
}

// tokens: a TokenCheck.
function makeApi(esgd, log, tokens) {
  const routes = makeRoutes(esgd, tokens).map(([method, pattern, handler, options = {}]) =>
    ({ method, ...compile(pattern), handler, bodyLimit: options.body || 0, public: !!options.public }));

  function match(method, pathname) {
    let pathMatched = false;
    for (const route of routes) {
      const m = route.regex.exec(pathname);
      if (!m) continue;
      pathMatched = true;
      if (route.method !== method) continue;
      const params = {};
      route.names.forEach((name, i) => {
        try {
          params[name] = decodeURIComponent(m[i + 1]);
        } catch {
          throw new ApiError(400, 'INVALID_ARGUMENT', `${name}: not a valid URL-encoded path segment`);
        }
      });
      return { route, params };
    }
    if (pathMatched) throw new ApiError(405, 'UNIMPLEMENTED', `${method} ${pathname}: method not allowed`);
    throw new ApiError(404, 'NOT_FOUND', `${pathname}: no such endpoint`);
  }

  return async function handle(req, res, url) {
    const started = Date.now();
    const owner = new Calls();
    // A browser that closes the connection before the answer cancels the calls made for it.
    res.on('close', () => { if (!res.writableFinished) owner.cancelAll(); });
    let httpStatus;
    try {
      const { route, params } = match(req.method === 'HEAD' ? 'GET' : req.method, url.pathname);
      checkAnnouncedLength(req, route.bodyLimit);
      const authorization = req.headers.authorization || undefined;
      if (!route.public) await tokens.check(authorization);
      const ctx = { req, params, query: url.searchParams, owner, authorization };
      const body = await route.handler(ctx);
      httpStatus = 200;
      if (body instanceof StreamedJson) await body.send(res);
      else sendJson(res, httpStatus, body);
    } catch (err) {
      const answer = toHttp(err);
      httpStatus = answer.httpStatus;
      if (httpStatus === 500) log(`error: ${req.method} ${url.pathname}: ${err.stack || err}`);
      if (!res.headersSent) sendJson(res, httpStatus, answer.body);
      else res.destroy();
    }
    // The query string holds times and flags only; the token is in a header and never logged.
    log(`${req.method} ${url.pathname} ${httpStatus} ${Date.now() - started} ms`);
  };
}

module.exports = { makeApi };
