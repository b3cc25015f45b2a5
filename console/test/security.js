// The gateway's own defences (docs/console-gateway.md "Security"), each against a real esgd and
// a real gateway: the token checked with esgd before a body is read, the body bounds, the caps
// on live subscriptions, and the Host/Origin list. Registered by gateway.test.js, whose esgd
// (with tokens and the 2 h flight) they share; each starts the gateways it measures.
'use strict';

const { test } = require('node:test');
const assert = require('node:assert/strict');
const crypto = require('node:crypto');
const path = require('node:path');
const WebSocket = require('ws');
const { startEsgd, startGateway, stop, request, Inbox } = require('./helpers');
const { openRequest, pour, rssBytes } = require('./rawhttp');

const MIB = 1024 * 1024;
const BIG = 30 * MIB;
const PREDICT = '/api/spacecraft/RDK-1/predict';
const JSON_TYPE = { 'content-type': 'application/json' };
// The gateway's bounds (gateway/limits.js, gateway/live.js), as documented.
const PREDICT_LIMIT = 2 * MIB;
const PER_SOCKET = 32;
const PER_OPERATOR = 64;

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

// Rejects when `promise` has not settled within `ms`: a request the gateway does not answer
// fails the test instead of hanging it.
function within(ms, promise, what) {
  let timer;
  return Promise.race([promise, new Promise((_, reject) => {
    timer = setTimeout(() => reject(new Error(`${what}: no answer within ${ms} ms`)), ms);
  })]).finally(() => clearTimeout(timer));
}

// A predict body of exactly `size` bytes: a JSON object padded with spaces (still JSON), so the
// gateway that reads it has a real PredictRequest of that size to convert.
function paddedPredictBody(size, json) {
  const text = JSON.stringify(json);
  return Buffer.from(text + ' '.repeat(size - Buffer.byteLength(text)));
}

// 30 MiB of one JSON PredictRequest with 1.2 million explicit epochs: what an attacker posts.
function hugePredictBody() {
  const item = '"2019-03-01T02:30:00.000Z",';
  const head = '{"times":[';
  const tail = '"2019-03-01T02:30:00.000Z"]}';
  const count = Math.floor((BIG - head.length - tail.length) / item.length);
  const text = head + item.repeat(count) + tail;
  return Buffer.concat([Buffer.from(text), Buffer.alloc(BIG - text.length, ' ')]);
}

function openSocket(url, options) {
  const ws = new WebSocket(new URL('/api/live', url.replace(/^http/, 'ws')), options);
  const inbox = new Inbox(ws);
  return new Promise((resolve, reject) => {
    ws.once('open', () => resolve({ ws, inbox }));
    ws.once('error', reject);
  });
}

async function signIn(url, token) {
  const socket = await openSocket(url);
  socket.ws.send(JSON.stringify({ type: 'auth', token }));
  assert.deepEqual(await socket.inbox.take(() => true), { type: 'ready' });
  return socket;
}

// Sends one alert subscription per id; resolves with each id's first answer (replay_complete or
// error), waiting at most `ms` for all of them.
async function subscribeAll(socket, ids, ms = 20_000) {
  for (const id of ids) {
    socket.ws.send(JSON.stringify({ type: 'subscribe', id, stream: 'alerts', spacecraft_id: '', since: null }));
  }
  return within(ms, Promise.all(ids.map((id) => socket.inbox.take((m) => m.id === id, ms + 1000))),
    `${ids.length} subscribe messages`);
}

const ids = (prefix, n) => Array.from({ length: n }, (_, i) => `${prefix}${i}`);

function register(ctx) {
  const asAlice = () => ({ Authorization: `Bearer ${ctx.alice}` });
  const asBob = () => ({ Authorization: `Bearer ${ctx.bob}` });

  test('security: a body is refused on the request head (413 above the route limit, 401 for no or an unknown token), before any of it is sent', async (t) => {
    const gateway = ctx.gateway();
    const head = (headers, pathName = PREDICT, method = 'POST') =>
      openRequest(gateway.url, { method, path: pathName, headers: { ...JSON_TYPE, ...headers } });

    // The attacker's request: no token, 30 MiB announced. Refused at once on its head.
    const attack = await head({ 'content-length': BIG });
    const refused = await within(5000, attack.answer, '30 MiB POST without a token');
    attack.socket.destroy();
    t.diagnostic(`30 MiB POST without a token: ${refused.status} after ${refused.ms} ms, ${refused.sentAtAnswer} body bytes sent`);
    assert.equal(refused.status, 413);
    assert.equal(refused.sentAtAnswer, 0);
    assert.equal(refused.json.error.code, 'RESOURCE_EXHAUSTED');
    assert.match(refused.json.error.message, /^body: /);
    assert.match(refused.json.error.message, /2097152 bytes/);
    assert.equal(refused.headers.connection, 'close');
    assert.ok(refused.ms < 1000, `refused after ${refused.ms} ms`);

    const cases = [
      // The bound holds for every operator.
      [{ ...asAlice(), 'content-length': BIG }, 413, 'RESOURCE_EXHAUSTED'],
      // Within the bound: the token decides, before the body is read.
      [{ 'content-length': MIB }, 401, 'UNAUTHENTICATED'],
      [{ Authorization: 'Bearer not-a-token', 'content-length': MIB }, 401, 'UNAUTHENTICATED'],
      [{ Authorization: 'Bearer not-a-token', 'transfer-encoding': 'chunked' }, 401, 'UNAUTHENTICATED'],
    ];
    for (const [headers, status, code] of cases) {
      const connection = await head(headers);
      const answer = await within(5000, connection.answer, JSON.stringify(headers));
      connection.socket.destroy();
      assert.equal(answer.status, status, JSON.stringify(headers));
      assert.equal(answer.json.error.code, code);
      assert.equal(answer.sentAtAnswer, 0);
    }
    // An acknowledgement's body is a name: 1 KiB at most. Routes without a body take none.
    for (const [pathName, method, headers] of [
      ['/api/spacecraft/RDK-1/alerts/1/acknowledge', 'POST', { ...asAlice(), 'content-length': 4096 }],
      ['/api/sessions', 'GET', { ...asBob(), 'content-length': 10 }],
    ]) {
      const connection = await head(headers, pathName, method);
      const answer = await within(5000, connection.answer, `${method} ${pathName}`);
      connection.socket.destroy();
      assert.equal(answer.status, 413, `${method} ${pathName}`);
      assert.match(answer.json.error.message, /^body: /);
    }

    // A known token within the bound: the gateway waits for the body, then answers it.
    const body = paddedPredictBody(MIB, { from: '2019-03-01T01:30:00Z', to: '2019-03-01T03:00:00Z', step_s: 900 });
    const operator = await head({ ...asBob(), 'content-length': body.length });
    await assert.rejects(within(300, operator.answer, 'a body not sent yet'), /no answer/);
    await pour(operator, body, body.length);
    const answered = await within(10_000, operator.answer, 'a 1 MiB predict body');
    operator.socket.destroy();
    assert.equal(answered.status, 200, answered.text);
    assert.equal(answered.json.samples.length, 7);
  });

  test('security: a chunked body is counted as it arrives and cut off at the route limit (413, connection closed)', async () => {
    const gateway = ctx.gateway();
    const connection = await openRequest(gateway.url, { method: 'POST', path: PREDICT,
      headers: { ...JSON_TYPE, ...asAlice(), 'transfer-encoding': 'chunked' } });
    let answered = false;
    connection.answer.then(() => { answered = true; }, () => { answered = true; });
    const written = await pour(connection, hugePredictBody(), BIG, { chunked: true, stopWhen: () => answered });
    const answer = await within(10_000, connection.answer, 'a chunked 30 MiB body');
    connection.socket.destroy();
    assert.equal(answer.status, 413);
    assert.match(answer.json.error.message, /^body: larger than 2097152 bytes/);
    assert.ok(answer.sentAtAnswer >= PREDICT_LIMIT, `answered after ${answer.sentAtAnswer} bytes`);
    assert.ok(written < BIG, 'the gateway took the whole 30 MiB');
  });

  test('security: six parallel 30 MiB POSTs without a token leave the gateway\'s memory flat and another operator served at once', async (t) => {
    const gateway = await startGateway(['--esgd', ctx.esgd().address]);
    try {
      const body = hugePredictBody();
      // Warm up the gateway (the proto, the token check of bob, the first connection to esgd).
      assert.equal((await request(new URL('/api/sessions', gateway.url), { headers: asBob() })).status, 200);
      const rssBefore = rssBytes(gateway.child.pid);
      const floods = Array.from({ length: 6 }, async () => {
        const connection = await openRequest(gateway.url, { method: 'POST', path: PREDICT,
          headers: { ...JSON_TYPE, 'content-length': BIG } });
        const written = await pour(connection, body, BIG);
        const answer = await within(60_000, connection.answer, 'a flooding POST').catch((err) => ({ err }));
        connection.socket.destroy();
        return { written, answer };
      });
      // Another operator's requests, one after the other while the floods last: the slowest.
      let flooding = true;
      const latencies = [];
      const failures = [];
      const probe = (async () => {
        while (flooding) {
          const started = Date.now();
          try {
            const sessions = await within(60_000, request(new URL('/api/sessions', gateway.url), { headers: asBob() }),
              'GET /api/sessions during the flood');
            if (sessions.status !== 200) failures.push(`status ${sessions.status}`);
          } catch (err) {
            failures.push(err.message);
          }
          latencies.push(Date.now() - started);
          await sleep(20);
        }
      })();
      const results = await Promise.all(floods);
      flooding = false;
      await probe;
      const latency = Math.max(...latencies);
      await sleep(200);
      const rssAfter = gateway.child.exitCode === null ? rssBytes(gateway.child.pid) : NaN;
      t.diagnostic(`${latencies.length} GET /api/sessions during the flood, the slowest ${latency} ms; gateway RSS ${(rssBefore / MIB).toFixed(1)} MiB before, ${(rssAfter / MIB).toFixed(1)} MiB after; body bytes the floods got in: ${results.map((r) => r.written).join(', ')}`);
      assert.deepEqual(failures, []);
      for (const { written, answer } of results) {
        assert.equal(answer.status, 413, answer.err && answer.err.message);
        assert.ok(written < BIG, 'the gateway took a whole 30 MiB body');
      }
      assert.ok(latency < 2000, `GET /api/sessions took ${latency} ms during the flood`);
      assert.ok(rssAfter - rssBefore < 8 * MIB, `RSS grew by ${((rssAfter - rssBefore) / MIB).toFixed(1)} MiB`);
    } finally {
      await stop(gateway.child);
    }
  });

  test('security: the token check is cached: ten requests with one unknown token cost esgd one check', async () => {
    const gateway = ctx.gateway();
    const refusals = () => (ctx.esgd().stderr().match(/authorization refused/g) || []).length;
    const before = refusals();
    const headers = { Authorization: `Bearer probe-${crypto.randomBytes(8).toString('hex')}` };
    for (let i = 0; i < 10; i++) {
      const answer = await request(new URL('/api/sessions', gateway.url), { headers });
      assert.equal(answer.status, 401);
      assert.match(answer.json.error.message, /unknown token/);
    }
    await sleep(100);
    assert.equal(refusals() - before, 1);
  });

  test('security: live subscriptions are capped per socket (32) and per operator (64); a flood of 150 does not delay another operator', async (t) => {
    const gateway = await startGateway(['--esgd', ctx.esgd().address]);
    const sockets = [];
    try {
      const a = await signIn(gateway.url, ctx.bob);
      sockets.push(a);
      const flood = ids('a', 150);
      for (const id of flood) {
        a.ws.send(JSON.stringify({ type: 'subscribe', id, stream: 'alerts', spacecraft_id: '', since: null }));
      }
      await sleep(1000);
      // Another operator's REST request right after the flood.
      const started = Date.now();
      const sessions = await within(15_000, request(new URL('/api/sessions', gateway.url), { headers: asAlice() }),
        'GET /api/sessions after 150 subscribes');
      const latency = Date.now() - started;
      t.diagnostic(`GET /api/sessions of another operator after 150 subscribes on one socket: ${latency} ms`);
      assert.equal(sessions.status, 200);
      assert.ok(latency < 2000, `took ${latency} ms`);

      const answers = await within(20_000, Promise.all(flood.map((id) => a.inbox.take((m) => m.id === id, 21_000))),
        '150 subscribe messages');
      const running = answers.filter((m) => m.type === 'replay_complete');
      const capped = answers.filter((m) => m.type === 'error');
      assert.equal(running.length, PER_SOCKET);
      assert.equal(capped.length, 150 - PER_SOCKET);
      assert.deepEqual(running.map((m) => m.id), flood.slice(0, PER_SOCKET));
      assert.equal(capped[0].error.code, 'RESOURCE_EXHAUSTED');
      assert.match(capped[0].error.message, /^subscribe: this socket already runs 32 subscriptions/);

      // The same operator on a second socket: up to 64 over both, then refused naming the operator.
      const b = await signIn(gateway.url, ctx.bob);
      sockets.push(b);
      const second = await subscribeAll(b, ids('b', PER_SOCKET));
      assert.ok(second.every((m) => m.type === 'replay_complete'));
      const c = await signIn(gateway.url, ctx.bob);
      sockets.push(c);
      const [over] = await subscribeAll(c, ['c0']);
      assert.equal(over.type, 'error');
      assert.equal(over.error.code, 'RESOURCE_EXHAUSTED');
      assert.match(over.error.message, /^subscribe: this operator already runs 64 subscriptions/);

      // Another operator subscribes as usual; one unsubscribe gives the first operator a slot back.
      const d = await signIn(gateway.url, ctx.alice);
      sockets.push(d);
      assert.equal((await subscribeAll(d, ['d0']))[0].type, 'replay_complete');
      a.ws.send(JSON.stringify({ type: 'unsubscribe', id: 'a0' }));
      await sleep(200);
      assert.equal((await subscribeAll(c, ['c1']))[0].type, 'replay_complete');
    } finally {
      for (const { ws } of sockets) ws.close();
      await stop(gateway.child);
    }
  });

  test('security: Host and Origin not in the allowed list are refused: 421 and 403, on REST and the WebSocket', async () => {
    const gateway = ctx.gateway();
    const { port } = new URL(gateway.url);
    const get = (pathName, headers) => request(new URL(pathName, gateway.url), { headers });

    for (const host of ['evil.example', `evil.example:${port}`, `127.0.0.1.evil.example:${port}`, `localhost:${Number(port) + 1}`]) {
      const refused = await get('/api/sessions', { ...asBob(), Host: host });
      assert.equal(refused.status, 421, host);
      assert.equal(refused.json.error.code, 'INVALID_ARGUMENT');
      assert.match(refused.json.error.message, /^Host: '[^']+' is not a name this console gateway serves under .*--allowed-hosts/);
    }
    // The static files are the same public page under any name (a health probe names the pod).
    assert.equal((await get('/openmct/openmct.js', { Host: 'evil.example' })).status, 200);
    const ack = await request(new URL('/api/spacecraft/RDK-1/alerts/1/acknowledge', gateway.url),
      { method: 'POST', headers: { ...asAlice(), Host: 'evil.example' }, body: { operator_name: '' } });
    assert.equal(ack.status, 421);
    for (const host of [`localhost:${port}`, `LOCALHOST:${port}`, `[::1]:${port}`, `127.0.0.1:${port}`]) {
      assert.equal((await get('/api/sessions', { ...asBob(), Host: host })).status, 200, host);
    }

    for (const origin of ['http://evil.example', `http://evil.example:${port}`, 'null']) {
      const refused = await get('/api/sessions', { ...asBob(), Origin: origin });
      assert.equal(refused.status, 403, origin);
      assert.equal(refused.json.error.code, 'PERMISSION_DENIED');
      assert.match(refused.json.error.message, /^Origin: /);
    }
    for (const origin of [`http://127.0.0.1:${port}`, `http://localhost:${port}`]) {
      assert.equal((await get('/api/sessions', { ...asBob(), Origin: origin })).status, 200, origin);
    }

    await assert.rejects(openSocket(gateway.url, { headers: { Host: 'evil.example' } }), /421/);
    await assert.rejects(openSocket(gateway.url, { origin: `http://evil.example:${port}` }), /403/);
    const own = await openSocket(gateway.url, { headers: { Host: `localhost:${port}` }, origin: `http://localhost:${port}` });
    own.ws.send(JSON.stringify({ type: 'auth', token: ctx.bob }));
    assert.deepEqual(await own.inbox.take(() => true), { type: 'ready' });
    own.ws.close();
  });

  test('security: --allowed-hosts replaces the loopback names; a name without a port takes the listen port or none', async () => {
    const gateway = await startGateway(['--esgd', ctx.esgd().address, '--allowed-hosts', 'Console.Example,10.1.2.3:9000,[fd00::1]']);
    try {
      const { port } = new URL(gateway.url);
      const status = async (headers) => (await request(new URL('/api/auth', gateway.url), { headers })).status;
      for (const host of [`console.example:${port}`, 'console.example', 'console.example.', '10.1.2.3:9000', `[fd00::1]:${port}`]) {
        assert.equal(await status({ Host: host }), 200, host);
      }
      for (const host of [`127.0.0.1:${port}`, `localhost:${port}`, '10.1.2.3', `10.1.2.3:${port}`, 'console.example:1']) {
        assert.equal(await status({ Host: host }), 421, host);
      }
      assert.equal(await status({ Host: 'console.example', Origin: 'https://console.example' }), 200);
      assert.equal(await status({ Host: 'console.example', Origin: 'https://other.example' }), 403);
      const socket = await openSocket(gateway.url, { headers: { Host: `console.example:${port}` } });
      socket.ws.close();
      await assert.rejects(openSocket(gateway.url), /421/);
    } finally {
      await stop(gateway.child);
    }
  });

  test('security: against an esgd without tokens any token passes, the body bounds hold, and the operator is the peer address', async () => {
    const open = await startEsgd(['--db', path.join(ctx.tmp, 'open.db')]);
    const gateway = await startGateway(['--esgd', open.address]);
    const sockets = [];
    try {
      const attack = await openRequest(gateway.url, { method: 'POST', path: PREDICT,
        headers: { ...JSON_TYPE, 'content-length': BIG } });
      const refused = await within(5000, attack.answer, '30 MiB POST');
      attack.socket.destroy();
      assert.equal(refused.status, 413);
      assert.equal(refused.sentAtAnswer, 0);
      // A made-up token reaches esgd, which knows no spacecraft here.
      const answer = await request(new URL(PREDICT, gateway.url),
        { method: 'POST', headers: { Authorization: 'Bearer made-up' }, body: {} });
      assert.equal(answer.status, 404, answer.text);
      // Made-up tokens do not make more operators: the cap is the peer address's.
      for (const token of ['x', 'y']) {
        const socket = await signIn(gateway.url, token);
        sockets.push(socket);
        const answers = await subscribeAll(socket, ids(token, PER_SOCKET));
        assert.ok(answers.every((m) => m.type === 'replay_complete'), token);
      }
      const third = await signIn(gateway.url, '');
      sockets.push(third);
      const [over] = await subscribeAll(third, ['z0']);
      assert.match(over.error.message, /^subscribe: this operator already runs 64 subscriptions/);
    } finally {
      for (const { ws } of sockets) ws.close();
      await stop(gateway.child);
      await stop(open.child);
    }
  });
}

module.exports = { register };
