// Large answers (docs/console-gateway.md "Large answers"): coefficient histories and per-step
// estimates. A 20-day history is some 67 MB of JSON; built whole, four at once took the gateway
// to 1.65 GB. Here:
//   - a history is written as it is read, one esgd page at a time (StreamedJson): the next page is
//     asked for only once the previous one was handed to the socket and its buffer drained, so a
//     request holds about one page (5000 snapshots, some 4 MB of JSON) whatever its span;
//   - a request returns at most MAX_HISTORY snapshots and a next_page_token to go on from;
//   - an operator runs at most PER_OPERATOR large answers at once; up to WAITING more wait for a
//     slot (the console asks for several series at once), further ones are refused with 429
//     RESOURCE_EXHAUSTED naming the bound.
'use strict';

const { once } = require('node:events');
const crypto = require('node:crypto');
const fs = require('node:fs');
const os = require('node:os');
const path = require('node:path');
const { ApiError } = require('./errors');

const MAX_HISTORY = 50000;
const PER_OPERATOR = 4;
const WAITING = 32;
// A SpooledText keeps up to this much in memory, then goes to a file read back this much at a time.
const SPOOL_MEMORY_BYTES = 256 * 1024;
const SPOOL_READ_BYTES = 64 * 1024;
// A streamed answer up to this size goes out whole, with its Content-Length.
const SMALL_ANSWER_BYTES = 64 * 1024;

// An answer {"<field>": [...items], ...tail()} written page by page. `pages` is an async
// iterator of arrays of JSON-able items (with `raw`, of their JSON texts); `tail()` (after the
// last page; may return a promise)
// gives the fields that follow the array, in their order, a SpooledText written as a JSON string
// from where it was kept; `done()` runs once the answer is written or failed.
class StreamedJson {
  constructor(field, pages, { tail = () => ({}), done = () => {}, raw = false } = {}) {
    this.field = field;
    this.pages = pages;
    this.raw = raw;
    this.tail = tail;
    this.done = done;
  }

  // Writes the answer; rejects if a page fails or the client goes away (after the headers went
  // out the caller destroys the socket; before, it answers the error). The first SMALL_ANSWER_BYTES
  // are held before the headers: an answer that ends within them goes out whole with its
  // Content-Length, as the gateway's other answers do; a larger one goes on chunked.
  async send(res) {
    try {
      await this.write(res);
    } finally {
      this.done();
    }
  }

  async write(res) {
    const headers = {
      'Content-Type': 'application/json; charset=utf-8',
      'Cache-Control': 'no-store',
      'X-Content-Type-Options': 'nosniff',
    };
    let held = [];
    let heldBytes = 0;
    let first = true;
    const write = async (text) => {
      if (res.destroyed) throw new Error('the client went away');
      if (held) {
        held.push(text);
        heldBytes += typeof text === 'string' ? Buffer.byteLength(text) : text.length;
        if (heldBytes <= SMALL_ANSWER_BYTES) return;
        res.writeHead(200, headers);
        text = Buffer.concat(held.map((t) => (typeof t === 'string' ? Buffer.from(t) : t)));
        held = null;
      }
      if (!res.write(text)) {
        await Promise.race([once(res, 'drain'), once(res, 'close')]);
        if (res.destroyed) throw new Error('the client went away');
      }
    };
    await write(`{${JSON.stringify(this.field)}:[`);
    for await (const page of this.pages) {
      if (page.length === 0) continue;
      const text = (this.raw ? page : page.map((item) => JSON.stringify(item))).join(',');
      await write(first ? text : `,${text}`);
      first = false;
    }
    await write(']');
    for (const [key, value] of Object.entries(await this.tail())) {
      if (value instanceof SpooledText) {
        await write(`,${JSON.stringify(key)}:"`);
        await value.writeTo(write);
        await write('"');
      } else {
        await write(`,${JSON.stringify(key)}:${JSON.stringify(value)}`);
      }
    }
    if (!held) {
      res.end('}');
      return;
    }
    held.push('}');
    const body = Buffer.concat(held.map((t) => (typeof t === 'string' ? Buffer.from(t) : t)));
    res.writeHead(200, { ...headers, 'Content-Length': body.length });
    res.end(body);
  }
}

// A string that arrives in pieces alongside a streamed answer but is written after it (a
// prediction's AEM text follows its samples): kept as the JSON-escaped text of its pieces, in
// memory up to `memoryBytes`, beyond that in a file of the system's temporary directory that is
// removed as soon as it is open (it goes away with the gateway too). close() it when done.
class SpooledText {
  constructor(memoryBytes = SPOOL_MEMORY_BYTES) {
    this.memoryBytes = memoryBytes;
    this.parts = [];
    this.bytes = 0;
    this.file = null;
    this.closed = false;
  }

  async append(text) {
    if (!text) return;
    const escaped = Buffer.from(JSON.stringify(text).slice(1, -1), 'utf8');
    if (!this.file && this.bytes + escaped.length <= this.memoryBytes) {
      this.parts.push(escaped);
      this.bytes += escaped.length;
      return;
    }
    if (!this.file) {
      const name = path.join(os.tmpdir(), `esg-gateway-${process.pid}-${crypto.randomBytes(8).toString('hex')}`);
      const file = await fs.promises.open(name, 'wx+', 0o600);
      await fs.promises.unlink(name);
      if (this.closed) { // closed while the file was being opened
        await file.close();
        throw new Error('the answer was closed');
      }
      this.file = file;
      for (const part of this.parts) await this.file.write(part);
      this.parts = [];
    }
    await this.file.write(escaped);
    this.bytes += escaped.length;
  }

  // Writes the escaped text (without its quotes) through `write` (an async function of a chunk),
  // SPOOL_READ_BYTES at a time.
  async writeTo(write) {
    if (!this.file) {
      for (const part of this.parts) await write(part);
      return;
    }
    for (let at = 0; at < this.bytes;) {
      const buffer = Buffer.alloc(Math.min(SPOOL_READ_BYTES, this.bytes - at));
      const { bytesRead } = await this.file.read(buffer, 0, buffer.length, at);
      if (bytesRead === 0) throw new Error('the kept text ended early');
      await write(buffer.subarray(0, bytesRead));
      at += bytesRead;
    }
  }

  async close() {
    this.closed = true;
    this.parts = [];
    const file = this.file;
    this.file = null;
    if (file) await file.close();
  }
}

// Slots for the large answers of each operator (a token, or a browser's address without tokens).
class LargeAnswers {
  constructor(perOperator = PER_OPERATOR, waiting = WAITING) {
    this.perOperator = perOperator;
    this.waiting = waiting;
    this.operators = new Map(); // key -> {running, queue: [resolve]}
  }

  // Resolves with release() once `key` has a slot; rejects with 429 when `key` already runs
  // perOperator and has `waiting` more waiting. `what` names the request in the message.
  async take(key, what) {
    let operator = this.operators.get(key);
    if (!operator) {
      operator = { running: 0, queue: [] };
      this.operators.set(key, operator);
    }
    if (operator.running >= this.perOperator) {
      if (operator.queue.length >= this.waiting) {
        throw new ApiError(429, 'RESOURCE_EXHAUSTED',
          `${what}: this operator already has ${operator.running} large answers running and ` +
          `${operator.queue.length} waiting (limit ${this.perOperator} running and ` +
          `${this.waiting} waiting per operator); retry when one finishes`);
      }
      await new Promise((resolve) => operator.queue.push(resolve));
    } else {
      operator.running++;
    }
    let released = false;
    return () => {
      if (released) return;
      released = true;
      const next = operator.queue.shift();
      if (next) {
        next(); // the slot passes on
        return;
      }
      operator.running--;
      if (operator.running === 0) this.operators.delete(key);
    };
  }

  // Large answers running now (all operators), for tests and diagnostics.
  running() {
    let n = 0;
    for (const operator of this.operators.values()) n += operator.running;
    return n;
  }
}

module.exports = { StreamedJson, SpooledText, LargeAnswers, MAX_HISTORY, PER_OPERATOR, WAITING };
