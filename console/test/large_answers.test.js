// Large answers of the gateway (docs/console-gateway.md "Large answers", issue 40) against a real
// esgd and the real gateway on loopback: a 10-day flight (43 200 coefficient snapshots, about
// 60 MB of history JSON, 14 400 per-step estimates, about 17 MB). The history and the estimate
// list are streamed a page at a time and capped per request with a next_page_token; each
// operator runs at most 4 large answers, 32 more wait, further ones are refused 429; the
// gateway's resident set (/proc/PID/status VmRSS) stays flat while four full histories, or
// estimate lists, are read in parallel and while four paused readers hold theirs.
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

const CONFIG = path.join(REPO, 'deploy', 'examples', 'rdk1.json');
const SCENARIO = path.join(REPO, 'deploy', 'examples', 'scenarios', 'paper_calibration.json');
const HOURS = 240;
const SNAPSHOTS = HOURS * 60 * 3; // a snapshot per gyro per minute (3 gyros)

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
    const req = http.get(new URL(pathAndQuery, gateway.url), { headers }, (res) => {
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
  gateway = await startGateway(['--esgd', esgd.address]);
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
  // at a time they hold a few pages, and what grows is garbage V8 has not collected yet
  // (measured: 62 to 207 MiB).
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
  // 385 MiB; streamed a page at a time, from 62 to 223 MiB (what grows is garbage V8 has not
  // collected yet).
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
