// Reading request parameters (query strings, path segments, JSON bodies). Each reader throws a
// 400 ApiError whose message starts with the parameter's name, so a bad request never reaches
// esgd half-converted and never crashes the gateway.
'use strict';

const { badRequest, ApiError } = require('./errors');
const { isoToTimestamp } = require('./convert');

// Largest request body read: a PredictRequest at esgd's limits (100 000 epochs and 100 000
// planned samples) is about 16 MB as JSON.
const MAX_BODY_BYTES = 32 * 1024 * 1024;

// Optional ISO-8601 time -> Timestamp, or undefined when absent or empty.
function timeParam(query, name) {
  const text = query.get(name);
  if (text === null || text === '') return undefined;
  const ts = isoToTimestamp(text);
  if (!ts) {
    throw badRequest(`${name}: expected an ISO-8601 UTC time such as 2019-03-01T00:00:00Z, got '${text}'`);
  }
  return ts;
}

function boolParam(query, name, fallback) {
  const text = query.get(name);
  if (text === null || text === '') return fallback;
  if (text === 'true' || text === '1') return true;
  if (text === 'false' || text === '0') return false;
  throw badRequest(`${name}: expected true or false, got '${text}'`);
}

// Integer in [min, max], from a query parameter (fallback when absent) or a path segment.
function intValue(name, text, min, max) {
  if (!/^-?\d+$/.test(text)) throw badRequest(`${name}: expected an integer, got '${text}'`);
  const n = Number(text);
  if (!Number.isSafeInteger(n) || n < min || n > max) {
    throw badRequest(`${name}: must be in ${min}..${max}, got ${text}`);
  }
  return n;
}

function intParam(query, name, min, max, fallback) {
  const text = query.get(name);
  if (text === null || text === '') return fallback;
  return intValue(name, text, min, max);
}

function numberParam(query, name) {
  const text = query.get(name);
  if (text === null || text === '') return undefined;
  const n = Number(text);
  if (!Number.isFinite(n)) throw badRequest(`${name}: expected a number, got '${text}'`);
  return n;
}

// The request body parsed as a JSON object; 400 naming `body` when it is missing or not JSON,
// 413 beyond MAX_BODY_BYTES, 415 when a body does not say it is JSON. A browser sends
// Content-Type application/json to another site only after a CORS preflight, which the gateway
// never grants: so another web site cannot make an operator's browser post here (acknowledge
// alerts of an esgd without tokens) with a form or a no-cors fetch.
function jsonBody(req) {
  return new Promise((resolve, reject) => {
    const chunks = [];
    let size = 0;
    let failed = false;
    req.on('data', (chunk) => {
      if (failed) return;
      size += chunk.length;
      if (size > MAX_BODY_BYTES) {
        failed = true;
        reject(new ApiError(413, 'RESOURCE_EXHAUSTED', `body: larger than ${MAX_BODY_BYTES} bytes`));
        return;
      }
      chunks.push(chunk);
    });
    req.on('error', (err) => { if (!failed) { failed = true; reject(err); } });
    req.on('end', () => {
      if (failed) return;
      const text = Buffer.concat(chunks).toString('utf8');
      if (text.trim() === '') {
        reject(badRequest('body: missing (expected a JSON object)'));
        return;
      }
      if (!/^application\/json\s*(;|$)/i.test(req.headers['content-type'] || '')) {
        reject(new ApiError(415, 'INVALID_ARGUMENT', 'Content-Type: expected application/json'));
        return;
      }
      let value;
      try {
        value = JSON.parse(text);
      } catch (err) {
        reject(badRequest(`body: not JSON (${err.message})`));
        return;
      }
      if (value === null || typeof value !== 'object' || Array.isArray(value)) {
        reject(badRequest('body: expected a JSON object'));
        return;
      }
      resolve(value);
    });
  });
}

module.exports = { timeParam, boolParam, intParam, intValue, numberParam, jsonBody };
