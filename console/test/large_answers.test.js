// Large answers of the gateway (docs/console-gateway.md "Large answers", issue 40) against a real
// esgd and the real gateway on loopback: a 10-day flight (43 200 coefficient snapshots, about
// 60 MB of history JSON, 14 400 per-step estimates, about 17 MB). The history and the estimate
// list are streamed a page at a time and capped per request with a next_page_token; each
// operator runs at most 4 large answers, 32 more wait, further ones are refused 429; the
// gateway's resident set (/proc/PID/status VmRSS) stays flat while four full histories, or
// estimate lists, are read in parallel and while four paused readers hold theirs. A prediction
// is PredictAttitudeStream written as its chunks arrive, the JSON of PredictAttitude's answer
// byte for byte; a 100 000-sample one with its AEM leaves the gateway flat, and a reader that
// goes away frees its slot and esgd's.
//   node --test console/test/large_answers.test.js     (ESGD, ESG: the binaries; default build/)
'use strict';

const { test, before, after } = require('node:test');
const assert = require('node:assert/strict');
const crypto = require('node:crypto');
const fs = require('node:fs');
const http = require('node:http');
const os = require('node:os');
const path = require('node:path');
const { REPO, startEsgd, startGateway, stop, esg, request } = require('./helpers');
const { Esgd } = require('../gateway/esgd');
const { toHttp } = require('../gateway/errors');
const { latestStates } = require('../gateway/routes');

const CONFIG = path.join(REPO, 'deploy', 'examples', 'rdk1.json');
const SCENARIO = path.join(REPO, 'deploy', 'examples', 'scenarios', 'paper_calibration.json');
const HOURS = 240;
const SNAPSHOTS = HOURS * 60 * 3; // a snapshot per gyro per minute (3 gyros)
// The gateway runs with a 128 MiB V8 heap: what it keeps alive must fit (a gateway holding four
// whole answers dies of heap exhaustion and the requests fail), and V8 collects its garbage before
// the heap passes that, so the resident set measures what the gateway holds, not when V8 chose
// to collect. Without the limit V8 let garbage grow before collecting: the same four histories
// measured 62 -> 207 and 150 -> 307 MiB, and once 527 MiB of growth (a failed run).
const GATEWAY_HEAP = ['--max-old-space-size=128'];

const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'esg-large-test-'));
const alice = `alice-${crypto.randomBytes(12).toString('hex')}`;
const bob = `bob-${crypto.randomBytes(12).toString('hex')}`;
const asAlice = { Authorization: `Bearer ${alice}` };
const asBob = { Authorization: `Bearer ${bob}` };
let esgd;
let gateway;

const api = (pathAndQuery, options = {}) => request(new URL(pathAndQuery, gateway.url), options);

function rssMiB(pid) {
  const status = fs.readFileSync(`/proc/${pid}/status`, 'utf8');
  return Number(/VmRSS:\s+(\d+) kB/.exec(status)[1]) / 1024;
}

// Samples `pid`'s resident set every 20 ms until stop() is called; stop() resolves with the
// largest sample.
function watchRss(pid) {
  let peak = rssMiB(pid);
  const timer = setInterval(() => { peak = Math.max(peak, rssMiB(pid)); }, 20);
  return () => {
    clearInterval(timer);
    return Math.max(peak, rssMiB(pid));
  };
}

// A GET whose answer is read until `bytes` arrived and then left unread (the socket paused):
// resolves with {status, req} once the headers and those bytes are in.
function pausedGet(pathAndQuery, headers, bytes = 1) {
  return new Promise((resolve, reject) => {
    // A connection of its own, as helpers.request's.
    const req = http.get(new URL(pathAndQuery, gateway.url), { headers, agent: false }, (res) => {
      let got = 0;
      const onData = (chunk) => {
        got += chunk.length;
        if (got >= bytes) {
          res.off('data', onData);
          res.pause();
          resolve({ status: res.statusCode, req, res });
        }
      };
      res.on('data', onData);
      res.on('end', () => resolve({ status: res.statusCode, req, res }));
    });
    req.on('error', (err) => { if (err.code !== 'ECONNRESET') reject(err); });
  });
}

before(async () => {
  const tokens = path.join(tmp, 'tokens');
  fs.writeFileSync(tokens, `${alice} read,write alice\n${bob} read bob\n`, { mode: 0o600 });
  const flight = path.join(tmp, 'flight.csv');
  await esg(['simulate', '--config', CONFIG, '--profile', 'calibration', '--scenario', SCENARIO,
    '--hours', String(HOURS), '--seed', '1', '--out', flight]);
  esgd = await startEsgd(['--db', path.join(tmp, 'esg.db'), '--tokens', tokens]);
  const cli = (...args) => esg(['--server', esgd.address, '--token', alice, ...args]);
  await cli('configure', '--config', CONFIG, '--model', '10+11');
  await cli('replay', '--recording', flight, '--wait');
  // A second spacecraft with gyro faults, for alerts (the flight above raises none).
  const faultyConfig = path.join(tmp, 'rdkf.json');
  fs.writeFileSync(faultyConfig, fs.readFileSync(CONFIG, 'utf8').replace('"spacecraftId": "RDK-1"', '"spacecraftId": "RDK-F"'));
  const faulty = path.join(tmp, 'faulty.csv');
  await esg(['simulate', '--config', faultyConfig, '--profile', 'calibration', '--scenario',
    path.join(REPO, 'deploy', 'examples', 'scenarios', 'gyro_faults.json'), '--hours', '10', '--seed', '2', '--out', faulty]);
  await cli('configure', '--config', faultyConfig, '--model', '10+11');
  await cli('replay', '--recording', faulty, '--wait');
  gateway = await startGateway(['--esgd', esgd.address], GATEWAY_HEAP);
});

after(async () => {
  if (gateway) await stop(gateway.child);
  if (esgd) await stop(esgd.child);
  fs.rmSync(tmp, { recursive: true, force: true });
});

test('a history is paged by limit and next_page_token, and the pages make up the whole', async () => {
  const whole = await api('/api/spacecraft/RDK-1/history', { headers: asBob });
  assert.equal(whole.status, 200);
  assert.equal(whole.json.snapshots.length, SNAPSHOTS);
  assert.equal(whole.json.next_page_token, undefined); // all of it fits the 50 000 of a request
  const pages = [];
  let token = '';
  do {
    const answer = await api(`/api/spacecraft/RDK-1/history?limit=7000${token ? `&page_token=${encodeURIComponent(token)}` : ''}`,
      { headers: asBob });
    assert.equal(answer.status, 200);
    assert.ok(answer.json.snapshots.length <= 7000);
    pages.push(...answer.json.snapshots);
    token = answer.json.next_page_token;
  } while (token);
  assert.equal(pages.length, SNAPSHOTS);
  assert.deepEqual(pages.at(0), whole.json.snapshots.at(0));
  assert.deepEqual(pages.at(-1), whole.json.snapshots.at(-1));
  assert.deepEqual(pages.map((s) => s.measurement_time), whole.json.snapshots.map((s) => s.measurement_time));

  const tooMany = await api('/api/spacecraft/RDK-1/history?limit=50001', { headers: asBob });
  assert.equal(tooMany.status, 400);
  assert.match(tooMany.json.error.message, /^limit:/);
  const unknown = await api('/api/spacecraft/NOPE/history', { headers: asBob });
  assert.equal(unknown.status, 404);
});

test('four full histories in parallel leave the gateway flat', async () => {
  const pid = gateway.child.pid;
  const baseline = rssMiB(pid);
  const stopWatch = watchRss(pid);
  const started = Date.now();
  const answers = await Promise.all([0, 1, 2, 3].map(() =>
    api('/api/spacecraft/RDK-1/history', { headers: asBob })));
  const seconds = (Date.now() - started) / 1000;
  const peak = stopWatch();
  for (const answer of answers) {
    assert.equal(answer.status, 200);
    assert.equal(answer.json.snapshots.length, SNAPSHOTS);
  }
  const bytes = answers[0].text.length;
  console.log(`gateway RSS ${baseline.toFixed(0)} MiB before, ${peak.toFixed(0)} MiB at most ` +
    `while 4 histories of ${(bytes / 1e6).toFixed(1)} MB each were answered in ${seconds.toFixed(1)} s`);
  // Built whole (before issue 40) the four took the gateway from 63 to 929 MiB; streamed a page
  // at a time they hold a few pages (measured with the 128 MiB heap: 107 to 170 MiB).
  assert.ok(peak - baseline < 250, `gateway grew by ${(peak - baseline).toFixed(0)} MiB`);
});

test('an estimate list is paged by limit and next_page_token, and the pages make up the whole', async () => {
  const whole = await api('/api/spacecraft/RDK-1/estimates', { headers: asBob });
  assert.equal(whole.status, 200);
  const n = whole.json.estimates.length;
  assert.ok(n >= HOURS * 60 - 60 && n <= HOURS * 60 + 1, `${n} estimates`); // one per 60 s step
  assert.equal(whole.json.next_page_token, undefined); // all of it fits the 20 000 of a request
  const pages = [];
  let token = '';
  do {
    const answer = await api(`/api/spacecraft/RDK-1/estimates?limit=4000${token ? `&page_token=${encodeURIComponent(token)}` : ''}`,
      { headers: asBob });
    assert.equal(answer.status, 200);
    assert.ok(answer.json.estimates.length <= 4000);
    pages.push(...answer.json.estimates);
    token = answer.json.next_page_token;
  } while (token);
  assert.equal(pages.length, n);
  assert.deepEqual(pages.at(0), whole.json.estimates.at(0));
  assert.deepEqual(pages.at(-1), whole.json.estimates.at(-1));
  assert.deepEqual(pages.map((e) => e.measurement_time), whole.json.estimates.map((e) => e.measurement_time));

  const tooMany = await api('/api/spacecraft/RDK-1/estimates?limit=20001', { headers: asBob });
  assert.equal(tooMany.status, 400);
  assert.match(tooMany.json.error.message, /^limit:/);
  const unknown = await api('/api/spacecraft/NOPE/estimates', { headers: asBob });
  assert.equal(unknown.status, 404);
});

test('four full estimate lists in parallel leave the gateway flat', async () => {
  const pid = gateway.child.pid;
  const baseline = rssMiB(pid);
  const stopWatch = watchRss(pid);
  const started = Date.now();
  const answers = await Promise.all([0, 1, 2, 3].map(() =>
    api('/api/spacecraft/RDK-1/estimates', { headers: asBob })));
  const seconds = (Date.now() - started) / 1000;
  const peak = stopWatch();
  for (const answer of answers) {
    assert.equal(answer.status, 200);
    assert.equal(answer.json.estimates.length, answers[0].json.estimates.length);
  }
  const bytes = answers[0].text.length;
  console.log(`gateway RSS ${baseline.toFixed(0)} MiB before, ${peak.toFixed(0)} MiB at most ` +
    `while 4 estimate lists of ${(bytes / 1e6).toFixed(1)} MB each were answered in ${seconds.toFixed(1)} s`);
  // Built whole (before issue 40's paging of estimates) the four took the gateway from 62 to
  // 385 MiB; streamed a page at a time, from 116 to 158 MiB (with the 128 MiB heap).
  assert.ok(peak - baseline < 250, `gateway grew by ${(peak - baseline).toFixed(0)} MiB`);
});

test('an operator runs 4 large answers, 32 more wait, the next is refused; others are not held', async () => {
  const pid = gateway.child.pid;
  const baseline = rssMiB(pid);
  const stopWatch = watchRss(pid);
  // Four answers started and left unread: each holds one of bob's slots.
  const paused = await Promise.all([0, 1, 2, 3].map(() =>
    pausedGet('/api/spacecraft/RDK-1/history', asBob, 64 * 1024)));
  for (const p of paused) assert.equal(p.status, 200);
  // 32 more wait for a slot (their heads are in; nothing of them is answered yet).
  const waiting = [];
  for (let i = 0; i < 32; i++) waiting.push(pausedGet('/api/spacecraft/RDK-1/history?limit=10', asBob));
  await new Promise((resolve) => setTimeout(resolve, 500));
  const refused = await api('/api/spacecraft/RDK-1/history?limit=10', { headers: asBob });
  assert.equal(refused.status, 429);
  assert.equal(refused.json.error.code, 'RESOURCE_EXHAUSTED');
  assert.equal(refused.json.error.message,
    'history: this operator already has 4 large answers running and 32 waiting (limit 4 running ' +
    'and 32 waiting per operator); retry when one finishes');
  const estimatesRefused = await api('/api/spacecraft/RDK-1/estimates', { headers: asBob });
  assert.equal(estimatesRefused.status, 429);
  // Another operator is not held by bob's.
  const other = await api('/api/spacecraft/RDK-1/history?limit=100', { headers: asAlice });
  assert.equal(other.status, 200);
  assert.equal(other.json.snapshots.length, 100);
  assert.ok(other.json.next_page_token);
  const peak = stopWatch();
  console.log(`gateway RSS ${baseline.toFixed(0)} MiB before, ${peak.toFixed(0)} MiB at most ` +
    'while 4 paused readers held their histories and 32 requests waited');
  assert.ok(peak - baseline < 150, `gateway grew by ${(peak - baseline).toFixed(0)} MiB`);
  // The paused readers go away: their slots pass to the waiting ones, which are answered.
  for (const p of paused) p.req.destroy();
  const answered = await Promise.all(waiting);
  for (const w of answered) assert.equal(w.status, 200);
  // Every slot is free again: a new request of bob's is answered.
  const again = await api('/api/spacecraft/RDK-1/history?limit=10', { headers: asBob });
  assert.equal(again.status, 200);
  assert.equal(again.json.snapshots.length, 10);
});

// --- Predictions (PredictAttitudeStream written as its chunks arrive) ---

// esgd asked directly, as the gateway asked it before the stream: PredictAttitude's answer in the
// console's JSON (convert.js), or {httpStatus, body} of its error.
async function unaryPredict(request) {
  const client = new Esgd({ address: esgd.address });
  try {
    return { json: await client.unary('PredictAttitude', request, asBob.Authorization) };
  } catch (err) {
    return { error: toHttp(err) };
  } finally {
    client.close();
  }
}

// How each of some held streams (async iterators of Esgd.streamed) goes on when read: the
// messages it still gives, then its end, its error, or nothing within 2 s (still held). Reads
// each to one of those.
async function heldStates(held) {
  const states = await Promise.all(held.map(async (h) => {
    const started = Date.now();
    let messages = 0;
    try {
      for (;;) {
        const next = await Promise.race([h.next(),
          new Promise((resolve) => setTimeout(() => resolve('held'), 2000))]);
        if (next === 'held') return `held after ${messages} more messages`;
        if (next.done) return `ended after ${messages} more messages in ${Date.now() - started} ms`;
        messages++;
      }
    } catch (e) {
      return `error ${e.code} after ${messages} more messages: ${e.details}`;
    }
  }));
  return states.map((state, i) => `stream ${i}: ${state}`).join('; ');
}

// The session's last frame: predictions span it (recorded samples before, held after).
async function lastFrameMs() {
  const sessions = await api('/api/sessions', { headers: asBob });
  return Date.parse(sessions.json.sessions.find((x) => x.spacecraft_id === 'RDK-1').last_frame_time);
}

const iso = (ms) => new Date(ms).toISOString();
const ts = (ms) => ({ seconds: Math.floor(ms / 1000), nanos: (ms % 1000) * 1e6 });
// The AEM's lines that name when it was made.
const madeAt = (aem) => aem.replace(/^(CREATION_DATE|MESSAGE_ID)\s*=.*$/gm, '$1 = ...');

test('a small prediction through the gateway is the JSON PredictAttitude answers, byte for byte', async () => {
  const last = await lastFrameMs();
  const from = last - 3600_000;
  const to = last + 1800_000;
  const step = 30;
  const streamed = await api(`/api/spacecraft/RDK-1/predict?from=${iso(from)}&to=${iso(to)}&step_s=${step}`,
    { headers: asBob });
  assert.equal(streamed.status, 200);
  const unary = await unaryPredict({ spacecraft_id: 'RDK-1', from: ts(from), to: ts(to), step_s: step });
  assert.ok(unary.json, JSON.stringify(unary.error));
  assert.ok(unary.json.recorded_samples > 0 && unary.json.recorded_samples < unary.json.samples.length,
    `${unary.json.recorded_samples} of ${unary.json.samples.length} recorded`);
  assert.equal(unary.json.attitude_source, 'ATTITUDE_SOURCE_INERTIAL_HOLD');
  assert.equal(streamed.text, JSON.stringify(unary.json));

  // With the AEM, and more samples than a chunk holds (2000) in both sources: the same fields; the
  // AEM is one valid AEM with a segment per chunk (PredictAttitude's has one per source).
  const aemStep = 1;
  const aemFrom = last - 2500_000;
  const aemTo = last + 2500_000;
  const withAem = await api(`/api/spacecraft/RDK-1/predict?from=${iso(aemFrom)}&to=${iso(aemTo)}&step_s=${aemStep}&aem=true`,
    { headers: asBob });
  assert.equal(withAem.status, 200);
  const unaryAem = await unaryPredict({ spacecraft_id: 'RDK-1', from: ts(aemFrom), to: ts(aemTo), step_s: aemStep, aem: true });
  assert.ok(unaryAem.json, JSON.stringify(unaryAem.error));
  assert.deepEqual(Object.keys(withAem.json), Object.keys(unaryAem.json));
  const { aem_text: streamedAem, ...streamedRest } = withAem.json;
  const { aem_text: unaryAemText, ...unaryRest } = unaryAem.json;
  assert.deepEqual(streamedRest, unaryRest);
  const dataLines = (aem) => aem.split('\n').filter((line) => /^\d{4}-\d{2}-\d{2}T/.test(line));
  assert.equal(dataLines(streamedAem).length, withAem.json.samples.length);
  assert.deepEqual(dataLines(streamedAem), dataLines(unaryAemText));
  assert.equal((streamedAem.match(/^META_START$/gm) || []).length, Math.ceil(unaryAem.json.recorded_samples / 2000) +
    Math.ceil((unaryAem.json.samples.length - unaryAem.json.recorded_samples) / 2000));
  assert.equal((unaryAemText.match(/^META_START$/gm) || []).length, 2);

  // A planned attitude (POST): PLANNED after the last frame, the same JSON as PredictAttitude's.
  const plan = [{ time: iso(last), q_in_b: [1, 0, 0, 0] }, { time: iso(last + 3600_000), q_in_b: [0.7071067811865476, 0, 0, 0.7071067811865476] }];
  const body = { from: iso(from), to: iso(to), step_s: step, planned_attitude: plan };
  const planned = await api('/api/spacecraft/RDK-1/predict', { method: 'POST', headers: asBob, body });
  assert.equal(planned.status, 200);
  const unaryPlanned = await unaryPredict({ spacecraft_id: 'RDK-1', from: ts(from), to: ts(to), step_s: step,
    planned_attitude: plan.map((p) => ({ time: ts(Date.parse(p.time)), q_in_b: p.q_in_b })) });
  assert.ok(unaryPlanned.json, JSON.stringify(unaryPlanned.error));
  assert.equal(unaryPlanned.json.attitude_source, 'ATTITUDE_SOURCE_PLANNED');
  assert.equal(planned.text, JSON.stringify(unaryPlanned.json));
  // Times only, none after the last frame: every sample recorded.
  const times = [iso(last - 7200_000), iso(last - 3600_000)];
  const recordedOnly = await api('/api/spacecraft/RDK-1/predict', { method: 'POST', headers: asBob, body: { times } });
  assert.equal(recordedOnly.status, 200);
  const unaryRecorded = await unaryPredict({ spacecraft_id: 'RDK-1', times: times.map((t) => ts(Date.parse(t))) });
  assert.equal(recordedOnly.text, JSON.stringify(unaryRecorded.json));
  assert.equal(recordedOnly.json.attitude_source, 'ATTITUDE_SOURCE_RECORDED');
});

test('an esgd error before the first chunk is answered with PredictAttitude\'s status and JSON', async () => {
  const last = await lastFrameMs();
  const cases = [
    // unknown spacecraft: 404
    ['NOPE', { from: last - 60_000, to: last, step_s: 10 }],
    // past the 48 h horizon after the last applied frame: 400 OUT_OF_RANGE
    ['RDK-1', { from: last, to: last + 49 * 3600_000, step_s: 3600 }],
    // more than 100 000 samples: 400
    ['RDK-1', { from: last - 3600_000, to: last + 3600_000, step_s: 0.01 }],
    // before any star-tracker fix: 400 OUT_OF_RANGE
    ['RDK-1', { from: last - 400 * 3600_000, to: last - 399 * 3600_000, step_s: 600 }],
  ];
  const statuses = [];
  for (const [sc, c] of cases) {
    const answer = await api(`/api/spacecraft/${sc}/predict?from=${iso(c.from)}&to=${iso(c.to)}&step_s=${c.step_s}`,
      { headers: asBob });
    const unary = await unaryPredict({ spacecraft_id: sc, from: ts(c.from), to: ts(c.to), step_s: c.step_s });
    assert.ok(unary.error, `esgd answered ${sc} ${JSON.stringify(c)}`);
    assert.equal(answer.status, unary.error.httpStatus, answer.text);
    assert.deepEqual(answer.json, unary.error.body);
    statuses.push(answer.status);
  }
  assert.deepEqual(statuses, [404, 400, 400, 400]);
  // Refused by the gateway itself, as before: a bad parameter.
  const bad = await api(`/api/spacecraft/RDK-1/predict?from=${iso(last)}&to=${iso(last)}&step_s=fast`, { headers: asBob });
  assert.equal(bad.status, 400);
  assert.match(bad.json.error.message, /^step_s:/);
  // Without a token: 401 before any call.
  const anonymous = await api(`/api/spacecraft/RDK-1/predict?from=${iso(last)}&to=${iso(last)}&step_s=1`);
  assert.equal(anonymous.status, 401);
});

test('a 100 000-sample prediction with its AEM is streamed: the gateway stays flat', async () => {
  const last = await lastFrameMs();
  // 48 h of 1.728 s steps: 100 000 samples, the recorded day before the last frame, the held day after.
  const from = last - 24 * 3600_000;
  const to = from + 99_999 * 1728;
  const query = `from=${iso(from)}&to=${iso(to)}&step_s=1.728&aem=true`;
  const pid = gateway.child.pid;
  const baseline = rssMiB(pid);
  const stopWatch = watchRss(pid);
  const started = Date.now();
  const answer = await api(`/api/spacecraft/RDK-1/predict?${query}`, { headers: asBob });
  const seconds = (Date.now() - started) / 1000;
  const peak = stopWatch();
  assert.equal(answer.status, 200, answer.text.slice(0, 300));
  assert.equal(answer.json.samples.length, 100_000);
  assert.ok(answer.json.recorded_samples > 40_000 && answer.json.recorded_samples < 60_000);
  assert.equal(answer.json.attitude_source, 'ATTITUDE_SOURCE_INERTIAL_HOLD');
  const dataLines = answer.json.aem_text.split('\n').filter((line) => /^\d{4}-\d{2}-\d{2}T/.test(line));
  assert.equal(dataLines.length, 100_000);
  const mb = answer.buffer.length / 1e6;
  const aemMb = answer.json.aem_text.length / 1e6;
  delete answer.json; // let the test's own copy go before the gateway's "after" is read
  answer.text = null;
  answer.buffer = null;
  await new Promise((resolve) => setTimeout(resolve, 2000));
  const afterwards = rssMiB(pid);
  console.log(`gateway RSS ${baseline.toFixed(0)} MiB before, ${peak.toFixed(0)} MiB at most, ` +
    `${afterwards.toFixed(0)} MiB 2 s after a 100 000-sample prediction with AEM of ` +
    `${mb.toFixed(1)} MB of JSON (AEM ${aemMb.toFixed(1)} MB) answered in ${seconds.toFixed(1)} s`);
  // Asked whole (PredictAttitude, before) the gateway held the message, its JSON object and its
  // JSON text at once: measured 66 to 577 MiB, and 516 MiB 2 s later. Streamed it holds a chunk
  // or two (measured with the 128 MiB heap: 124 to 134 MiB).
  assert.ok(peak - baseline < 150, `gateway grew by ${(peak - baseline).toFixed(0)} MiB`);

  // Four in parallel.
  const base4 = rssMiB(pid);
  const watch4 = watchRss(pid);
  const started4 = Date.now();
  const four = await Promise.all([0, 1, 2, 3].map(() =>
    api(`/api/spacecraft/RDK-1/predict?${query}`, { headers: asBob })));
  const seconds4 = (Date.now() - started4) / 1000;
  const peak4 = watch4();
  for (const a of four) {
    assert.equal(a.status, 200);
    assert.equal(a.buffer.length > 1e6, true);
  }
  four.length = 0;
  console.log(`gateway RSS ${base4.toFixed(0)} MiB before, ${peak4.toFixed(0)} MiB at most while four ` +
    `such predictions were answered in parallel in ${seconds4.toFixed(1)} s`);
  // Asked whole: 516 to 1575 MiB; streamed, with the 128 MiB heap: 130 to 172 MiB.
  assert.ok(peak4 - base4 < 250, `gateway grew by ${(peak4 - base4).toFixed(0)} MiB`);
});

test('a prediction takes an operator\'s large-answer slot; a client that goes away frees it, and esgd\'s', async () => {
  const last = await lastFrameMs();
  const from = last - 24 * 3600_000;
  const to = from + 99_999 * 1728;
  const query = `/api/spacecraft/RDK-1/predict?from=${iso(from)}&to=${iso(to)}&step_s=1.728&aem=true`;
  const pid = gateway.child.pid;
  const baseline = rssMiB(pid);
  const stopWatch = watchRss(pid);
  for (let round = 0; round < 2; round++) {
    // Four predictions started and left unread after 64 KiB: they hold bob's four slots (and
    // esgd's four predictions of his).
    const paused = await Promise.all([0, 1, 2, 3].map(() => pausedGet(query, asBob, 64 * 1024)));
    for (const p of paused) assert.equal(p.status, 200);
    // A fifth waits for a slot: nothing of it is answered while the four are held.
    const fifth = pausedGet(`${query.replace('aem=true', 'aem=false')}`, asBob);
    const early = await Promise.race([fifth.then(() => 'answered'),
      new Promise((resolve) => setTimeout(() => resolve('waiting'), 1500))]);
    assert.equal(early, 'waiting');
    // The readers go away mid-answer: the fifth gets a slot and is answered.
    for (const p of paused) p.req.destroy();
    const got = await fifth;
    assert.equal(got.status, 200);
    got.req.destroy();
  }
  const peak = stopWatch();
  console.log(`gateway RSS ${baseline.toFixed(0)} MiB before, ${peak.toFixed(0)} MiB at most while ` +
    'four paused readers held 100 000-sample predictions with AEM (twice)');
  assert.ok(peak - baseline < 150, `gateway grew by ${(peak - baseline).toFixed(0)} MiB`);
  // Every slot, the gateway's and esgd's, is free again: four whole predictions in parallel.
  const small = `/api/spacecraft/RDK-1/predict?from=${iso(last - 600_000)}&to=${iso(last)}&step_s=10`;
  const again = await Promise.all([0, 1, 2, 3].map(() => api(small, { headers: asBob })));
  for (const a of again) {
    assert.equal(a.status, 200, a.text);
    assert.equal(a.json.samples.length, 61);
  }

  // esgd's own bound (four predictions per caller) held by another client of bob's token: the
  // gateway answers 429 with esgd's refusal, as PredictAttitude's was answered.
  const client = new Esgd({ address: esgd.address });
  try {
    // With the AEM (0.6 MB chunks) a stream that is not read stops in esgd within a chunk or two.
    const request = { spacecraft_id: 'RDK-1', from: ts(from), to: ts(to), step_s: 1.728, aem: true };
    const held = [0, 1, 2, 3].map(() => client.streamed('PredictAttitudeStream', request, asBob.Authorization));
    for (const h of held) assert.equal((await h.next()).done, false);
    const smallRequest = { spacecraft_id: 'RDK-1', from: ts(last - 600_000), to: ts(last), step_s: 10 };
    const unary = await unaryPredict(smallRequest);
    assert.ok(unary.error, 'esgd answered a fifth prediction of bob\'s');
    const refused = await api(small, { headers: asBob });
    // The gateway asks again for 1.5 s before it answers: a held stream that ended meanwhile
    // would let it through. A failure says how each held stream went on (drained).
    if (refused.status !== 429) {
      assert.fail(`the gateway answered ${refused.status}, not 429; the held streams: ${await heldStates(held)}`);
    }
    assert.equal(refused.status, unary.error.httpStatus);
    assert.equal(refused.json.error.code, unary.error.body.error.code);
    assert.match(refused.json.error.message, /^PredictAttitudeStream: caller '.*' already runs 4 predictions \(limit 4 per caller\)/);
    for (const h of held) await h.return();
  } finally {
    client.close();
  }
});

test('an alert list is a large answer: the JSON it was, written in pages, waiting for a slot', async () => {
  // The previous gateway's answer: the replay collected whole, each alert once in its latest state.
  const client = new Esgd({ address: esgd.address });
  let whole;
  try {
    whole = latestStates(await client.replay('SubscribeAlerts', { spacecraft_id: '', since: { seconds: 0, nanos: 0 } },
      asBob.Authorization));
  } finally {
    client.close();
  }
  assert.ok(whole.length > 0, 'the flight has alerts');
  const all = await api('/api/alerts', { headers: asBob });
  assert.equal(all.status, 200);
  assert.equal(all.text, JSON.stringify({ alerts: whole }));
  const one = await api('/api/spacecraft/RDK-F/alerts', { headers: asBob });
  assert.equal(one.text, JSON.stringify({ alerts: whole.filter((a) => a.spacecraft_id === 'RDK-F') }));
  const none = await api(`/api/spacecraft/RDK-F/alerts?since=${iso(Date.now() + 86400_000)}`, { headers: asBob });
  assert.equal(none.text, '{"alerts":[]}');
  assert.equal((await api('/api/spacecraft/NOPE/alerts', { headers: asBob })).status, 404);
  console.log(`${whole.length} alerts in the list`);
  // The fleet counts the same latest states (it keeps only the open ones while it reads).
  const fleet = await api('/api/fleet', { headers: asBob });
  assert.equal(fleet.status, 200);
  const rank = (a) => ['INFO', 'WARNING', 'DISTRESS', 'CRITICAL'].indexOf(a.severity.replace(/^ALERT_SEVERITY_/, ''));
  for (const entry of fleet.json.fleet) {
    const open = whole.filter((a) => a.spacecraft_id === entry.session.spacecraft_id && !a.cleared && !a.revised_time);
    const counts = { INFO: 0, WARNING: 0, DISTRESS: 0, CRITICAL: 0 };
    for (const a of open) counts[a.severity.replace(/^ALERT_SEVERITY_/, '')]++;
    assert.deepEqual(entry.open_alerts, counts, entry.session.spacecraft_id);
    const worst = open.reduce((w, a) => (!w || rank(a) > rank(w) ||
      (rank(a) === rank(w) && (a.measurement_time || '') > (w.measurement_time || '')) ? a : w), null);
    assert.deepEqual(entry.worst_alert, worst, entry.session.spacecraft_id);
  }
  assert.ok(fleet.json.fleet.some((e) => e.worst_alert), 'an open alert in the fleet');

  // Bob's four slots held by paused predictions: his alert list waits, alice's does not.
  const last = await lastFrameMs();
  const from = last - 24 * 3600_000;
  const query = `/api/spacecraft/RDK-1/predict?from=${iso(from)}&to=${iso(from + 99_999 * 1728)}&step_s=1.728`;
  const paused = await Promise.all([0, 1, 2, 3].map(() => pausedGet(query, asBob, 64 * 1024)));
  const waiting = api('/api/alerts', { headers: asBob });
  const early = await Promise.race([waiting.then(() => 'answered'),
    new Promise((resolve) => setTimeout(() => resolve('waiting'), 1000))]);
  assert.equal(early, 'waiting');
  assert.equal((await api('/api/alerts', { headers: asAlice })).text, all.text);
  for (const p of paused) p.req.destroy();
  assert.equal((await waiting).text, all.text);
});

test('an esgd without PredictAttitudeStream is asked PredictAttitude, as before', async () => {
  // A stand-in esgd of an older version: GetSession (the token check) and PredictAttitude only.
  const grpc = require('@grpc/grpc-js');
  const protoLoader = require('@grpc/proto-loader');
  const definition = protoLoader.loadSync('esg/v1/estimation_service.proto', {
    includeDirs: [path.join(REPO, 'proto')], keepCase: true, longs: Number, enums: String, defaults: true, arrays: true,
  });
  const service = grpc.loadPackageDefinition(definition).esg.v1.EstimationService.service;
  const response = {
    samples: [{ time: { seconds: 1551398400, nanos: 0 }, q_in_b: [1, 0, 0, 0], sigma_arcsec: [1, 2, 3], spin_axes: [] }],
    aem_text: '', attitude_source: 'ATTITUDE_SOURCE_INERTIAL_HOLD', recorded_samples: 0,
    last_applied_time: { seconds: 1551398000, nanos: 0 }, assumption: 'inertial hold after ...',
  };
  const server = new grpc.Server();
  server.addService({ GetSession: service.GetSession, PredictAttitude: service.PredictAttitude }, {
    GetSession: (call, callback) => callback({ code: grpc.status.INVALID_ARGUMENT, details: 'spacecraft_id: empty' }),
    PredictAttitude: (call, callback) => callback(null, response),
  });
  const port = await new Promise((resolve, reject) => server.bindAsync('127.0.0.1:0',
    grpc.ServerCredentials.createInsecure(), (err, p) => (err ? reject(err) : resolve(p))));
  const old = await startGateway(['--esgd', `127.0.0.1:${port}`]);
  try {
    const answer = await request(new URL('/api/spacecraft/OLD-1/predict?from=2019-03-01T00:00:00Z&to=2019-03-01T00:00:00Z&step_s=1',
      old.url));
    assert.equal(answer.status, 200, answer.text);
    const converter = new Esgd({ address: `127.0.0.1:${port}` });
    try {
      assert.equal(answer.text, JSON.stringify(converter.convert.toJson('esg.v1.PredictResponse', response)));
    } finally {
      converter.close();
    }
  } finally {
    await stop(old.child);
    server.forceShutdown();
  }
});
