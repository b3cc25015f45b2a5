// Helpers of the gateway test: start real processes (esgd, the gateway) and wait for their
// "listening" lines, run the esg CLI, make HTTP(S) requests, and bring esg's proto3 JSON
// (camelCase names, int64 as strings) to the console's shape so the two can be compared field
// by field.
'use strict';

const { spawn, execFile } = require('node:child_process');
const http = require('node:http');
const https = require('node:https');
const path = require('node:path');
const protoLoader = require('@grpc/proto-loader');

const REPO = path.resolve(__dirname, '..', '..');
const ESGD = process.env.ESGD || path.join(REPO, 'build', 'server', 'esgd');
const ESG = process.env.ESG || path.join(REPO, 'build', 'client', 'esg');
const GATEWAY = path.join(REPO, 'console', 'gateway', 'main.js');

// Starts `command args`, resolves with {child, match, stderr()} once a stdout line matches
// `pattern` (match: its RegExp match); rejects if the process exits or 20 s pass first.
function startProcess(command, args, pattern) {
  return new Promise((resolve, reject) => {
    const child = spawn(command, args, { stdio: ['ignore', 'pipe', 'pipe'] });
    let stdout = '';
    let stderr = '';
    const timer = setTimeout(() => {
      child.kill('SIGKILL');
      reject(new Error(`${path.basename(command)} did not start in 20 s: ${stderr}`));
    }, 20_000);
    child.stdout.on('data', (chunk) => {
      stdout += chunk;
      const m = pattern.exec(stdout);
      if (m) {
        clearTimeout(timer);
        resolve({ child, match: m, stderr: () => stderr });
      }
    });
    child.stderr.on('data', (chunk) => { stderr += chunk; });
    child.on('exit', (code) => {
      clearTimeout(timer);
      reject(new Error(`${path.basename(command)} exited ${code} before it served: ${stderr}`));
    });
  });
}

async function startEsgd(args) {
  const { child, match, stderr } = await startProcess(ESGD, ['--listen', '127.0.0.1:0', ...args],
    /esgd listening on port (\d+)/);
  return { child, address: `127.0.0.1:${match[1]}`, stderr };
}

// nodeArgs: node's own options before the script (e.g. a heap limit).
async function startGateway(args, nodeArgs = []) {
  const { child, match, stderr } = await startProcess(process.execPath,
    [...nodeArgs, GATEWAY, '--listen', '127.0.0.1:0', ...args], /console: listening on (\S+)\n/);
  return { child, url: match[1], stderr };
}

// Runs the gateway expecting it to fail at once; resolves with {code, stderr}.
function runGatewayExpectingFailure(args) {
  return new Promise((resolve) => {
    execFile(process.execPath, [GATEWAY, ...args], { timeout: 10_000 }, (err, stdout, stderr) => {
      resolve({ code: err ? err.code : 0, stdout, stderr });
    });
  });
}

function stop(child) {
  return new Promise((resolve) => {
    if (child.exitCode !== null || child.signalCode !== null) {
      resolve({ code: child.exitCode, signal: child.signalCode });
      return;
    }
    child.once('exit', (code, signal) => resolve({ code, signal }));
    child.kill('SIGTERM');
  });
}

// Runs the esg CLI; resolves with stdout, rejects with stderr on a non-zero exit.
function esg(args) {
  return new Promise((resolve, reject) => {
    execFile(ESG, args, { maxBuffer: 256 * 1024 * 1024 }, (err, stdout, stderr) => {
      if (err) reject(new Error(`esg ${args.join(' ')}: exit ${err.code}: ${stderr}`));
      else resolve(stdout);
    });
  });
}

// One HTTP(S) request; resolves with {status, headers, text, json} (json: the parsed body when
// it is JSON). options: {method, headers, body (object or string), ca}. Each request on a
// connection of its own (agent: false): Node 20's global agent keeps connections alive, and a
// request sent on one just as the gateway closed it idle (its 5 s keep-alive timeout) failed
// with "socket hang up" (seen on a loaded machine). A browser retries such a request; a test
// client does not need the reuse.
function request(url, options = {}) {
  return new Promise((resolve, reject) => {
    const target = new URL(url);
    const lib = target.protocol === 'https:' ? https : http;
    let body = options.body;
    if (body !== undefined && typeof body !== 'string') body = JSON.stringify(body);
    const req = lib.request(target, {
      method: options.method || 'GET',
      headers: { ...(body !== undefined ? { 'Content-Type': 'application/json' } : {}),
        ...(options.headers || {}) },
      ca: options.ca,
      servername: options.servername,
      agent: false,
    }, (res) => {
      const chunks = [];
      res.on('data', (c) => chunks.push(c));
      res.on('end', () => {
        const buffer = Buffer.concat(chunks);
        const text = buffer.toString('utf8');
        let json;
        if ((res.headers['content-type'] || '').startsWith('application/json')) json = JSON.parse(text);
        resolve({ status: res.statusCode, headers: res.headers, text, buffer, json });
      });
    });
    req.on('error', reject);
    if (body !== undefined) req.write(body);
    req.end();
  });
}

// esg's proto3 JSON of message `typeName` -> the console's shape: .proto field names and int64
// as numbers, walked by the message descriptors (not by guessing from values). Unknown keys are
// kept unchanged, so a field the console lacks still shows up as a difference.
class EsgJson {
  constructor() {
    this.definition = protoLoader.loadSync('esg/v1/estimation_service.proto', {
      includeDirs: [path.join(REPO, 'proto')], keepCase: true,
    });
  }

  type(scope, typeName) {
    for (const name of [`${scope}.${typeName}`, typeName]) {
      if (this.definition[name]) return name;
    }
    throw new Error(`no type ${typeName}`);
  }

  normalize(typeName, json) {
    if (typeName === 'google.protobuf.Timestamp') return json;
    const fields = this.definition[typeName].type.field;
    const byJsonName = new Map(fields.map((f) =>
      [f.name.replace(/_([a-z0-9])/g, (_, c) => c.toUpperCase()), f]));
    const out = {};
    for (const [key, value] of Object.entries(json)) {
      const field = byJsonName.get(key) || fields.find((f) => f.name === key);
      if (!field) {
        out[key] = value;
        continue;
      }
      const one = (v) => {
        if (field.type === 'TYPE_MESSAGE') return this.normalize(this.type('esg.v1', field.typeName), v);
        if (/INT64|FIXED64/.test(field.type)) return Number(v);
        return v;
      };
      out[field.name] = Array.isArray(value) ? value.map(one) : one(value);
    }
    return out;
  }
}

// Every message a WebSocket receives, in order, and its close; take() removes and returns the
// first message (in arrival order) that satisfies a predicate, waiting for it if needed.
class Inbox {
  constructor(ws) {
    this.messages = [];
    this.waiters = new Set();
    this.closed = null;
    ws.on('message', (data) => {
      this.messages.push(JSON.parse(data.toString()));
      this.wake();
    });
    ws.on('close', (code, reason) => {
      this.closed = { code, reason: reason.toString() };
      this.wake();
    });
  }

  wake() {
    for (const waiter of this.waiters) waiter();
  }

  take(predicate, ms = 15_000) {
    return new Promise((resolve, reject) => {
      const check = () => {
        const i = this.messages.findIndex(predicate);
        if (i < 0) return false;
        const [message] = this.messages.splice(i, 1);
        this.waiters.delete(check);
        clearTimeout(timer);
        resolve(message);
        return true;
      };
      const timer = setTimeout(() => {
        this.waiters.delete(check);
        reject(new Error(`no matching WebSocket message in ${ms} ms; received ${JSON.stringify(this.messages).slice(0, 500)}`));
      }, ms);
      if (!check()) this.waiters.add(check);
    });
  }

  whenClosed(ms = 15_000) {
    return new Promise((resolve, reject) => {
      const check = () => {
        if (!this.closed) return;
        this.waiters.delete(check);
        clearTimeout(timer);
        resolve(this.closed);
      };
      const timer = setTimeout(() => reject(new Error(`WebSocket not closed in ${ms} ms`)), ms);
      this.waiters.add(check);
      check();
    });
  }
}

module.exports = {
  REPO, ESGD, ESG, startEsgd, startGateway, runGatewayExpectingFailure, stop, esg, request,
  EsgJson, Inbox,
};
