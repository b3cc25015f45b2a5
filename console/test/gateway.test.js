// The console gateway against a real esgd on loopback (no mocks): a temp SQLite file, a tokens
// file with a read-write and a read-only operator, a 2 h simulated flight replayed with the esg
// CLI. Each REST answer is compared field by field with what the esg CLI prints for the same
// query; the WebSocket is driven through auth, replay, a live alert and unsubscribe; HTTPS and
// TLS to esgd use a certificate made here with openssl.
//   node --test console/test/gateway.test.js     (ESGD, ESG: the binaries; default build/)
'use strict';

const { test, before, after } = require('node:test');
const assert = require('node:assert/strict');
const crypto = require('node:crypto');
const fs = require('node:fs');
const os = require('node:os');
const path = require('node:path');
const { execFileSync } = require('node:child_process');
const WebSocket = require('ws');
const {
  REPO, startEsgd, startGateway, runGatewayExpectingFailure, stop, esg, request, EsgJson, Inbox,
} = require('./helpers');
const security = require('./security');

const CONFIG = path.join(REPO, 'deploy', 'examples', 'rdk1.json');
const SCENARIO = path.join(REPO, 'deploy', 'examples', 'scenarios', 'paper_calibration.json');

const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'esg-console-test-'));
const alice = `alice-${crypto.randomBytes(12).toString('hex')}`;
const bob = `bob-${crypto.randomBytes(12).toString('hex')}`;
const esgJson = new EsgJson();
let esgd;
let gateway;
let flight;
let conflict;

const asAlice = { Authorization: `Bearer ${alice}` };
const asBob = { Authorization: `Bearer ${bob}` };
const cli = (token, ...args) => esg(['--server', esgd.address, '--token', token, ...args]);
const api = (pathAndQuery, options = {}) => request(new URL(pathAndQuery, gateway.url), options);

// A one-row recording whose frame reuses sequence 1 of the flight with other content: esgd
// refuses it (ALREADY_EXISTS) and raises INGEST_CONFLICT, or repeats that alert while it is
// active. This is how the test makes an alert happen when it wants one.
function writeConflictRecording() {
  const lines = fs.readFileSync(flight, 'utf8').split('\n');
  const header = lines.filter((l) => l.startsWith('#'));
  const columns = lines.find((l) => l.startsWith('time_utc'));
  const first = lines[lines.indexOf(columns) + 1].split(',');
  const ux = columns.split(',').indexOf('g1_ux');
  first[ux] = String(Number(first[ux]) + 1);
  const file = path.join(tmp, 'conflict.csv');
  fs.writeFileSync(file, [...header, columns, first.join(','), ''].join('\n'));
  return file;
}

const raiseConflict = () => cli(alice, 'replay', '--recording', conflict, '--allow-rejects');

before(async () => {
  const tokens = path.join(tmp, 'tokens');
  fs.writeFileSync(tokens, `${alice} read,write alice\n${bob} read bob\n`, { mode: 0o600 });
  flight = path.join(tmp, 'flight.csv');
  await esg(['simulate', '--config', CONFIG, '--profile', 'calibration', '--scenario', SCENARIO,
    '--hours', '2', '--seed', '1', '--out', flight]);
  esgd = await startEsgd(['--db', path.join(tmp, 'esg.db'), '--tokens', tokens]);
  await cli(alice, 'configure', '--config', CONFIG, '--model', '10+11');
  await cli(alice, 'replay', '--recording', flight, '--wait');
  conflict = writeConflictRecording();
  await raiseConflict();
  gateway = await startGateway(['--esgd', esgd.address]);
});

after(async () => {
  if (gateway) await stop(gateway.child);
  if (esgd) await stop(esgd.child);
  fs.rmSync(tmp, { recursive: true, force: true });
});

test('bad flags end the gateway at once with a message naming the flag', async () => {
  const cases = [
    [[], '--esgd'],
    [['--esgd', 'nohost'], '--esgd'],
    [['--esgd', '127.0.0.1:1', '--listen', '127.0.0.1:99999'], '--listen'],
    [['--esgd', '127.0.0.1:1', '--tls-cert', CONFIG], '--tls-key'],
    [['--esgd', '127.0.0.1:1', '--esgd-ca', path.join(tmp, 'missing.pem')], '--esgd-ca'],
    [['--esgd', '127.0.0.1:1', '--esgd-server-name', 'x'], '--esgd-server-name'],
    [['--esgd', '127.0.0.1:1', '--colour'], '--colour'],
    [['--esgd', '127.0.0.1:1', '--allowed-hosts', 'evil example'], '--allowed-hosts'],
    [['--esgd', '127.0.0.1:1', '--allowed-hosts', '::1'], '--allowed-hosts'],
    [['--esgd', '127.0.0.1:1', '--allowed-hosts', 'localhost,,console.example'], '--allowed-hosts'],
    [['--esgd', '127.0.0.1:1', '--allowed-hosts', 'localhost:99999'], '--allowed-hosts'],
  ];
  for (const [args, flag] of cases) {
    const { code, stderr } = await runGatewayExpectingFailure(args);
    assert.notEqual(code, 0, `${args.join(' ')} exited 0`);
    assert.match(stderr.split('\n')[0], new RegExp(`^console gateway: ${flag}:`), args.join(' '));
  }
});

test('/api/auth says a token is needed, accepts a known one and refuses an unknown one (401), and tells a read-only token from a writer', async () => {
  assert.deepEqual((await api('/api/auth')).json, { auth_required: true });
  const ok = await api('/api/auth', { headers: asBob });
  assert.equal(ok.status, 200);
  // bob's token has the read role only, alice's also write (esgd answers the role, the gateway
  // asks it with a call esgd refuses before changing anything).
  assert.deepEqual(ok.json, { auth_required: true, ok: true, can_write: false });
  const writer = await api('/api/auth', { headers: asAlice });
  assert.equal(writer.status, 200);
  assert.deepEqual(writer.json, { auth_required: true, ok: true, can_write: true });
  const refused = await api('/api/auth', { headers: { Authorization: 'Bearer not-a-token' } });
  assert.equal(refused.status, 401);
  assert.equal(refused.json.error.code, 'UNAUTHENTICATED');
  assert.match(refused.json.error.message, /unknown token/);
});

test('/api/sessions equals esg status --json, every field', async () => {
  const answer = await api('/api/sessions', { headers: asBob });
  assert.equal(answer.status, 200);
  const expected = JSON.parse(await cli(bob, 'status', '--json'))
    .sessions.map((s) => esgJson.normalize('esg.v1.SessionInfo', s));
  assert.deepEqual(answer.json.sessions, expected);
  const [session] = answer.json.sessions;
  assert.equal(session.spacecraft_id, 'RDK-1');
  assert.equal(session.frames_accepted, 121);
  assert.match(session.state, /^SESSION_STATE_/);
  assert.equal(session.last_frame_time, '2019-03-01T02:00:00.000Z');
  assert.deepEqual(session.config.gyros[0].basis_terms, []);
});

test('/api/fleet counts open alerts by severity and gives the last star-tracker time', async () => {
  const answer = await api('/api/fleet', { headers: asBob });
  assert.equal(answer.status, 200);
  assert.equal(answer.json.fleet.length, 1);
  const [entry] = answer.json.fleet;
  assert.equal(entry.session.spacecraft_id, 'RDK-1');
  // The one open alert is the INGEST_CONFLICT raised in before(): WARNING.
  assert.deepEqual(entry.open_alerts, { INFO: 0, WARNING: 1, DISTRESS: 0, CRITICAL: 0 });
  // ... which is the worst active alert; no diagnosis has run yet (the diagnoses test is later).
  assert.equal(entry.worst_alert.reason, 'ALERT_REASON_INGEST_CONFLICT');
  assert.equal(entry.worst_alert.cleared, false);
  assert.equal(entry.last_diagnosis, null);
  const estimates = await api('/api/spacecraft/RDK-1/estimates', { headers: asBob });
  if (estimates.status === 501) {
    assert.equal(entry.last_star_tracker_time, null);
  } else {
    const last = estimates.json.estimates.at(-1);
    assert.equal(entry.last_star_tracker_time, last.last_star_tracker_time);
    assert.match(entry.last_star_tracker_time, /^2019-03-01T0[12]:\d\d:00\.000Z$/);
  }
});

test('/api/spacecraft/:id/history equals esg history --json, every field', async () => {
  const all = await api('/api/spacecraft/RDK-1/history', { headers: asBob });
  assert.equal(all.status, 200);
  const expected = JSON.parse(await cli(bob, 'history', '--spacecraft', 'RDK-1', '--json'))
    .snapshots.map((s) => esgJson.normalize('esg.v1.CoefficientSnapshot', s));
  assert.ok(expected.length > 100, `only ${expected.length} snapshots`);
  assert.deepEqual(all.json.snapshots, expected);

  const query = 'gyro=2&from=2019-03-01T01:00:00Z&to=2019-03-01T01:30:00.000Z';
  const some = await api(`/api/spacecraft/RDK-1/history?${query}`, { headers: asBob });
  const expectedSome = JSON.parse(await cli(bob, 'history', '--spacecraft', 'RDK-1', '--gyro', '2',
    '--from', '2019-03-01T01:00:00Z', '--to', '2019-03-01T01:30:00Z', '--json'))
    .snapshots.map((s) => esgJson.normalize('esg.v1.CoefficientSnapshot', s));
  assert.ok(expectedSome.length > 0 && expectedSome.length < expected.length);
  assert.ok(expectedSome.every((s) => s.gyro_id === 2));
  assert.deepEqual(some.json.snapshots, expectedSome);
});

test('alert lists equal esg alerts --json', async () => {
  const expected = JSON.parse(await cli(bob, 'alerts', '--json'))
    .alerts.map((a) => esgJson.normalize('esg.v1.Alert', a));
  assert.equal(expected.length, 1);
  const all = await api('/api/alerts', { headers: asBob });
  assert.equal(all.status, 200);
  assert.deepEqual(all.json.alerts, expected);
  const one = await api('/api/spacecraft/RDK-1/alerts?since=2019-03-01T00:00:00Z', { headers: asBob });
  assert.deepEqual(one.json.alerts, expected);
  assert.equal(one.json.alerts[0].reason, 'ALERT_REASON_INGEST_CONFLICT');
  assert.equal(one.json.alerts[0].severity, 'ALERT_SEVERITY_WARNING');
  // `since` after the alert's latest occurrence: nothing stored is that recent.
  const later = await api('/api/alerts?since=2019-03-01T00:00:01Z', { headers: asBob });
  assert.deepEqual(later.json.alerts, []);
});

test('acknowledge: read-only token 403; empty operator_name is the token\'s name', async () => {
  const refused = await api('/api/spacecraft/RDK-1/alerts/1/acknowledge',
    { method: 'POST', headers: asBob, body: { operator_name: '' } });
  assert.equal(refused.status, 403);
  assert.equal(refused.json.error.code, 'PERMISSION_DENIED');
  assert.match(refused.json.error.message, /write/);

  const acked = await api('/api/spacecraft/RDK-1/alerts/1/acknowledge',
    { method: 'POST', headers: asAlice, body: { operator_name: '' } });
  assert.equal(acked.status, 200);
  assert.equal(acked.json.sequence, 1);
  assert.equal(acked.json.acknowledged, true);
  assert.equal(acked.json.acknowledged_by, 'alice');
  assert.match(acked.json.acknowledged_time, /^\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d\.\d{3}Z$/);

  const [stored] = JSON.parse(await cli(bob, 'alerts', '--spacecraft', 'RDK-1', '--json')).alerts;
  assert.equal(stored.acknowledged, true);
  assert.equal(stored.acknowledgedBy, 'alice');
  assert.deepEqual(esgJson.normalize('esg.v1.Alert', stored), acked.json);

  // Alice's token acknowledging in another operator's name is refused by esgd: 403 with its
  // message (with tokens the name is the token's own), and the stored acknowledgement stands.
  const other = await api('/api/spacecraft/RDK-1/alerts/1/acknowledge',
    { method: 'POST', headers: asAlice, body: { operator_name: 'carol' } });
  assert.equal(other.status, 403);
  assert.equal(other.json.error.code, 'PERMISSION_DENIED');
  assert.match(other.json.error.message, /operator_name: 'carol' is not the caller's name 'alice'/);
  const [after] = JSON.parse(await cli(bob, 'alerts', '--spacecraft', 'RDK-1', '--json')).alerts;
  assert.equal(after.acknowledgedBy, 'alice');
});

test('errors: unknown spacecraft 404 with esgd\'s message; bad parameters 400 naming them', async () => {
  const unknown = await api('/api/spacecraft/NOPE/history', { headers: asBob });
  assert.equal(unknown.status, 404);
  assert.deepEqual(unknown.json, { error: { code: 'NOT_FOUND', message: "spacecraft_id: 'NOPE' is not configured" } });

  const bad = [
    ['/api/spacecraft/RDK-1/history?from=yesterday', 'from'],
    ['/api/spacecraft/RDK-1/history?to=2019-02-30T00:00:00Z', 'to'],
    ['/api/spacecraft/RDK-1/history?gyro=7', 'gyro'],
    ['/api/spacecraft/RDK-1/history?include_revised=maybe', 'include_revised'],
    ['/api/alerts?since=2019-03-01', null],
    ['/api/spacecraft/RDK-1/alerts?since=03/01/2019', 'since'],
    ['/api/spacecraft/RDK-1/predict?from=2019-03-01T02:10:00Z&to=2019-03-01T03:00:00Z&step_s=fast', 'step_s'],
  ];
  for (const [url, name] of bad) {
    const answer = await api(url, { headers: asBob });
    if (name === null) {
      assert.equal(answer.status, 200, `${url}: a date alone is a valid time`);
      continue;
    }
    assert.equal(answer.status, 400, url);
    assert.equal(answer.json.error.code, 'INVALID_ARGUMENT');
    assert.ok(answer.json.error.message.startsWith(`${name}:`), `${url}: ${answer.json.error.message}`);
  }
  const posts = [
    ['/api/spacecraft/RDK-1/alerts/first/acknowledge', { operator_name: '' }, 'sequence'],
    ['/api/spacecraft/RDK-1/alerts/0/acknowledge', { operator_name: '' }, 'sequence'],
    ['/api/spacecraft/RDK-1/alerts/1/acknowledge', undefined, 'body'],
    ['/api/spacecraft/RDK-1/alerts/1/acknowledge', '{"operator_name": ', 'body'],
    ['/api/spacecraft/RDK-1/alerts/1/acknowledge', { operator_name: 3 }, 'body.operator_name'],
    ['/api/spacecraft/RDK-1/predict', undefined, 'body'],
    ['/api/spacecraft/RDK-1/predict', { from: 'soon' }, 'body.from'],
    ['/api/spacecraft/RDK-1/predict', { step: 60 }, 'body.step'],
    ['/api/spacecraft/RDK-1/predict', { planned_attitude: [{ time: 'x', q_in_b: [1, 0, 0, 0] }] },
      'body.planned_attitude[0].time'],
  ];
  for (const [url, body, name] of posts) {
    const answer = await api(url, { method: 'POST', headers: asAlice, body });
    assert.equal(answer.status, 400, `${url} ${JSON.stringify(body)}`);
    assert.ok(answer.json.error.message.startsWith(`${name}:`), answer.json.error.message);
  }
  // esgd's own INVALID_ARGUMENT (it names its field) and OUT_OF_RANGE are 400 too.
  const step = await api('/api/spacecraft/RDK-1/predict?from=2019-03-01T02:10:00Z&to=2019-03-01T03:00:00Z&step_s=0',
    { headers: asBob });
  assert.equal(step.status, 400);
  assert.match(step.json.error.message, /^step_s:/);
  const far = await api('/api/spacecraft/RDK-1/predict?from=2019-03-10T00:00:00Z&to=2019-03-10T01:00:00Z&step_s=600',
    { headers: asBob });
  assert.equal(far.status, 400);
  assert.equal(far.json.error.code, 'OUT_OF_RANGE');

  // A body that does not say it is JSON (what another site's form could post): 415, nothing done.
  const form = await api('/api/spacecraft/RDK-1/alerts/1/acknowledge', { method: 'POST',
    headers: { ...asAlice, 'Content-Type': 'text/plain' }, body: { operator_name: 'mallory' } });
  assert.equal(form.status, 415);
  assert.match(form.json.error.message, /^Content-Type:/);

  const endpoint = await api('/api/nothing-here', { headers: asBob });
  assert.equal(endpoint.status, 404);
  const method = await api('/api/sessions', { method: 'DELETE', headers: asBob });
  assert.equal(method.status, 405);
  // The gateway is still serving after all of that.
  assert.equal((await api('/api/sessions', { headers: asBob })).status, 200);
});

test('predict: GET equals esg predict --json; POST takes a planned attitude', async () => {
  const from = '2019-03-01T01:30:00Z';
  const to = '2019-03-01T03:00:00Z';
  const got = await api(`/api/spacecraft/RDK-1/predict?from=${from}&to=${to}&step_s=900`, { headers: asBob });
  assert.equal(got.status, 200);
  const expected = esgJson.normalize('esg.v1.PredictResponse', JSON.parse(
    await cli(bob, 'predict', '--spacecraft', 'RDK-1', '--from', from, '--to', to, '--step', '900', '--json')));
  assert.deepEqual(got.json, expected);
  assert.equal(got.json.samples.length, 7);
  assert.equal(got.json.recorded_samples, 3);
  assert.equal(got.json.attitude_source, 'ATTITUDE_SOURCE_INERTIAL_HOLD');

  const q = got.json.samples.at(-1).q_in_b;
  const posted = await api('/api/spacecraft/RDK-1/predict', {
    method: 'POST', headers: asBob,
    body: { from, to, step_s: 900, planned_attitude: [{ time: '2019-03-01T02:30:00Z', q_in_b: q }] },
  });
  assert.equal(posted.status, 200, posted.text);
  assert.equal(posted.json.samples.length, 7);
  assert.equal(posted.json.attitude_source, 'ATTITUDE_SOURCE_PLANNED');
  assert.equal(posted.json.samples[6].time, '2019-03-01T03:00:00.000Z');
});

test('diagnoses: list and report equal esg diagnoses list/show --json', async () => {
  await cli(bob, 'diagnose', '--spacecraft', 'RDK-1', '--effects', 'none', '--json');
  const list = await api('/api/spacecraft/RDK-1/diagnoses', { headers: asBob });
  // The fleet gives the newest one.
  const fleet = await api('/api/fleet', { headers: asBob });
  assert.deepEqual(fleet.json.fleet[0].last_diagnosis, list.json.diagnoses.at(-1));
  assert.equal(list.status, 200);
  const expected = JSON.parse(await cli(bob, 'diagnoses', 'list', '--spacecraft', 'RDK-1', '--json'))
    .diagnoses.map((d) => esgJson.normalize('esg.v1.DiagnosisResult', d));
  assert.equal(expected.length, 1);
  // Summaries: report_json is empty (esg leaves it out of its list).
  assert.ok(list.json.diagnoses.every((d) => d.report_json === ''));
  const summaries = list.json.diagnoses.map(({ report_json: _, ...rest }) => rest);
  assert.deepEqual(summaries, expected);
  const id = expected[0].id;
  const one = await api(`/api/spacecraft/RDK-1/diagnoses/${id}`, { headers: asBob });
  assert.equal(one.status, 200);
  const { report, ...shown } = JSON.parse(await cli(bob, 'diagnoses', 'show', '--spacecraft', 'RDK-1',
    '--id', String(id), '--json'));
  assert.deepEqual(one.json, { ...esgJson.normalize('esg.v1.DiagnosisResult', shown), report });
  assert.ok(!('report_json' in one.json));
  const missing = await api(`/api/spacecraft/RDK-1/diagnoses/${id + 100}`, { headers: asBob });
  assert.equal(missing.status, 404);
  assert.match(missing.json.error.message, /^id:/);
});

test('estimates: 501 from an esgd without the RPC, else the stored per-step estimates', async () => {
  const answer = await api('/api/spacecraft/RDK-1/estimates', { headers: asBob });
  if (answer.status === 501) {
    assert.equal(answer.json.error.code, 'UNIMPLEMENTED');
    assert.match(answer.json.error.message, /GetEstimateHistory/);
    return;
  }
  assert.equal(answer.status, 200, answer.text);
  const { estimates } = answer.json;
  // One per measurement step (60 s) of the 2 h flight, the last at the last frame.
  assert.ok(estimates.length >= 100 && estimates.length <= 121, `${estimates.length} estimates`);
  assert.equal(estimates.at(-1).measurement_time, '2019-03-01T02:00:00.000Z');
  for (let i = 0; i < estimates.length; i++) {
    assert.equal(estimates[i].spacecraft_id, 'RDK-1');
    assert.match(estimates[i].state, /^SESSION_STATE_/);
    assert.ok(Array.isArray(estimates[i].output_pair) && Array.isArray(estimates[i].star_tracker_innovations));
    if (i > 0) assert.ok(estimates[i].measurement_time > estimates[i - 1].measurement_time);
    // The attitude error estimate about body x, y, z with its 1-sigma: at every step that applied
    // the star tracker to a valid output, at no other.
    const withError = estimates[i].star_tracker_used && estimates[i].attitude !== undefined;
    assert.equal(estimates[i].attitude_error_b_arcsec.length, withError ? 3 : 0, estimates[i].measurement_time);
    assert.equal(estimates[i].attitude_error_sigma_b_arcsec.length, withError ? 3 : 0);
  }
  assert.ok(estimates.some((e) => e.attitude_error_b_arcsec.length === 3), 'some steps carry an estimate');
  const span = await api('/api/spacecraft/RDK-1/estimates?from=2019-03-01T01:00:00Z&to=2019-03-01T01:10:00Z',
    { headers: asBob });
  assert.deepEqual(span.json.estimates, estimates.filter((e) =>
    e.measurement_time >= '2019-03-01T01:00:00.000Z' && e.measurement_time <= '2019-03-01T01:10:00.000Z'));
});

function openSocket(url, options) {
  const ws = new WebSocket(new URL('/api/live', url.replace(/^http/, 'ws')), options);
  const inbox = new Inbox(ws);
  return new Promise((resolve, reject) => {
    ws.once('open', () => resolve({ ws, inbox }));
    ws.once('error', reject);
  });
}

test('WebSocket: auth, stored alerts, replay_complete, a live alert, unsubscribe', async () => {
  const { ws, inbox } = await openSocket(gateway.url);
  try {
    ws.send(JSON.stringify({ type: 'auth', token: bob }));
    assert.deepEqual(await inbox.take(() => true), { type: 'ready' });

    const stored = JSON.parse(await cli(bob, 'alerts', '--json')).alerts
      .map((a) => esgJson.normalize('esg.v1.Alert', a));
    ws.send(JSON.stringify({ type: 'subscribe', id: 'a', stream: 'alerts', spacecraft_id: 'RDK-1',
      since: '2019-03-01T00:00:00Z' }));
    const replayed = await inbox.take((m) => m.id === 'a');
    assert.deepEqual(replayed, { type: 'alert', id: 'a', alert: stored[0] });
    assert.deepEqual(await inbox.take((m) => m.id === 'a'), { type: 'replay_complete', id: 'a' });

    // Live: another conflicting frame repeats the active INGEST_CONFLICT alert.
    await raiseConflict();
    const live = await inbox.take((m) => m.id === 'a');
    assert.equal(live.type, 'alert');
    assert.equal(live.alert.sequence, stored[0].sequence);
    assert.equal(live.alert.repeat_count, stored[0].repeat_count + 1);

    // A second subscription without `since`: the marker at once, then live alerts only.
    ws.send(JSON.stringify({ type: 'subscribe', id: 'b', stream: 'alerts', spacecraft_id: '', since: null }));
    assert.deepEqual(await inbox.take((m) => m.id === 'b'), { type: 'replay_complete', id: 'b' });
    ws.send(JSON.stringify({ type: 'subscribe', id: 'b', stream: 'alerts' }));
    const duplicate = await inbox.take((m) => m.id === 'b');
    assert.equal(duplicate.type, 'error');
    assert.match(duplicate.error.message, /^id:/);

    ws.send(JSON.stringify({ type: 'unsubscribe', id: 'a' }));
    // The gateway handles a socket's messages in order: once an unsubscribe of an unknown id is
    // answered, 'a' is cancelled.
    ws.send(JSON.stringify({ type: 'unsubscribe', id: 'a' }));
    assert.equal((await inbox.take((m) => m.id === 'a')).error.code, 'NOT_FOUND');
    await raiseConflict();
    const toB = await inbox.take((m) => m.id === 'b');
    assert.equal(toB.alert.repeat_count, stored[0].repeat_count + 2);
    // 'a' was cancelled: give any stray message time to arrive, then check there was none.
    await new Promise((r) => setTimeout(r, 300));
    assert.deepEqual(inbox.messages.filter((m) => m.id === 'a'), []);

    // Estimates: every message of the subscription up to the first that is not an estimate.
    ws.send(JSON.stringify({ type: 'subscribe', id: 'e', stream: 'estimates', spacecraft_id: 'RDK-1',
      since: '2019-03-01T01:50:00Z' }));
    const estimates = [];
    do {
      estimates.push(await inbox.take((m) => m.id === 'e'));
    } while (estimates.at(-1).type === 'estimate');
    const last = estimates.at(-1);
    if (last.type === 'error') {
      assert.equal(last.error.code, 'UNIMPLEMENTED');
      assert.equal(estimates.length, 1);
    } else {
      assert.equal(last.type, 'replay_complete');
      assert.equal(estimates.length - 1, 11, 'steps 01:50..02:00');
      assert.equal(estimates.at(-2).estimate.measurement_time, '2019-03-01T02:00:00.000Z');
    }

    const bad = [
      [{ type: 'subscribe', id: 'x', stream: 'weather' }, /^stream:/],
      [{ type: 'subscribe', id: 'y', stream: 'alerts', since: 'noon' }, /^since:/],
      [{ type: 'unsubscribe', id: 'zz' }, /^id:/],
    ];
    for (const [message, pattern] of bad) {
      ws.send(JSON.stringify(message));
      const answer = await inbox.take((m) => m.id === message.id);
      assert.equal(answer.type, 'error');
      assert.match(answer.error.message, pattern);
    }
  } finally {
    ws.close();
  }
});

test('WebSocket: an unknown token is refused and the socket closed', async () => {
  const { ws, inbox } = await openSocket(gateway.url);
  ws.send(JSON.stringify({ type: 'auth', token: 'not-a-token' }));
  const error = await inbox.take(() => true);
  assert.equal(error.type, 'error');
  assert.equal(error.error.code, 'UNAUTHENTICATED');
  assert.equal((await inbox.whenClosed()).code, 4401);

  // A page of another site (its Origin) cannot open the socket at all.
  await assert.rejects(openSocket(gateway.url, { origin: 'http://evil.example' }), /403/);
  const own = await openSocket(gateway.url, { origin: gateway.url.replace(/\/$/, '') });
  own.ws.close();

  const second = await openSocket(gateway.url);
  second.ws.send(JSON.stringify({ type: 'subscribe', id: 'a', stream: 'alerts' }));
  assert.equal((await second.inbox.take(() => true)).error.code, 'UNAUTHENTICATED');
  assert.equal((await second.inbox.whenClosed()).code, 4401);
});

test('static files: Open MCT, the page, and nothing outside the console', async () => {
  const openmct = await api('/openmct/openmct.js');
  assert.equal(openmct.status, 200);
  assert.match(openmct.headers['content-type'], /^text\/javascript/);
  const file = path.join(REPO, 'console', 'node_modules', 'openmct', 'dist', 'openmct.js');
  assert.ok(openmct.buffer.equals(fs.readFileSync(file)));

  const index = path.join(REPO, 'console', 'public', 'index.html');
  const page = await api('/');
  if (fs.existsSync(index)) {
    assert.equal(page.status, 200);
    assert.match(page.headers['content-type'], /^text\/html/);
    assert.equal(page.text, fs.readFileSync(index, 'utf8'));
  } else {
    assert.equal(page.status, 404);
  }
  for (const escape of ['/plugin/../../package.json', '/openmct/..%2f..%2f..%2fpackage.json',
    '/..%2fgateway%2fmain.js', '/plugin/%2e%2e/gateway/main.js']) {
    const answer = await request(`${gateway.url.replace(/\/$/, '')}${escape}`);
    assert.equal(answer.status, 404, escape);
  }
});

test('HTTPS to the browser and TLS to esgd checked against --esgd-ca and --esgd-server-name', async () => {
  const key = path.join(tmp, 'key.pem');
  const cert = path.join(tmp, 'cert.pem');
  // The certificate names "localhost" only: reaching 127.0.0.1 needs --esgd-server-name.
  execFileSync('openssl', ['req', '-x509', '-newkey', 'rsa:2048', '-nodes', '-keyout', key,
    '-out', cert, '-days', '1', '-subj', '/CN=localhost', '-addext', 'subjectAltName=DNS:localhost'],
  { stdio: 'ignore' });
  const tlsEsgd = await startEsgd(['--db', path.join(tmp, 'tls.db'), '--tls-cert', cert, '--tls-key', key]);
  const gateways = [];
  try {
    const secure = await startGateway(['--esgd', tlsEsgd.address, '--esgd-ca', cert,
      '--esgd-server-name', 'localhost', '--tls-cert', cert, '--tls-key', key]);
    gateways.push(secure);
    assert.match(secure.url, /^https:\/\/127\.0\.0\.1:\d+\/$/);
    const tls = { ca: fs.readFileSync(cert), servername: 'localhost' };
    const auth = await request(new URL('/api/auth', secure.url), { ca: tls.ca, servername: 'localhost' });
    assert.equal(auth.status, 200);
    // This esgd runs without tokens.
    assert.deepEqual(auth.json, { auth_required: false });
    const sessions = await request(new URL('/api/sessions', secure.url), { ca: tls.ca, servername: 'localhost' });
    assert.deepEqual(sessions.json, { sessions: [] });

    const { ws, inbox } = await openSocket(secure.url, tls);
    ws.send(JSON.stringify({ type: 'auth', token: '' }));
    assert.deepEqual(await inbox.take(() => true), { type: 'ready' });
    ws.close();

    // Plain text to a TLS esgd, or a certificate that does not name the address: 503.
    for (const args of [[], ['--esgd-ca', cert]]) {
      const wrong = await startGateway(['--esgd', tlsEsgd.address, ...args]);
      gateways.push(wrong);
      const refused = await request(new URL('/api/sessions', wrong.url));
      assert.equal(refused.status, 503, args.join(' '));
      assert.equal(refused.json.error.code, 'UNAVAILABLE');
    }
  } finally {
    for (const g of gateways) await stop(g.child);
    await stop(tlsEsgd.child);
  }
});

security.register({ esgd: () => esgd, gateway: () => gateway, alice, bob, tmp });

test('the gateway\'s log has every request and socket, and never a token', () => {
  const log = gateway.stderr();
  assert.match(log, /GET \/api\/sessions 200 \d+ ms/);
  assert.match(log, /POST \/api\/spacecraft\/RDK-1\/alerts\/1\/acknowledge 403 \d+ ms/);
  assert.match(log, /live: 127\.0\.0\.1:\d+ signed in/);
  assert.match(log, /live: 127\.0\.0\.1:\d+ refused: UNAUTHENTICATED/);
  for (const token of [alice, bob, 'not-a-token']) assert.ok(!log.includes(token), 'a token in the log');
});

test('SIGTERM: open subscriptions are closed (1001) and the gateway exits 0 at once', async () => {
  const own = await startGateway(['--esgd', esgd.address]);
  const { ws, inbox } = await openSocket(own.url);
  ws.send(JSON.stringify({ type: 'auth', token: bob }));
  await inbox.take((m) => m.type === 'ready');
  ws.send(JSON.stringify({ type: 'subscribe', id: 'a', stream: 'alerts', since: null }));
  await inbox.take((m) => m.type === 'replay_complete');
  const started = Date.now();
  const exit = await stop(own.child);
  assert.deepEqual(exit, { code: 0, signal: null });
  assert.ok(Date.now() - started < 3000, `took ${Date.now() - started} ms`);
  assert.equal((await inbox.whenClosed()).code, 1001);
});
