// Whether esgd accepts a token, asked before the gateway does any work for a request (before it
// reads a body, before a WebSocket signs in). The gateway has no credentials or token list of its
// own: esgd is asked, with the cheapest call that needs the read role, GetSession with an empty
// spacecraft id. esgd checks the token first (UNAUTHENTICATED: missing or unknown token;
// PERMISSION_DENIED: a token without the read role) and then refuses the empty id at once
// (INVALID_ARGUMENT "spacecraft_id: required") without a lock or a database read; so
// INVALID_ARGUMENT means "accepted". Against an esgd without tokens every call is accepted.
//
// Answers are kept for a few seconds, keyed by the SHA-256 of the Authorization value (the cache
// holds no token), so a burst of requests, or of refused ones, costs esgd one call per token.
// The cache only decides what the gateway bothers to read: every call the gateway then makes
// carries the token and esgd checks it again, so a token revoked meanwhile gains nothing.
//
// Whether a token has the write role (canWrite, for the page to offer its write actions only to
// those who may use them) is asked the same way with the cheapest call that needs it,
// ApplyDiagnosis with an empty spacecraft id: esgd checks the role first (PERMISSION_DENIED
// without it), then refuses the empty id at once (INVALID_ARGUMENT), changing nothing. It only
// decides what the page shows: esgd checks the role of every write call itself.
'use strict';

const crypto = require('node:crypto');
const { grpc } = require('./esgd');

const TTL_MS = 5000;
const MAX_ENTRIES = 1000;
// GetSession("") is answered at once; a slow answer means esgd is in trouble, not a slow check.
const CHECK_DEADLINE_MS = 10_000;

const REFUSALS = new Set([grpc.status.UNAUTHENTICATED, grpc.status.PERMISSION_DENIED]);
const ACCEPTED = new Set([grpc.status.INVALID_ARGUMENT, grpc.status.NOT_FOUND]);

function digest(authorization) {
  return crypto.createHash('sha256').update(authorization || '').digest('hex');
}

// Answers per token digest, each kept TTL_MS, at most MAX_ENTRIES in insertion order (a flood
// of made-up tokens pushes out only answers, oldest first). An answer `keep` rejects (esgd could
// not tell) is dropped as soon as it is known, so the next request asks again.
class AnswerCache {
  constructor() {
    this.entries = new Map(); // digest -> {promise, expires}
  }

  // The kept answer for `key`, or `ask()`'s; `keep({value})` or `keep({error})` says whether it
  // is kept. The promise settles as ask()'s does.
  get(key, ask, keep) {
    const cached = this.entries.get(key);
    if (cached && cached.expires > Date.now()) return cached.promise;
    this.entries.delete(key);
    const entry = { expires: Infinity, promise: null };
    const settle = (outcome) => {
      if (keep(outcome)) entry.expires = Date.now() + TTL_MS;
      else if (this.entries.get(key) === entry) this.entries.delete(key);
    };
    entry.promise = ask().then((value) => {
      settle({ value });
      return value;
    }, (error) => {
      settle({ error });
      throw error;
    });
    entry.promise.catch(() => {});
    this.entries.set(key, entry);
    while (this.entries.size > MAX_ENTRIES) this.entries.delete(this.entries.keys().next().value);
    return entry.promise;
  }
}

class TokenCheck {
  constructor(esgd) {
    this.esgd = esgd;
    this.reads = new AnswerCache(); // check's answers
    this.writes = new AnswerCache(); // canWrite's answers
  }

  // Resolves when esgd accepts `authorization` (an "Authorization" header value, or undefined
  // for none) for reading; rejects with esgd's error: code UNAUTHENTICATED or PERMISSION_DENIED
  // for a refused token, any other code when esgd could not be asked (not kept).
  check(authorization) {
    return this.reads.get(digest(authorization), () => this.ask(authorization),
      ({ error }) => !error || REFUSALS.has(error.code));
  }

  // Whether esgd lets `authorization` write: true (INVALID_ARGUMENT: the role was granted, then
  // the empty id refused), false (PERMISSION_DENIED or UNAUTHENTICATED: refused before), null
  // when esgd could not tell (an esgd without ApplyDiagnosis, refusals beyond its per-address
  // budget, esgd unreachable; not kept). Never rejects.
  canWrite(authorization) {
    const ask = () => this.esgd.unary('ApplyDiagnosis', { spacecraft_id: '', diagnosis_id: 0 },
      authorization, undefined, CHECK_DEADLINE_MS).then(() => true, (err) => {
      if (err.code === grpc.status.INVALID_ARGUMENT) return true;
      if (REFUSALS.has(err.code)) return false;
      return null;
    });
    return this.writes.get(digest(authorization), ask, ({ value }) => value !== null);
  }

  async ask(authorization) {
    try {
      await this.esgd.unary('GetSession', { spacecraft_id: '' }, authorization, undefined, CHECK_DEADLINE_MS);
    } catch (err) {
      if (ACCEPTED.has(err.code)) return;
      throw err;
    }
  }

  // Whether esgd wants a token at all: is a call without one refused? An esgd that throttles
  // refused calls per address (the gateway is one address for all its browsers) answers those
  // beyond its budget RESOURCE_EXHAUSTED instead of UNAUTHENTICATED: refused all the same. That
  // answer is not kept by check(), which would otherwise hold it against a valid token too.
  async tokensRequired() {
    try {
      await this.check(undefined);
      return false;
    } catch (err) {
      if (err.code === grpc.status.UNAUTHENTICATED || err.code === grpc.status.RESOURCE_EXHAUSTED) return true;
      throw err;
    }
  }

  // Who an operator is, for the per-operator limits: their token (its digest) when esgd checks
  // tokens; otherwise the browser's address, since any made-up token passes an esgd without
  // tokens and would make a new operator each time.
  async operatorKey(token, peerAddress) {
    if (await this.tokensRequired()) return `token:${digest(token)}`;
    return `peer:${peerAddress}`;
  }
}

module.exports = { TokenCheck, digest };
