// Bounds on request bodies (docs/console-gateway.md "Security"). Each route declares the largest
// body it reads; a request announcing more (Content-Length) is refused on its head, before a byte
// of the body is read, and a chunked body is counted as it arrives and refused once it passes the
// bound. An answer given before the whole body arrived closes the connection (respond.js), so
// the rest is never read.
'use strict';

const { ApiError } = require('./errors');

// POST .../predict: a PredictRequest as JSON. esgd takes request messages of at most 8 MiB, and
// its JSON is larger than the message it becomes, so a bigger body is never one esgd would take;
// 8 MiB holds a planned attitude sampled every 2.5 s over the whole 48 h a prediction may reach
// (about 110 bytes of JSON a sample). Reading and converting that much takes the gateway's one
// thread a fraction of a second, and only for an operator whose token esgd accepted.
const PREDICT_BODY_BYTES = 8 * 1024 * 1024;
// POST .../acknowledge: {"operator_name": NAME}, a name of at most 64 characters (esgd's
// bound), 768 bytes even if every character is written as a \u escape pair.
const ACKNOWLEDGE_BODY_BYTES = 1024;

function tooLarge(limit) {
  return new ApiError(413, 'RESOURCE_EXHAUSTED', limit === 0
    ? 'body: this request takes no body'
    : `body: larger than ${limit} bytes, the most this request takes`);
}

// Throws 413 when the request announces a body larger than `limit` bytes.
function checkAnnouncedLength(req, limit) {
  const announced = req.headers['content-length'];
  if (announced !== undefined && Number(announced) > limit) throw tooLarge(limit);
}

// The body, at most `limit` bytes, as one Buffer; rejects with 413 as soon as more arrived (the
// rest is not kept).
function readBody(req, limit) {
  return new Promise((resolve, reject) => {
    const chunks = [];
    let size = 0;
    let failed = false;
    const fail = (err) => {
      if (failed) return;
      failed = true;
      chunks.length = 0;
      reject(err);
    };
    req.on('data', (chunk) => {
      if (failed) return;
      size += chunk.length;
      if (size > limit) {
        fail(tooLarge(limit));
        return;
      }
      chunks.push(chunk);
    });
    req.on('error', fail);
    req.on('end', () => { if (!failed) resolve(Buffer.concat(chunks)); });
  });
}

module.exports = { PREDICT_BODY_BYTES, ACKNOWLEDGE_BODY_BYTES, checkAnnouncedLength, readBody };
