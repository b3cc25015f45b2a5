// Reading request parameters (query strings, path segments, JSON bodies). Each reader throws a
// 400 ApiError whose message starts with the parameter's name, so a bad request never reaches
// esgd half-converted and never crashes the gateway.
'use strict';

const { badRequest, ApiError } = require('./errors');
const { isoToTimestamp } = require('./convert');
const { readBody } = require('./limits');

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
// 413 beyond `limit` bytes (limits.js), 415 when a body does not say it is JSON. A browser sends
// Content-Type application/json to another site only after a CORS preflight, which the gateway
// never grants: so another web site cannot make an operator's browser post here (acknowledge
// alerts of an esgd without tokens) with a form or a no-cors fetch.
async function jsonBody(req, limit) {
  const text = (await readBody(req, limit)).toString('utf8');
  if (text.trim() === '') throw badRequest('body: missing (expected a JSON object)');
  if (!/^application\/json\s*(;|$)/i.test(req.headers['content-type'] || '')) {
    throw new ApiError(415, 'INVALID_ARGUMENT', 'Content-Type: expected application/json');
  }
  let value;
  try {
    value = JSON.parse(text);
  } catch (err) {
    throw badRequest(`body: not JSON (${err.message})`);
  }
  if (value === null || typeof value !== 'object' || Array.isArray(value)) {
    throw badRequest('body: expected a JSON object');
  }
  return value;
}

module.exports = { timeParam, boolParam, intParam, intValue, numberParam, jsonBody };
