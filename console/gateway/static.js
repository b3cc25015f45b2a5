// Static files of the console: the page (console/public/), Open MCT's build
// (console/node_modules/openmct/dist/) and the plugin (console/plugin/). A path that leaves its
// directory (../, encoded or not) is answered 404 like any missing file.
'use strict';

const fs = require('node:fs');
const path = require('node:path');
const { sendJson } = require('./respond');

const CONSOLE_DIR = path.resolve(__dirname, '..');

const MOUNTS = [
  { prefix: '/openmct/', dir: path.join(CONSOLE_DIR, 'node_modules', 'openmct', 'dist') },
  { prefix: '/plugin/', dir: path.join(CONSOLE_DIR, 'plugin') },
  // Everything else (the page itself and any file beside it, e.g. a favicon).
  { prefix: '/', dir: path.join(CONSOLE_DIR, 'public') },
];

const TYPES = {
  '.html': 'text/html; charset=utf-8',
  '.js': 'text/javascript; charset=utf-8',
  '.mjs': 'text/javascript; charset=utf-8',
  '.css': 'text/css; charset=utf-8',
  '.json': 'application/json; charset=utf-8',
  '.map': 'application/json; charset=utf-8',
  '.svg': 'image/svg+xml',
  '.png': 'image/png',
  '.ico': 'image/x-icon',
  '.woff': 'font/woff',
  '.woff2': 'font/woff2',
  '.ttf': 'font/ttf',
  '.txt': 'text/plain; charset=utf-8',
};

function notFound(res, pathname) {
  sendJson(res, 404, { error: { code: 'NOT_FOUND', message: `${pathname}: no such file` } });
}

// The file a URL path names, or null when it is outside every mount.
function resolve(pathname) {
  let decoded;
  try {
    decoded = decodeURIComponent(pathname);
  } catch {
    return null;
  }
  if (decoded.includes('\0')) return null;
  if (decoded === '/') decoded = '/index.html';
  const mount = MOUNTS.find((m) => decoded.startsWith(m.prefix));
  const file = path.resolve(mount.dir, `.${decoded.slice(mount.prefix.length - 1)}`);
  if (file !== mount.dir && !file.startsWith(mount.dir + path.sep)) return null;
  return file;
}

function serveStatic(req, res, url) {
  if (req.method !== 'GET' && req.method !== 'HEAD') {
    sendJson(res, 405, { error: { code: 'UNIMPLEMENTED', message: `${req.method}: static files are GET only` } });
    return;
  }
  const file = resolve(url.pathname);
  if (!file) {
    notFound(res, url.pathname);
    return;
  }
  fs.stat(file, (err, stat) => {
    if (err || !stat.isFile()) {
      notFound(res, url.pathname);
      return;
    }
    const mtime = stat.mtime.toUTCString();
    const headers = {
      'Content-Type': TYPES[path.extname(file).toLowerCase()] || 'application/octet-stream',
      'Content-Length': stat.size,
      'Last-Modified': mtime,
      // Revalidated on every load, so a new plugin or Open MCT version shows at the next reload.
      'Cache-Control': 'no-cache',
      'X-Content-Type-Options': 'nosniff',
    };
    if (req.headers['if-modified-since'] === mtime) {
      res.writeHead(304, { 'Last-Modified': mtime, 'Cache-Control': 'no-cache' });
      res.end();
      return;
    }
    res.writeHead(200, headers);
    if (req.method === 'HEAD') {
      res.end();
      return;
    }
    const stream = fs.createReadStream(file);
    stream.on('error', () => res.destroy());
    stream.pipe(res);
  });
}

module.exports = { serveStatic, resolve };
