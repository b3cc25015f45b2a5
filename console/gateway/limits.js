// Bounds on request bodies (docs/console-gateway.md "Security"). Each route declares the largest
// body it reads; a request announcing more (Content-Length) is refused on its head, before a byte
// of the body is read, and a chunked body is counted as it arrives and refused once it passes the
// bound. An answer given before the whole body arrived closes the connection (respond.js), so
// the rest is never read.
'use strict';

const { ApiError } = require('./errors');

// POST .../predict: a PredictRequest as JSON, read, parsed and converted on the gateway's one
// thread, which serves every other operator meanwhile: about 0.3 s for 2 MiB, 1.5 s for 8 MiB
// (measured on 2 loaded cores). 2 MiB holds a planned attitude sampled every 10 s over the whole
// 48 h a prediction may reach (about 17 000 samples of some 120 bytes of JSON). Larger plans, up
// to the 100 000 samples esgd takes in its 8 MiB messages, go through the esg CLI
// (`esg predict --planned FILE`), which talks to esgd directly.
const PREDICT_BODY_BYTES = 2 * 1024 * 1024;
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
