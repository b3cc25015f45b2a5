// Writing a JSON answer: the one place that sets the headers every /api/ answer and every error
// of the static files carry.
'use strict';

function sendJson(res, httpStatus, body) {
  const text = JSON.stringify(body);
  res.writeHead(httpStatus, {
    'Content-Type': 'application/json; charset=utf-8',
    'Content-Length': Buffer.byteLength(text),
    'Cache-Control': 'no-store',
    'X-Content-Type-Options': 'nosniff',
  });
  res.end(text);
}

module.exports = { sendJson };
