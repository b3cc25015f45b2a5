// The Open MCT console in a real browser (Debian chromium through puppeteer-core) against a real
// esgd and the real gateway, no mocks: esgd with a tokens file on a temp SQLite file; RDK-1 fed
// with the demo's simulated flight (scripts/demo.sh: the paper's calibration profile, 30 h,
// seed 1) and RDK-F with a faulty recording (deploy/examples/scenarios/gyro_faults.json, 10 h:
// a gyro 1 readout jump and a gyro 3 drift step), both replayed with `esg replay`; RDK-F
// diagnosed with `esg diagnose`. What the page shows, read from its DOM, is compared with what
// the esg CLI prints from the same server.
//   node --test console/test/browser.test.js
// Environment: ESGD, ESG (default build/), CHROMIUM (default /usr/bin/chromium),
// ESG_CONSOLE_SCREENSHOTS=1 to write docs/console/*.png (off in CI: they are tracked files).
'use strict';

const { test, before, after } = require('node:test');
const assert = require('node:assert/strict');
const crypto = require('node:crypto');
const fs = require('node:fs');
const os = require('node:os');
const path = require('node:path');
const puppeteer = require('puppeteer-core');
const { REPO, startEsgd, startGateway, stop, esg, request } = require('./helpers');

const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
const SCREENSHOTS = process.env.ESG_CONSOLE_SCREENSHOTS === '1';
const SHOT_DIR = path.join(REPO, 'docs', 'console');
const CONFIG = path.join(REPO, 'deploy', 'examples', 'rdk1.json');
const SCENARIOS = path.join(REPO, 'deploy', 'examples', 'scenarios');
// The demo flight in full: simulating and replaying 30 h takes about 2 s (measured), so CI runs
// the same flight as scripts/demo.sh.
const DEMO_HOURS = 30;
const FAULT_HOURS = 10;
const FAULTY = 'RDK-F';
const OPERATOR = 'ana.lopez';

const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'esg-console-browser-'));
const token = `ops-${crypto.randomBytes(16).toString('hex')}`;
const viewerToken = `view-${crypto.randomBytes(16).toString('hex')}`;
let esgd;
let gateway;
let browser;
let page;
let diagnosisId;
let faulty;
let faultyConfig;

const cli = (...args) => esg(['--server', esgd.address, '--token', token, ...args]);
const cliJson = async (...args) => JSON.parse(await cli(...args, '--json'));
const api = (p) => request(new URL(p, gateway.url), { headers: { Authorization: `Bearer ${token}` } });
const sleep = (ms) => new Promise((r) => setTimeout(r, ms));
// A drift coefficient of a GyroDriftModel in esg's JSON, by its term's key (docs/formats.md: every
// coefficient keyed); 0 when the model does not hold it.
const coef = (m, term) => (((m || {}).coefficients || []).find((c) => c.term === term) || { valueDegH: 0 }).valueDegH;

async function timed(label, fn) {
  const t0 = Date.now();
  const result = await fn();
  process.stdout.write(`# ${label}: ${((Date.now() - t0) / 1000).toFixed(1)} s\n`);
  return result;
}

// Open an object of the console by its Open MCT path (the part after #/browse/).
// Navigates by the URL's hash. Open MCT writes the time conductor's state into the hash after a
// change of bounds, with the path it showed then, so a navigation made in between can be
// overwritten: the page stays on the view before, and a table opened so never asks for its data
// (seen as "0 rows of 10" under load). The hash is set again until it holds the path asked for
// 250 ms after being set.
async function open(browsePath, query = '') {
  const target = `#/browse/${browsePath}`;
  for (let attempt = 0; attempt < 20; attempt++) {
    await page.evaluate((hash) => { window.location.hash = hash; }, `${target}${query}`);
    await sleep(250);
    if ((await page.evaluate(() => window.location.hash)).split('?')[0] === target) return;
  }
  throw new Error(`the page did not stay on ${target}: it shows ${await page.evaluate(() => window.location.hash)}`);
}

// height: a taller window for a long view (the diagnosis report scrolls inside Open MCT's pane,
// so a full-page capture would not show more).
// width: 1600 for the views that must fit an engineer's 1600x900 screen.
async function shot(name, height = 900, width = 1500) {
  if (!SCREENSHOTS) return;
  fs.mkdirSync(SHOT_DIR, { recursive: true });
  const resized = height !== 900 || width !== 1500;
  if (resized) await page.setViewport({ width, height });
  await page.mouse.move(1, 880); // no hover toolbar or tooltip over the plot
  await sleep(1500); // plots draw on the next animation frames
  await page.screenshot({ path: path.join(SHOT_DIR, `${name}.png`) });
  if (resized) await page.setViewport({ width: 1500, height: 900 });
}

// The rows of the Open MCT telemetry table on screen, as {column title: cell text}.
async function tableRows() {
  return page.evaluate(() => {
    const titles = [...document.querySelectorAll('.c-telemetry-table__headers__labels th')]
      .map((th) => th.textContent.trim());
    return [...document.querySelectorAll('.c-telemetry-table__body tr.noselect')].map((tr) => {
      const cells = [...tr.querySelectorAll('td')].map((td) => td.textContent.trim());
      return Object.fromEntries(titles.map((t, i) => [t, cells[i]]));
    });
  });
}

// A table's rows come from an answer that waits behind the operator's earlier large answers
// (the views opened before it: 4 run at a time per operator), so it is given 60 s; once the CI
// machine took more than 20 s. A timeout says what the table had and what the page said.
async function waitForTableRows(min = 1) {
  try {
    await page.waitForFunction((n) =>
      document.querySelectorAll('.c-telemetry-table__body tr.noselect').length >= n,
    { timeout: 60_000 }, min);
  } catch (err) {
    const seen = await page.evaluate(() => ({
      rows: document.querySelectorAll('.c-telemetry-table__body tr.noselect').length,
      bounds: window.openmct.time.bounds(),
      notices: [...document.querySelectorAll('.c-message, .esg-unavailable')].map((e) => e.textContent.trim()),
    }));
    throw new Error(`${err.message}: ${seen.rows} rows of ${min} (bounds ${new Date(seen.bounds.start).toISOString()}` +
      ` to ${new Date(seen.bounds.end).toISOString()}; notices: ${JSON.stringify(seen.notices)})` +
      `\n${apiRequestsReport()}`);
  }
  return tableRows();
}

// The page's requests to the gateway's API, each with its outcome, and the gateway's log: what a
// timed-out wait prints, so that a view left without data says which answer it lacked.
const apiRequests = new Map(); // puppeteer request -> {url, started, outcome}
function watchApiRequests() {
  const isApi = (r) => new URL(r.url()).pathname.startsWith('/api/');
  page.on('request', (r) => {
    if (isApi(r)) apiRequests.set(r, { url: r.url(), started: Date.now(), outcome: 'pending' });
  });
  page.on('requestfinished', (r) => {
    const e = apiRequests.get(r);
    if (e) e.outcome = `${r.response() ? r.response().status() : 'no response'} after ${Date.now() - e.started} ms`;
  });
  page.on('requestfailed', (r) => {
    const e = apiRequests.get(r);
    if (e) e.outcome = `failed (${(r.failure() || {}).errorText}) after ${Date.now() - e.started} ms`;
  });
}
function apiRequestsReport() {
  const now = Date.now();
  const lines = [...apiRequests.values()].slice(-40).map((e) =>
    `  ${e.outcome === 'pending' ? `pending for ${now - e.started} ms` : e.outcome}: ${e.url}`);
  const log = gateway.stderr().split('\n').slice(-40).map((l) => `  | ${l}`);
  return `the page's last API requests:\n${lines.join('\n')}\nthe gateway's log (last lines):\n${log.join('\n')}`;
}

// Open MCT's utc format: "2019-03-02 06:00:00.000Z".
const cellTime = (text) => Date.parse(text.replace(' ', 'T'));

before(async () => {
  const tokens = path.join(tmp, 'tokens');
  fs.writeFileSync(tokens, `${token} read,write ${OPERATOR}\n${viewerToken} read viewer\n`, { mode: 0o600 });
  const flight = path.join(tmp, 'flight.csv');
  faulty = path.join(tmp, 'faulty.csv');
  faultyConfig = path.join(tmp, 'rdkf.json');
  fs.writeFileSync(faultyConfig, fs.readFileSync(CONFIG, 'utf8')
    .replace('"spacecraftId": "RDK-1"', `"spacecraftId": "${FAULTY}"`));
  await timed(`simulate ${DEMO_HOURS} h demo flight and ${FAULT_HOURS} h faulty flight`, async () => {
    await esg(['simulate', '--config', CONFIG, '--profile', 'calibration', '--scenario',
      path.join(SCENARIOS, 'paper_calibration.json'), '--hours', String(DEMO_HOURS), '--seed', '1',
      '--out', flight]);
    await esg(['simulate', '--config', faultyConfig, '--profile', 'calibration', '--scenario',
      path.join(SCENARIOS, 'gyro_faults.json'), '--hours', String(FAULT_HOURS), '--seed', '1',
      '--out', faulty]);
  });
  esgd = await startEsgd(['--db', path.join(tmp, 'esg.db'), '--tokens', tokens, '--sync', 'normal']);
  await timed('configure and replay both (esg replay --wait)', async () => {
    await cli('configure', '--config', CONFIG, '--model', '10+11');
    await cli('configure', '--config', faultyConfig, '--model', '10+11');
    await cli('replay', '--recording', flight, '--wait');
    await cli('replay', '--recording', faulty, '--wait');
  });
  const diagnosis = await timed(`esg diagnose --spacecraft ${FAULTY}`,
    () => cliJson('diagnose', '--spacecraft', FAULTY));
  diagnosisId = Number(diagnosis.id);
  gateway = await startGateway(['--esgd', esgd.address]);
  browser = await puppeteer.launch({
    executablePath: CHROMIUM,
    headless: true,
    args: process.getuid && process.getuid() === 0 ? ['--no-sandbox'] : [],
  });
  page = await browser.newPage();
  await page.setViewport({ width: 1500, height: 900 });
  page.on('pageerror', (err) => process.stdout.write(`# page error: ${err.message}\n`));
  watchApiRequests();
});

after(async () => {
  if (browser) await browser.close();
  if (gateway) await stop(gateway.child);
  if (esgd) await stop(esgd.child);
  fs.rmSync(tmp, { recursive: true, force: true });
});

test('sign-in: esgd wants a token, a wrong one is refused, the operator token opens the console', async () => {
  await page.goto(gateway.url, { waitUntil: 'domcontentloaded' });
  await page.waitForSelector('#esg-signin:not([hidden])', { timeout: 20_000 });
  await page.type('#esg-token', 'not-a-token');
  await page.click('#esg-signin-submit');
  await page.waitForFunction(() => /refused/.test(document.getElementById('esg-signin-message').textContent));
  await page.$eval('#esg-token', (input) => { input.value = ''; });
  await page.type('#esg-token', token);
  await page.click('#esg-signin-submit');
  await page.waitForSelector('.l-shell', { timeout: 20_000 });
  assert.equal(await page.$eval('#esg-signin', (f) => f.hidden), true);
  assert.equal(await page.evaluate(() => sessionStorage.getItem('esg.token')), token);
});

// The fleet's rows as the page shows them, top to bottom, read from their cells' data attributes
// and texts.
async function fleetRows(tab = page) {
  return tab.$$eval('tr[data-spacecraft]', (trs) => trs.map((tr) => {
    const cell = (attr) => tr.querySelector(`td[${attr}]`);
    return {
      id: tr.dataset.spacecraft,
      attention: tr.dataset.attention,
      state: cell('data-state').dataset.state,
      stateText: cell('data-state').textContent.trim(),
      health: cell('data-health').dataset.health,
      healthText: cell('data-health').textContent.trim(),
      excluded: [...tr.querySelectorAll('[data-excluded-gyro]')].map((s) => ({ gyro: Number(s.dataset.excludedGyro), reason: s.dataset.reason })),
      sigma: cell('data-sigma').dataset.sigma,
      sigmaText: cell('data-sigma').textContent.trim(),
      model: cell('data-model').dataset.model,
      widened: cell('data-model').dataset.widened,
      modelText: cell('data-model').textContent.trim(),
      worstAlert: cell('data-worst-alert').dataset.worstAlert,
      worstSeverity: cell('data-worst-alert').dataset.alertSeverity || '',
      alertText: cell('data-worst-alert').textContent.trim(),
      counts: Object.fromEntries([...tr.querySelectorAll('[data-severity]')].map((e) => [e.dataset.severity, Number(e.dataset.count)])),
      countColours: [...tr.querySelectorAll('[data-severity]')].map((e) => getComputedStyle(e).color),
      verdict: cell('data-verdict').dataset.verdict,
      verdictText: cell('data-verdict').textContent.trim(),
      lastFrame: cell('data-last-frame').dataset.lastFrame,
      starTracker: tr.querySelector('[data-star-tracker]').textContent.trim(),
    };
  }));
}

const ATTENTION = ['NOMINAL', 'INFO', 'WARNING', 'DISTRESS', 'CRITICAL'];

// Each row against esg status, esg alerts and esg diagnoses of the same server; the rows in
// the order worst first.
async function checkFleet(rows) {
  const status = await cliJson('status');
  assert.deepEqual(rows.map((r) => r.id).sort(), status.sessions.map((s) => s.spacecraftId).sort());
  const alerts = (await cliJson('alerts')).alerts.filter((a) => !a.cleared && !a.revisedTime);
  const rank = (sev) => ['INFO', 'WARNING', 'DISTRESS', 'CRITICAL'].indexOf(sev) + 1;
  for (const session of status.sessions) {
    const row = rows.find((r) => r.id === session.spacecraftId);
    const where = session.spacecraftId;
    const state = session.state.replace('SESSION_STATE_', '');
    assert.equal(row.state, state, where);
    assert.ok(row.stateText.startsWith(state), row.stateText);
    // Sensor health beside the state (docs/service.md "Session states").
    if (state === 'QUARANTINED') {
      assert.equal(row.health, 'quarantined', where);
      assert.ok(row.healthText.includes(session.quarantineReason), row.healthText);
    } else if (state === 'FAULTED') {
      assert.equal(row.health, 'faulted', where);
    } else if (session.degraded) {
      assert.equal(row.health, 'degraded', where);
      assert.deepEqual(row.excluded, session.excludedGyros.map((g) => ({ gyro: g.gyroId, reason: g.reason })), where);
      for (const g of session.excludedGyros) {
        assert.ok(row.healthText.includes(`gyro ${g.gyroId} excluded (${g.reason.toLowerCase().replace(/_/g, ' ')})`), row.healthText);
      }
    } else {
      assert.equal(row.health, 'nominal', where);
    }
    // The attitude 1-sigma now, per body axis, to the 0.1 arcsec shown.
    const sigma = session.latestAttitude ? session.latestAttitude.sigmaArcsec : null;
    if (sigma) {
      assert.equal(row.sigma, sigma.join(' '), where);
      assert.equal(row.sigmaText, sigma.map((v) => v.toFixed(1)).join(' / '), where);
    }
    // The model-consistency monitor: inconsistent, and the widening as an unmodelled drift.
    const m = session.modelConsistency;
    assert.equal(row.model, !m ? 'untested' : m.consistent ? 'consistent' : 'inconsistent', where);
    assert.equal(Number(row.widened || 0), m ? m.widenedDriftDegH || 0 : 0, where);
    if (m && m.widenedDriftDegH > 0) {
      assert.ok(row.modelText.includes('filter widened') && row.modelText.includes(`${m.widenedDriftDegH.toFixed(3)} deg/h`), row.modelText);
    }
    // Active alerts: counts of the severities present only; the worst one named.
    const mine = alerts.filter((a) => a.spacecraftId === session.spacecraftId);
    const counts = {};
    for (const a of mine) counts[a.severity.replace('ALERT_SEVERITY_', '')] = (counts[a.severity.replace('ALERT_SEVERITY_', '')] || 0) + 1;
    assert.deepEqual(row.counts, counts, `${where} active alerts`);
    assert.ok(!Object.values(row.counts).includes(0), 'no zero count printed');
    const worst = mine.map((a) => a.severity.replace('ALERT_SEVERITY_', '')).sort((a, b) => rank(b) - rank(a))[0] || '';
    assert.equal(row.worstSeverity, worst, `${where} worst alert`);
    if (worst) assert.ok(mine.some((a) => a.reason === `ALERT_REASON_${row.worstAlert}` && a.severity.endsWith(worst)), row.alertText);
    // The last diagnosis' verdict.
    const diagnoses = (await cliJson('diagnoses', 'list', '--spacecraft', session.spacecraftId)).diagnoses || [];
    assert.equal(row.verdict, diagnoses.length ? diagnoses.at(-1).verdict : '', where);
    assert.equal(row.lastFrame, session.lastFrameTime, where);
  }
  // Worst first: the attention level never rises down the table.
  const levels = rows.map((r) => ATTENTION.indexOf(r.attention));
  assert.deepEqual(levels, [...levels].sort((a, b) => b - a), `attention down the table: ${rows.map((r) => `${r.id} ${r.attention}`).join(', ')}`);
  return status;
}

test('fleet overview: health, 1-sigma, model, worst alert and diagnosis per spacecraft, worst first', async () => {
  await open('esg:root/esg:fleet');
  await page.waitForFunction(() => document.querySelectorAll('tr[data-spacecraft]').length >= 2,
    { timeout: 20_000 });
  const rows = await fleetRows();
  const status = await checkFleet(rows);
  // RDK-F: gyro 1's 2 arcmin readout jump excludes it: degraded, the output on the clean pair
  // [2,3], not FAULTED; gyro 3's 0.05 deg/h drift step is a drift the model lacks: the filter
  // widens and the model-consistency monitor reports it; the diagnosis names a verdict. It is
  // shown above the healthy RDK-1.
  const faultySession = status.sessions.find((s) => s.spacecraftId === FAULTY);
  assert.equal(faultySession.degraded, true, JSON.stringify(faultySession.excludedGyros));
  assert.deepEqual(faultySession.excludedGyros.map((g) => g.gyroId), [1]);
  assert.notEqual(faultySession.state, 'SESSION_STATE_FAULTED');
  const f = rows.find((r) => r.id === FAULTY);
  assert.equal(f.health, 'degraded');
  assert.deepEqual(f.excluded.map((g) => g.gyro), [1]);
  assert.equal(f.model, 'inconsistent');
  assert.ok(Number(f.widened) > 0, 'RDK-F runs widened');
  assert.equal(f.worstSeverity, 'DISTRESS');
  assert.equal(f.worstAlert, 'WORKING_PAIR_FAULT');
  assert.ok(f.verdict && f.verdict !== 'none', `RDK-F verdict ${f.verdict}`);
  assert.equal(f.attention, 'DISTRESS');
  const healthy = rows.find((r) => r.id === 'RDK-1');
  assert.equal(healthy.health, 'nominal');
  assert.equal(healthy.model, 'consistent');
  assert.equal(healthy.worstAlert, '', 'RDK-1\'s two alerts are cleared');
  assert.deepEqual(healthy.counts, {});
  assert.deepEqual(rows.map((r) => r.id), [FAULTY, 'RDK-1']);
});

test('summary layout of the faulty spacecraft: health panel, envelope, k0 bands, innovations of running gyros, on one 1600x900 screen', async () => {
  const status = await cliJson('status', '--spacecraft', FAULTY);
  const session = status.sessions ? status.sessions[0] : status;
  const last = Date.parse(session.lastFrameTime);
  // The time bounds of the page, given back at the end for the tests after this one.
  const saved = await page.evaluate(() => window.openmct.time.getBounds());
  await page.setViewport({ width: 1600, height: 900 });
  try {
    await open(`esg:root/esg:sc~${FAULTY}/esg:summary~${FAULTY}`,
      `?tc.mode=fixed&tc.startBound=${last - FAULT_HOURS * 3600e3}&tc.endBound=${last}&tc.timeSystem=utc`);
    await page.waitForSelector(`.esg-health[data-spacecraft="${FAULTY}"] [data-active-alerts]`, { timeout: 20_000 });
    await page.waitForFunction(() => document.querySelectorAll('.gl-plot canvas').length >= 7, { timeout: 20_000 });
    const panel = await page.$eval('.esg-health', (t) => ({
      attention: t.dataset.attention,
      health: t.querySelector('[data-health]').dataset.health,
      excluded: [...t.querySelectorAll('[data-excluded-gyro]')].map((e) => Number(e.dataset.excludedGyro)),
      model: t.querySelector('[data-model]').dataset.model,
      verdict: t.querySelector('[data-verdict]').dataset.verdict,
      alerts: [...t.querySelectorAll('[data-alert]')].map((e) => Number(e.dataset.alert)),
    }));
    const active = (await cliJson('alerts', '--spacecraft', FAULTY)).alerts.filter((a) => !a.cleared);
    assert.equal(panel.attention, 'DISTRESS');
    assert.equal(panel.health, 'degraded');
    assert.deepEqual(panel.excluded, session.excludedGyros.map((g) => g.gyroId));
    assert.equal(panel.model, 'inconsistent');
    const diagnoses = (await cliJson('diagnoses', 'list', '--spacecraft', FAULTY)).diagnoses;
    assert.equal(panel.verdict, diagnoses.at(-1).verdict);
    // Every active alert, worst first (the DISTRESS one at the top).
    assert.deepEqual([...panel.alerts].sort((a, b) => a - b), active.map((a) => Number(a.sequence)).sort((a, b) => a - b));
    const distress = active.find((a) => a.severity === 'ALERT_SEVERITY_DISTRESS');
    assert.equal(panel.alerts[0], Number(distress.sequence));
    // The frames: the panel, the envelope, k0 of each running gyro, the innovations of each
    // running gyro (the working and reserve pairs: gyros 1, 2, 3; spare gyro 4 has none), all
    // inside the window.
    const frames = await page.$$eval('.l-layout__frame', (fs) => fs.map((f) => {
      const r = f.getBoundingClientRect();
      return { title: (f.querySelector('.c-object-label__name') || {}).textContent, bottom: r.bottom, right: r.right };
    }));
    const titles = frames.map((f) => (f.title || '').trim());
    const running = [...new Set([...session.config.workingPair, ...session.config.reservePair])].sort();
    assert.deepEqual(running, [1, 2, 3]);
    assert.deepEqual(titles.filter((t) => t.startsWith('Innovations')), running.map((g) => `Innovations gyro ${g}`));
    assert.deepEqual(titles.filter((t) => t.startsWith('k0')), running.map((g) => `k0 gyro ${g} with 1-sigma band`));
    assert.ok(titles.includes('Attitude 1-sigma envelope') && titles.includes('Health, alerts and last diagnosis'), titles.join(', '));
    for (const f of frames) assert.ok(f.bottom <= 900 - 40 && f.right <= 1600, `${f.title} at ${f.right},${f.bottom}: off the screen`);
    // No innovations object for the spare in the spacecraft's folder either.
    assert.equal(await page.evaluate(async (sc) => (await window.openmct.objects.get({ namespace: 'esg', key: `sc~${sc}` }))
      .composition.some((c) => c.key === `innovplot~${sc}~4`), FAULTY), false);
    await shot('summary', 900, 1600);
  } finally {
    await page.setViewport({ width: 1500, height: 900 });
    await page.evaluate((b) => window.openmct.time.setBounds(b), saved);
    // Open MCT then writes the bounds into the URL's hash; the next test navigates after that.
    await page.waitForFunction((start) => window.location.hash.includes(`tc.startBound=${start}`),
      { timeout: 20_000 }, saved.start);
  }
});

test('coefficient table shows the values and 1-sigma of esg history, to the digits shown', async () => {
  await open('esg:root/esg:sc~RDK-1/esg:coefs~RDK-1~1/esg:coeftable~RDK-1~1');
  const rows = await waitForTableRows(10);
  const history = (await cliJson('history', '--spacecraft', 'RDK-1', '--gyro', '1')).snapshots;
  const byTime = new Map(history.map((s) => [Date.parse(s.measurementTime), s]));
  // The table lists newest first: its top row is the newest snapshot esg has.
  assert.equal(cellTime(rows[0]['Time (UTC)']), Date.parse(history[history.length - 1].measurementTime));
  const columns = [
    ['k0', (m) => coef(m, 'k0')], ['C11', (m) => coef(m, 'c1x')], ['C12', (m) => coef(m, 'c1y')],
    ['C13', (m) => coef(m, 'c1z')], ['C21', (m) => coef(m, 'c2x')], ['C22', (m) => coef(m, 'c2y')],
    ['C23', (m) => coef(m, 'c2z')],
  ];
  let compared = 0;
  for (const row of rows) {
    const snapshot = byTime.get(cellTime(row['Time (UTC)']));
    assert.ok(snapshot, `no esg snapshot at ${row['Time (UTC)']}`);
    for (const [name, get] of columns) {
      // Shown with 5 decimals (1e-5 deg/h); equal to esg's value to that precision.
      assert.equal(Number(row[`${name} [deg/h]`]).toFixed(5), get(snapshot.model).toFixed(5), `${name} at ${row['Time (UTC)']}`);
      assert.equal(Number(row[`${name} 1-sigma [deg/h]`]).toFixed(5), get(snapshot.sigma).toFixed(5), `${name} 1-sigma at ${row['Time (UTC)']}`);
      compared += 2;
    }
  }
  assert.ok(compared >= 140, `compared ${compared} values`);
  if (SCREENSHOTS) {
    await open('esg:root/esg:sc~RDK-1/esg:coefs~RDK-1~1/esg:coefplot~RDK-1~1~k0');
    await page.waitForSelector('.gl-plot canvas', { timeout: 20_000 });
    await shot('coefficient_k0_band');
  }
});

test('a gyro fault alert of the faulty flight is acknowledged from the fault view, esg shows who', async () => {
  const before = (await cliJson('alerts', '--spacecraft', FAULTY)).alerts;
  const fault = before.find((a) => a.reason === 'ALERT_REASON_FAULT_AMBIGUOUS' && /^gyro_\d$/.test(a.subsystem));
  assert.ok(fault, `no gyro fault alert among ${before.map((a) => a.reason).join(', ')}`);
  assert.equal(fault.acknowledged, false);
  const repeats = Number(fault.repeatCount);
  const label = `FAULT_AMBIGUOUS #${fault.sequence}${repeats > 1 ? ` x${repeats}` : ''}`;
  await open('faults.taxonomy:faultManagement.view');
  const item = await page.waitForFunction((text) => [...document.querySelectorAll('.c-fault-mgmt__list')]
    .find((li) => li.querySelector('.c-fault-mgmt__list-faultname')?.textContent.trim() === text),
  { timeout: 20_000 }, label);
  const namespace = await item.evaluate((li) => li.querySelector('.c-fault-mgmt__list-path').textContent.trim());
  assert.equal(namespace, `${FAULTY} / ${fault.subsystem} | WARNING | first ${fault.firstTime.slice(0, 16).replace('T', ' ')}Z | active, not acknowledged`.replace('active', fault.cleared ? 'cleared' : 'active'));
  await acknowledgeInFaultList(page, label);
  // esgd stored it under the token's own name (the page sent an empty operator_name) ...
  let after;
  for (let i = 0; i < 100; i++) {
    after = (await cliJson('alerts', '--spacecraft', FAULTY)).alerts.find((a) => a.sequence === fault.sequence);
    if (after.acknowledged) break;
    await sleep(100);
  }
  assert.equal(after.acknowledged, true);
  assert.equal(after.acknowledgedBy, OPERATOR);
  // ... and the change came back to the page over the WebSocket.
  await page.waitForFunction((text, who) => [...document.querySelectorAll('.c-fault-mgmt__list.is-acknowledged')]
    .some((li) => li.querySelector('.c-fault-mgmt__list-faultname').textContent.trim() === text &&
      li.querySelector('.c-fault-mgmt__list-path').textContent.endsWith(`acknowledged by ${who}`)),
  { timeout: 20_000 }, label, OPERATOR);
});

test('a read-only token cannot acknowledge: the page says so and esgd keeps the alert unacknowledged', async () => {
  const alerts = (await cliJson('alerts', '--spacecraft', FAULTY)).alerts;
  const target = alerts.find((a) => !a.acknowledged);
  const repeats = Number(target.repeatCount);
  const label = `${target.reason.replace('ALERT_REASON_', '')} #${target.sequence}${repeats > 1 ? ` x${repeats}` : ''}`;
  const tab = await browser.newPage(); // a tab of its own: its own sessionStorage, its own sign-in
  try {
    await tab.setViewport({ width: 1500, height: 900 });
    await tab.goto(`${gateway.url}#/browse/faults.taxonomy:faultManagement.view`, { waitUntil: 'domcontentloaded' });
    await tab.waitForSelector('#esg-signin:not([hidden])', { timeout: 20_000 });
    await tab.type('#esg-token', viewerToken);
    await tab.click('#esg-signin-submit');
    await acknowledgeInFaultList(tab, label);
    await tab.waitForFunction(() => /does not have the write role/.test(document.body.textContent), { timeout: 20_000 });
  } finally {
    await tab.close();
  }
  const after = (await cliJson('alerts', '--spacecraft', FAULTY)).alerts.find((a) => a.sequence === target.sequence);
  assert.equal(after.acknowledged, false);
});

test('alerts raised while the fault view is open appear in it without a reload (WebSocket push)', async () => {
  // A third spacecraft whose star tracker has outliers and an outage
  // (deploy/examples/scenarios/star_tracker_defects.json, 5 h): esgd declares it faulty.
  const config = path.join(tmp, 'rdks.json');
  const recording = path.join(tmp, 'star_tracker.csv');
  fs.writeFileSync(config, fs.readFileSync(CONFIG, 'utf8').replace('"spacecraftId": "RDK-1"', '"spacecraftId": "RDK-S"'));
  await esg(['simulate', '--config', config, '--profile', 'orbital', '--scenario',
    path.join(SCENARIOS, 'star_tracker_defects.json'), '--hours', '5', '--seed', '1', '--out', recording]);
  await open('faults.taxonomy:faultManagement.view');
  await page.waitForSelector('.c-fault-mgmt__list');
  const marker = await page.evaluate(() => { window.esgNoReload = true; return document.querySelectorAll('.c-fault-mgmt__list').length; });
  assert.ok(marker > 0);
  assert.equal(await page.$$eval('.c-fault-mgmt__list-path', (ps) => ps.filter((p) => p.textContent.includes('RDK-S')).length), 0);
  await cli('configure', '--config', config, '--model', '10+11');
  await cli('replay', '--recording', recording, '--wait');
  const raised = (await cliJson('alerts', '--spacecraft', 'RDK-S')).alerts
    .filter((a) => a.reason === 'ALERT_REASON_STAR_TRACKER_FAULT');
  assert.ok(raised.length > 0, 'the star-tracker defects raise STAR_TRACKER_FAULT');
  await page.waitForFunction((n) => [...document.querySelectorAll('.c-fault-mgmt__list')]
    .filter((li) => li.textContent.includes('RDK-S / star_tracker | DISTRESS') && li.textContent.includes('STAR_TRACKER_FAULT #')).length === n,
  { timeout: 20_000 }, raised.length);
  assert.equal(await page.evaluate(() => window.esgNoReload), true, 'the page was not reloaded');
  // Cleared alerts are not styled as active ones: their severity mark grey, their text dimmed.
  const styles = await page.$$eval('.c-fault-mgmt__list.data-selectable', (lis) => lis.map((li) => ({
    cleared: / \| cleared, /.test(li.querySelector('.c-fault-mgmt__list-path').textContent),
    grey: getComputedStyle(li.querySelector('.c-fault-mgmt__list-severity')).filter === 'grayscale(1)',
    dimmed: Number(getComputedStyle(li.querySelector('.c-fault-mgmt__list-content')).opacity) < 1,
  })));
  assert.ok(styles.some((r) => r.cleared) && styles.some((r) => !r.cleared), JSON.stringify(styles));
  // (Open MCT dims acknowledged ones itself: an active acknowledged alert may be dimmed too.)
  for (const r of styles) {
    assert.equal(r.grey, r.cleared, JSON.stringify(r));
    if (r.cleared) assert.ok(r.dimmed, JSON.stringify(r));
  }
  await shot('faults');
});

// The tree's items on screen, top to bottom, as {name, level}: level is the indent in px.
function treeItems(tab) {
  return tab.$$eval('.c-tree__item-h[role=treeitem]', (items) => items
    .sort((a, b) => parseFloat(a.style.top) - parseFloat(b.style.top))
    .map((item) => ({
      name: item.querySelector('.c-tree__item__name').textContent.trim(),
      level: parseFloat(item.style.paddingLeft) || 0,
    })));
}

// The names of the children of the tree item named `name`, in order (an empty list while it is
// closed).
async function treeChildren(tab, name) {
  const items = await treeItems(tab);
  const at = items.findIndex((i) => i.name === name);
  assert.ok(at >= 0, `no tree item ${name} in ${items.map((i) => i.name).join(', ')}`);
  const children = [];
  for (const item of items.slice(at + 1)) {
    if (item.level <= items[at].level) break;
    if (children.length === 0 || item.level === children[0].level) children.push(item);
  }
  return children.map((i) => i.name);
}

// Clicks the disclosure triangle of the tree item named `name`; `open` true waits until its
// children are listed, false until they are gone.
async function toggleTreeItem(tab, name, open) {
  await tab.evaluate((n, o) => {
    const item = [...document.querySelectorAll('.c-tree__item-h[role=treeitem]')]
      .find((h) => h.querySelector('.c-tree__item__name').textContent.trim() === n);
    if (item.getAttribute('aria-expanded') !== String(o)) item.querySelector('.c-tree__item__view-control').click();
  }, name, open);
  await tab.waitForFunction((n, o) => {
    const items = [...document.querySelectorAll('.c-tree__item-h[role=treeitem]')]
      .sort((a, b) => parseFloat(a.style.top) - parseFloat(b.style.top));
    const at = items.findIndex((h) => h.querySelector('.c-tree__item__name').textContent.trim() === n);
    const next = items[at + 1];
    const deeper = Boolean(next) && parseFloat(next.style.paddingLeft || 0) > parseFloat(items[at].style.paddingLeft || 0);
    return at >= 0 && deeper === o;
  }, { timeout: 20_000 }, name, open);
}

// The demo's configuration under another spacecraft id, and a simulated calibration flight of
// `hours` for it (paper_calibration.json, `seed`): the two files, in the test's temp dir.
async function simulateSpacecraft(id, hours, seed) {
  const config = path.join(tmp, `${id}.json`);
  const recording = path.join(tmp, `${id}.csv`);
  fs.writeFileSync(config, fs.readFileSync(CONFIG, 'utf8').replace('"spacecraftId": "RDK-1"', `"spacecraftId": "${id}"`));
  await esg(['simulate', '--config', config, '--profile', 'calibration', '--scenario',
    path.join(SCENARIOS, 'paper_calibration.json'), '--hours', String(hours), '--seed', String(seed),
    '--out', recording]);
  return { config, recording };
}

// Opens the Disposition Actions menu of the fault named `label` in tab's fault list and chooses
// Acknowledge, then saves the comment form. The list is drawn again whenever esgd pushes an
// alert, which can take the menu away under the click: each try finds the fault afresh, and a
// menu that has not opened within 3 s is asked for again (5 tries).
async function acknowledgeInFaultList(tab, label) {
  for (let attempt = 1; ; attempt++) {
    const item = await tab.waitForFunction((text) => [...document.querySelectorAll('.c-fault-mgmt__list')]
      .find((li) => li.querySelector('.c-fault-mgmt__list-faultname')?.textContent.trim() === text),
    { timeout: 20_000 }, label);
    await (await item.evaluateHandle((li) => li.querySelector('button[aria-label="Disposition Actions"]'))).click();
    const menuItem = await tab.waitForFunction(() => [...document.querySelectorAll('.c-menu li')]
      .find((li) => li.textContent.trim() === 'Acknowledge'), { timeout: 3_000 }).catch((e) => {
      if (attempt >= 5) throw e;
      return null;
    });
    if (menuItem === null) continue;
    await menuItem.click();
    break;
  }
  await tab.waitForSelector('.c-overlay button[aria-label="Save"]');
  await tab.click('.c-overlay button[aria-label="Save"]');
}

const treeHas = (name) => [...document.querySelectorAll('.c-tree__item-h[role=treeitem] .c-tree__item__name')]
  .some((n) => n.textContent.trim() === name);

test('a spacecraft configured after the page loaded appears in the tree without a reload', async () => {
  // A new tab loads the page with the fleet esgd has now; RDK-N is configured and its first hour
  // replayed afterwards. Its folder must come from the pushed estimates and alerts, not a reload.
  const NEW = 'RDK-N';
  const { config, recording } = await simulateSpacecraft(NEW, 1, 2);
  const tab = await browser.newPage();
  try {
    await tab.setViewport({ width: 1500, height: 1400 }); // the tree draws only the items in view
    await tab.goto(`${gateway.url}#/browse/esg:root`, { waitUntil: 'domcontentloaded' });
    await tab.waitForSelector('#esg-signin:not([hidden])', { timeout: 20_000 });
    await tab.type('#esg-token', token);
    await tab.click('#esg-signin-submit');
    await tab.waitForFunction(treeHas, { timeout: 20_000 }, 'ESG spacecraft');
    await toggleTreeItem(tab, 'ESG spacecraft', true);
    await tab.waitForFunction(treeHas, { timeout: 20_000 }, 'RDK-1');
    const atLoad = await treeChildren(tab, 'ESG spacecraft');
    assert.ok(atLoad.includes('RDK-1') && !atLoad.includes(NEW), `at load: ${atLoad.join(', ')}`);
    await tab.evaluate(() => { window.esgNoReload = true; });
    await cli('configure', '--config', config, '--model', '10+11');
    const t0 = Date.now();
    await cli('replay', '--recording', recording, '--wait');
    const replayed = Date.now();
    await tab.waitForFunction(treeHas, { timeout: 20_000 }, NEW);
    process.stdout.write(`# ${NEW} in the tree ${((Date.now() - t0) / 1000).toFixed(1)} s after its configuration ` +
      `(${((Date.now() - replayed) / 1000).toFixed(1)} s after its replay ended)\n`);
    const now = await treeChildren(tab, 'ESG spacecraft');
    assert.deepEqual(now.filter((n) => n !== NEW), atLoad, 'the other children stay as they were');
    // Its folder holds what the folders read at load hold (the same gyros: the same configuration).
    await toggleTreeItem(tab, NEW, true);
    const children = await treeChildren(tab, NEW);
    await toggleTreeItem(tab, NEW, false);
    await toggleTreeItem(tab, 'RDK-1', true);
    const reference = await treeChildren(tab, 'RDK-1');
    assert.ok(reference.includes('Drift coefficients gyro 1') && reference.includes('Diagnoses'), reference.join(', '));
    assert.deepEqual(children, reference);
    assert.equal(await tab.evaluate(() => window.esgNoReload), true, 'the page was not reloaded');
  } finally {
    await tab.close();
  }
});

test('the diagnosis report opens with the verdict and findings esg stored', async () => {
  const stored = await cliJson('diagnoses', 'show', '--spacecraft', FAULTY, '--id', String(diagnosisId));
  const report = stored.report || JSON.parse(stored.reportJson);
  await open(`esg:root/esg:sc~${FAULTY}/esg:diags~${FAULTY}/esg:diag~${FAULTY}~${diagnosisId}`);
  await page.waitForSelector('.esg-verdict', { timeout: 20_000 });
  assert.equal(await page.$eval('.esg-verdict', (e) => e.textContent), stored.verdict);
  const headings = await page.$$eval('.esg-finding h3', (hs) => hs.map((h) => h.textContent));
  assert.deepEqual(headings, report.findings.map((f) => `${f.effect}${f.gyro ? ` (gyro ${f.gyro})` : ''}`));
  assert.ok(headings.length > 0, 'the faulty flight has findings');
  // Parameters by their names in words, not the report's JSON keys.
  const parameters = await page.$$eval('.esg-finding td[data-parameter]', (tds) => tds.map((td) => td.textContent));
  assert.ok(parameters.length > 0, 'the findings have parameters');
  for (const name of parameters) assert.doesNotMatch(name, /\[\d\]|DegH|Hours/, name);
  assert.ok(parameters.includes('drift step about case z'), parameters.join(', '));
  const gaps = report.fit.before.gaps.length;
  assert.equal(await page.$$eval('.esg-gap-chart rect title', (t) => t.length), 2 * gaps);
  await shot('diagnosis', 1350);
});

test('per-step estimate views: real sigma values when esgd has them, "not available" when not', async () => {
  const status = (await cliJson('status', '--spacecraft', 'RDK-1'));
  const last = Date.parse((status.sessions ? status.sessions[0] : status).lastFrameTime);
  const from = new Date(last - 3600e3).toISOString();
  const to = new Date(last).toISOString();
  const probe = await api(`/api/spacecraft/RDK-1/estimates?from=${from}&to=${to}`);
  process.stdout.write(`# GET /api/spacecraft/RDK-1/estimates: ${probe.status}\n`);
  await open('esg:root/esg:sc~RDK-1/esg:atttable~RDK-1');
  if (probe.status === 501) {
    await page.waitForSelector('.esg-unavailable', { timeout: 20_000 });
    assert.match(await page.$eval('.esg-unavailable', (e) => e.textContent), /not available/);
    await open('esg:root/esg:sc~RDK-1/esg:innovtable~RDK-1');
    await page.waitForFunction(() => /not available/.test(document.querySelector('.esg-unavailable')?.textContent || ''));
    await open('esg:root/esg:fleet');
    await page.waitForSelector('tr[data-spacecraft="RDK-1"]');
    assert.equal(await page.$eval('tr[data-spacecraft="RDK-1"] [data-star-tracker]', (e) => e.textContent),
      'last star tracker: not available');
  } else {
    assert.equal(probe.status, 200, probe.text);
    const estimates = probe.json.estimates;
    assert.ok(estimates.length > 0);
    const byTime = new Map(estimates.filter((e) => e.attitude).map((e) => [Date.parse(e.measurement_time), e]));
    const rows = await waitForTableRows(10);
    let compared = 0;
    for (const row of rows) {
      const t = cellTime(row['Time (UTC)']);
      const record = byTime.get(t);
      if (!record) continue; // older than the probe's hour
      ['x', 'y', 'z'].forEach((axis, i) => {
        assert.equal(Number(row[`1-sigma body ${axis} [arcsec]`]).toFixed(3),
          record.attitude.sigma_arcsec[i].toFixed(3), `sigma ${axis} at ${row['Time (UTC)']}`);
        compared++;
      });
    }
    assert.ok(compared >= 30, `compared ${compared} sigma values`);
    // Star-tracker innovations per gyro, with their 1-sigma, in the gyro's basis.
    await open('esg:root/esg:sc~RDK-1/esg:innovtable~RDK-1');
    const innovationRows = await waitForTableRows(10);
    let innovations = 0;
    for (const row of innovationRows) {
      const record = byTime.get(cellTime(row['Time (UTC)']));
      if (!record) continue;
      for (const g of record.star_tracker_innovations) {
        for (const i of [0, 1]) {
          assert.equal(Number(row[`gyro ${g.gyro_id} z${i + 1} [arcsec]`]).toFixed(3),
            g.innovation_arcsec[i].toFixed(3), `gyro ${g.gyro_id} z${i + 1} at ${row['Time (UTC)']}`);
          assert.equal(Number(row[`gyro ${g.gyro_id} z${i + 1} 1-sigma [arcsec]`]).toFixed(3),
            g.sigma_arcsec[i].toFixed(3), `gyro ${g.gyro_id} z${i + 1} 1-sigma at ${row['Time (UTC)']}`);
          innovations += 2;
        }
      }
    }
    assert.ok(innovations > 0, 'innovations compared');
    // The fleet's last star-tracker correction: from the newest estimate's last_star_tracker_time.
    const newest = estimates[estimates.length - 1];
    const minutes = Math.round((Date.parse(status.sessions ? status.sessions[0].lastFrameTime : status.lastFrameTime) -
      Date.parse(newest.last_star_tracker_time)) / 60000);
    await open('esg:root/esg:fleet');
    await page.waitForSelector('tr[data-spacecraft="RDK-1"]');
    assert.equal(await page.$eval('tr[data-spacecraft="RDK-1"] [data-star-tracker]', (e) => e.textContent),
      `star tracker ${Math.floor(minutes / 60)} h ${String(minutes % 60).padStart(2, '0')} min before it`);
    if (SCREENSHOTS) {
      await open('esg:root/esg:sc~RDK-1/esg:attplot~RDK-1');
      await page.waitForSelector('.gl-plot canvas', { timeout: 20_000 });
      await shot('attitude_envelope');
      // The last 3 h: over the whole flight the innovations are a solid cloud.
      await open('esg:root/esg:sc~RDK-1/esg:innovplot~RDK-1~1',
        `?tc.mode=fixed&tc.startBound=${last - 3 * 3600e3}&tc.endBound=${last}&tc.timeSystem=utc`);
      await page.waitForSelector('.gl-plot canvas', { timeout: 20_000 });
      await shot('innovations_gyro1');
    }
    await liveEstimatesAndCoefficients(last, Number((status.sessions ? status.sessions[0] : status).lastSequence));
  }
});

// The attitude error estimate of each star-tracker update (per body axis, with its 1-sigma): the
// table's values over 45 min of the flight against `esg estimates --format json` of the same steps
// (3 decimals, the table's format), empty on a step without a star-tracker update (the span ends
// 5 min after the newest such step of the flight, a rejected outlier of the demo scenario, so the
// table's 50 rows hold it); each axis has its plot with the estimate and its +/-1-sigma envelope.
test('attitude error estimate: the table shows what esg estimates stored, a plot per body axis', async () => {
  const status = await cliJson('status', '--spacecraft', 'RDK-1');
  const last = Date.parse((status.sessions ? status.sessions[0] : status).lastFrameTime);
  const probe = await api(`/api/spacecraft/RDK-1/estimates?from=${new Date(last - 3600e3).toISOString()}`);
  if (probe.status === 501) {
    await open('esg:root/esg:sc~RDK-1/esg:errtable~RDK-1');
    await page.waitForFunction(() => /not available/.test(document.querySelector('.esg-unavailable')?.textContent || ''));
    return;
  }
  assert.equal(probe.status, 200, probe.text);
  const all = JSON.parse(await cli('estimates', '--spacecraft', 'RDK-1', '--format', 'json')).estimates;
  const noEstimate = all.filter((e) => (e.attitudeErrorBArcsec || []).length === 0 && e.attitude);
  const end = noEstimate.length > 0
    ? Math.min(Date.parse(noEstimate.at(-1).measurementTime) + 5 * 60e3, last) : last;
  const start = end - 45 * 60e3;
  const byTime = new Map(all.map((e) => [Date.parse(e.measurementTime), e]));
  const bounds = `?tc.mode=fixed&tc.startBound=${start}&tc.endBound=${end}&tc.timeSystem=utc`;
  await open('esg:root/esg:sc~RDK-1/esg:errtable~RDK-1', bounds);
  const rows = await waitForTableRows(30);
  let withEstimate = 0;
  let without = 0;
  for (const row of rows) {
    const at = row['Time (UTC)'];
    const record = byTime.get(cellTime(at));
    assert.ok(record, `esg estimates has the step at ${at}`);
    const error = record.attitudeErrorBArcsec || [];
    const sigma = record.attitudeErrorSigmaBArcsec || [];
    if (error.length === 0) {
      assert.equal(row['Star tracker used'], 'no', `a step without an estimate applied no star tracker (${at})`);
      for (const axis of ['x', 'y', 'z']) {
        assert.doesNotMatch(row[`Attitude error body ${axis} [arcsec]`] || '', /\d/, `no estimate at ${at}`);
      }
      without++;
      continue;
    }
    assert.equal(row['Star tracker used'], 'yes');
    ['x', 'y', 'z'].forEach((axis, i) => {
      assert.equal(Number(row[`Attitude error body ${axis} [arcsec]`]).toFixed(3), error[i].toFixed(3),
        `error ${axis} at ${at}`);
      assert.equal(Number(row[`Attitude error body ${axis} 1-sigma [arcsec]`]).toFixed(3), sigma[i].toFixed(3),
        `error 1-sigma ${axis} at ${at}`);
    });
    withEstimate++;
  }
  process.stdout.write(`# attitude error table: ${withEstimate} rows with an estimate, ${without} without ` +
    `(${noEstimate.length} of ${all.length} steps of the flight have none)\n`);
  assert.ok(withEstimate >= 20, `compared ${withEstimate} rows`);
  if (noEstimate.length > 0) assert.ok(without >= 1, 'the span holds a step without an estimate');
  // The plots: the estimate and its +/-1-sigma lines about zero, one plot per body axis.
  for (const axis of ['x', 'y', 'z']) {
    await open(`esg:root/esg:sc~RDK-1/esg:errplot~RDK-1~${axis}`, bounds);
    await page.waitForSelector('.gl-plot canvas', { timeout: 20_000 });
    await page.waitForFunction(() => document.querySelectorAll('.plot-series-name').length >= 3,
      { timeout: 20_000 });
    const names = await page.$$eval('.plot-series-name', (spans) => spans.map((s) => s.textContent.trim()));
    for (const band of ['', ' +1-sigma', ' -1-sigma']) {
      assert.ok(names.some((n) => n.startsWith(`attitude error body ${axis}${band}`) &&
        (band || !/sigma/.test(n))), `series "attitude error body ${axis}${band}" in ${names.join(' | ')}`);
    }
    if (axis === 'x') await shot('attitude_error_x');
  }
});

// Real time with per-step estimates: the next hour of the same flight is replayed in two halves
// while a table is open. The estimate table gets rows pushed by SubscribeEstimates; the
// coefficient table gets the snapshots fetched on each pushed estimate. No reload in between.
async function liveEstimatesAndCoefficients(last, lastSequence) {
  const more = path.join(tmp, 'flight_next_hour.csv');
  await esg(['simulate', '--config', CONFIG, '--profile', 'calibration', '--scenario',
    path.join(SCENARIOS, 'paper_calibration.json'), '--hours', String(DEMO_HOURS + 1), '--seed', '1',
    '--out', more]);
  const bounds = `?tc.mode=fixed&tc.startBound=${last - 3600e3}&tc.endBound=${last + 2 * 3600e3}&tc.timeSystem=utc`;
  const newestRowTime = () => page.evaluate(() => {
    const td = document.querySelector('.c-telemetry-table__body tr.noselect td');
    return td ? Date.parse(td.textContent.trim().replace(' ', 'T')) : 0;
  });
  const replayHalf = (first, count) => {
    const rows = fs.readFileSync(more, 'utf8').split('\n');
    const header = rows.filter((l) => l.startsWith('#'));
    const columns = rows.find((l) => l.startsWith('time_utc'));
    const data = rows.slice(rows.indexOf(columns) + 1).filter((l) => l);
    const file = path.join(tmp, `next_${first}.csv`);
    fs.writeFileSync(file, [...header, columns, ...data.slice(0, first - 1 + count), ''].join('\n'));
    return cli('replay', '--recording', file, '--from-sequence', String(first), '--wait');
  };
  await open('esg:root/esg:sc~RDK-1/esg:atttable~RDK-1', bounds);
  await waitForTableRows(10);
  assert.equal(await newestRowTime(), last);
  await page.evaluate(() => { window.esgLive = 1; });
  await replayHalf(lastSequence + 1, 30);
  await page.waitForFunction((t) => {
    const td = document.querySelector('.c-telemetry-table__body tr.noselect td');
    return td && Date.parse(td.textContent.trim().replace(' ', 'T')) > t;
  }, { timeout: 20_000 }, last);
  assert.equal(await page.evaluate(() => window.esgLive), 1, 'no reload');
  const afterFirst = (await cliJson('status', '--spacecraft', 'RDK-1'));
  const mid = Date.parse((afterFirst.sessions ? afterFirst.sessions[0] : afterFirst).lastFrameTime);
  await open('esg:root/esg:sc~RDK-1/esg:coefs~RDK-1~1/esg:coeftable~RDK-1~1', bounds);
  await waitForTableRows(10);
  assert.equal(await newestRowTime(), mid);
  await page.evaluate(() => { window.esgLive = 2; });
  await replayHalf(lastSequence + 31, 30);
  const end = Date.parse((await cliJson('history', '--spacecraft', 'RDK-1', '--gyro', '1')).snapshots.at(-1).measurementTime);
  await page.waitForFunction((t) => {
    const td = document.querySelector('.c-telemetry-table__body tr.noselect td');
    return td && Date.parse(td.textContent.trim().replace(' ', 'T')) === t;
  }, { timeout: 20_000 }, end);
  assert.equal(await page.evaluate(() => window.esgLive), 2, 'no reload');
}

test('predicted attitude across a gap after the last frame: table from PredictAttitude', async () => {
  const status = (await cliJson('status', '--spacecraft', 'RDK-1'));
  const last = Date.parse((status.sessions ? status.sessions[0] : status).lastFrameTime);
  const start = last - 6 * 3600e3;
  const end = last + 6 * 3600e3;
  const bounds = `?tc.mode=fixed&tc.startBound=${start}&tc.endBound=${end}&tc.timeSystem=utc`;
  await open('esg:root/esg:sc~RDK-1/esg:predtable~RDK-1', bounds);
  const rows = await waitForTableRows(5);
  // The newest rows are after the last frame: an inertial hold of the last estimate, its
  // envelope growing with the time since the last star-tracker fix. The sources in words, as
  // esg's table names them; the enum names stay in the JSON (esg --format json below).
  assert.equal(rows[0]['Attitude source'], 'inertial hold');
  for (const row of rows) assert.ok(['recorded', 'inertial hold'].includes(row['Attitude source']), row['Attitude source']);
  assert.doesNotMatch(await page.$eval('.c-telemetry-table__body', (b) => b.textContent), /INERTIAL_HOLD|ATTITUDE_SOURCE_|RECORDED/);
  assert.ok(cellTime(rows[0]['Time (UTC)']) > last);
  const sigmas = rows.map((r) => Number(r['1-sigma body x [arcsec]']));
  assert.ok(sigmas[0] > sigmas[sigmas.length - 1], 'the envelope grows across the gap');
  // The page asks for ~400 samples over the bounds (12 h: every 108 s); esg asked the same
  // gives the same samples.
  const step = Math.ceil((end - start) / 1000 / 400);
  const predicted = (await cliJson('predict', '--spacecraft', 'RDK-1', '--from', new Date(start).toISOString(),
    '--to', new Date(end).toISOString(), '--step', String(step))).samples;
  const byTime = new Map(predicted.map((s) => [Date.parse(s.time), s]));
  for (const row of rows) {
    const sample = byTime.get(cellTime(row['Time (UTC)']));
    assert.ok(sample, `no esg sample at ${row['Time (UTC)']}`);
    ['x', 'y', 'z'].forEach((axis, i) => assert.equal(Number(row[`1-sigma body ${axis} [arcsec]`]).toFixed(3),
      sample.sigmaArcsec[i].toFixed(3), `sigma ${axis} at ${row['Time (UTC)']}`));
    ['q0', 'q1', 'q2', 'q3'].forEach((q, i) => assert.equal(Number(row[q]).toFixed(9),
      sample.qInB[i].toFixed(9), `${q} at ${row['Time (UTC)']}`));
  }
  // The plot marks where each source begins: the recorded readings at the first sample, the
  // inertial hold at the first sample after the last archived frame (esg predict's
  // recordedSamples), each named in the legend; no plan, no planned marker.
  const answer = await cliJson('predict', '--spacecraft', 'RDK-1', '--from', new Date(start).toISOString(),
    '--to', new Date(end).toISOString(), '--step', String(step));
  const recorded = Number(answer.recordedSamples);
  assert.equal(answer.attitudeSource, 'ATTITUDE_SOURCE_INERTIAL_HOLD');
  await open('esg:root/esg:sc~RDK-1/esg:predplot~RDK-1', bounds);
  await page.waitForSelector('.gl-plot canvas', { timeout: 20_000 });
  // The legend names the switch: the recorded samples are the gyros' alone, the hold continues
  // that run with its 1-sigma carried across, so the envelope does not drop there.
  const legend = await page.waitForFunction(() => {
    const text = document.querySelector('.c-plot-legend')?.textContent || '';
    return /inertial hold from here, the 1-sigma carried on from the recorded readings/.test(text) && text;
  }, { timeout: 20_000 });
  ['x', 'y', 'z'].forEach((axis, i) => assert.ok(predicted[recorded].sigmaArcsec[i] >= predicted[recorded - 1].sigmaArcsec[i],
    `1-sigma ${axis} drops at the switch: ${predicted[recorded - 1].sigmaArcsec[i]} -> ${predicted[recorded].sigmaArcsec[i]}`));
  assert.match(await legend.jsonValue(), /recorded gyro readings from here \(star tracker withheld: the gyros alone\)/);
  assert.doesNotMatch(await legend.jsonValue(), /INERTIAL_HOLD|ATTITUDE_SOURCE_/);
  const marks = await predictionMarks('RDK-1', start, end);
  assert.deepEqual(marks.RECORDED.map((p) => p.utc), [Date.parse(predicted[0].time), Date.parse(predicted[0].time) + 1]);
  const holdStart = Date.parse(predicted[recorded].time);
  assert.ok(holdStart > Date.parse(answer.lastArchivedTime) && Date.parse(predicted[recorded - 1].time) <= Date.parse(answer.lastArchivedTime));
  assert.deepEqual(marks.INERTIAL_HOLD.map((p) => p.utc), [holdStart, holdStart + 1]);
  assert.deepEqual(marks.PLANNED, []);
  // Each marker spans the plotted 1-sigma: from the smallest to the largest of the samples.
  const all = predicted.flatMap((p) => p.sigmaArcsec);
  assert.deepEqual(marks.INERTIAL_HOLD.map((p) => p.mark), [Math.min(...all), Math.max(...all)]);
  await shot('prediction_envelope');
});

// The marker series of the prediction plot as the page's telemetry provider gives them.
function predictionMarks(sc, start, end) {
  return page.evaluate(async (spacecraft, s, e) => {
    const out = {};
    for (const source of ['RECORDED', 'INERTIAL_HOLD', 'PLANNED']) {
      const object = await window.openmct.objects.get({ namespace: 'esg', key: `predmark~${spacecraft}~${source}` });
      out[source] = (await window.openmct.telemetry.request(object, { start: s, end: e }))
        .map((d) => ({ utc: d.utc, mark: d.mark }));
    }
    return out;
  }, sc, start, end);
}

test('without tokens: no sign-in, and acknowledging asks the operator name esgd then records', async () => {
  // A second esgd without a tokens file, the faulty flight replayed into it, its own gateway, and
  // a new browser tab (its own sessionStorage).
  const open2 = await startEsgd(['--db', path.join(tmp, 'open.db'), '--sync', 'normal']);
  let gateway2;
  let tab;
  try {
    const cli2 = (...args) => esg(['--server', open2.address, ...args]);
    await cli2('configure', '--config', faultyConfig, '--model', '10+11');
    await cli2('replay', '--recording', faulty, '--wait');
    gateway2 = await startGateway(['--esgd', open2.address]);
    tab = await browser.newPage();
    await tab.setViewport({ width: 1500, height: 900 });
    await tab.goto(`${gateway2.url}#/browse/faults.taxonomy:faultManagement.view`, { waitUntil: 'domcontentloaded' });
    await tab.waitForSelector('.c-fault-mgmt__list', { timeout: 20_000 });
    assert.equal(await tab.$eval('#esg-signin', (f) => f.hidden), true);
    const alerts = JSON.parse(await cli2('alerts', '--spacecraft', FAULTY, '--json')).alerts;
    const target = alerts.find((a) => !a.acknowledged);
    const repeats = Number(target.repeatCount);
    const label = `${target.reason.replace('ALERT_REASON_', '')} #${target.sequence}${repeats > 1 ? ` x${repeats}` : ''}`;
    await acknowledgeInFaultList(tab, label);
    // The second form: the operator's name.
    await tab.waitForSelector('#esg-operator-name', { timeout: 10_000 });
    await tab.type('#esg-operator-name', 'night.shift');
    await tab.click('#esg-operator-ok');
    let acked;
    for (let i = 0; i < 100; i++) {
      acked = JSON.parse(await cli2('alerts', '--spacecraft', FAULTY, '--json')).alerts
        .find((a) => a.sequence === target.sequence);
      if (acked.acknowledged) break;
      await sleep(100);
    }
    assert.equal(acked.acknowledged, true);
    assert.equal(acked.acknowledgedBy, 'night.shift');
  } finally {
    if (tab) await tab.close();
    if (gateway2) await stop(gateway2.child);
    await stop(open2.child);
  }
});

// q * (rotation by `deg` about body z), Hamilton, scalar first.
function rotateAboutBodyZ(q, deg) {
  const h = (deg * Math.PI) / 360;
  const [w, x, y, z] = q;
  const [c, s] = [Math.cos(h), Math.sin(h)];
  const r = [w * c - z * s, x * c + y * s, y * c - x * s, z * c + w * s];
  return r[0] < 0 ? r.map((v) => -v) : r;
}

test('a planned attitude pasted in the console is what the prediction after the last frame uses', async () => {
  const status = await cliJson('status', '--spacecraft', 'RDK-1');
  const session = status.sessions ? status.sessions[0] : status;
  const last = Date.parse(session.lastFrameTime);
  const q = session.latestAttitude.qInB;
  const plan = ['time,q0,q1,q2,q3',
    `${new Date(last + 3600e3).toISOString()},${q.join(',')}`,
    `${new Date(last + 6 * 3600e3).toISOString()},${rotateAboutBodyZ(q, 10).join(',')}`].join('\n');
  const planFile = path.join(tmp, 'plan.csv');
  fs.writeFileSync(planFile, `${plan}\n`);
  await open('esg:root/esg:sc~RDK-1/esg:plan~RDK-1');
  await page.waitForSelector('.esg-plan-text');
  await page.$eval('.esg-plan-text', (area, text) => { area.value = text; }, plan);
  await page.click('.esg-plan-use');
  await page.waitForFunction(() => /2 samples/.test(document.querySelector('.esg-plan-status').textContent));
  const start = last - 6 * 3600e3;
  const end = last + 6 * 3600e3;
  await open('esg:root/esg:sc~RDK-1/esg:predtable~RDK-1',
    `?tc.mode=fixed&tc.startBound=${start}&tc.endBound=${end}&tc.timeSystem=utc`);
  await page.waitForFunction(() => [...document.querySelectorAll('.c-telemetry-table__body tr.noselect')]
    .some((tr) => tr.textContent.includes('planned')), { timeout: 20_000 });
  const rows = await tableRows();
  const step = Math.ceil((end - start) / 1000 / 400);
  const predicted = (await cliJson('predict', '--spacecraft', 'RDK-1', '--planned', planFile,
    '--from', new Date(start).toISOString(), '--to', new Date(end).toISOString(), '--step', String(step))).samples;
  const byTime = new Map(predicted.map((s) => [Date.parse(s.time), s]));
  let planned = 0;
  for (const row of rows) {
    const sample = byTime.get(cellTime(row['Time (UTC)']));
    assert.ok(sample, `no esg sample at ${row['Time (UTC)']}`);
    ['q0', 'q1', 'q2', 'q3'].forEach((k, i) => assert.equal(Number(row[k]).toFixed(9), sample.qInB[i].toFixed(9), `${k} at ${row['Time (UTC)']}`));
    ['x', 'y', 'z'].forEach((axis, i) => assert.equal(Number(row[`1-sigma body ${axis} [arcsec]`]).toFixed(3),
      sample.sigmaArcsec[i].toFixed(3), `sigma ${axis} at ${row['Time (UTC)']}`));
    if (row['Attitude source'] === 'planned') planned++;
  }
  assert.ok(planned > 10, `${planned} planned rows`);
  const marks = await predictionMarks('RDK-1', start, end);
  const firstPlanned = predicted.find((p) => Date.parse(p.time) > last);
  assert.deepEqual(marks.PLANNED.map((p) => p.utc), [Date.parse(firstPlanned.time), Date.parse(firstPlanned.time) + 1]);
  assert.deepEqual(marks.INERTIAL_HOLD, []);
  // Clearing the plan brings the inertial hold back.
  await open('esg:root/esg:sc~RDK-1/esg:plan~RDK-1');
  await page.waitForSelector('.esg-plan-clear');
  await page.click('.esg-plan-clear');
  await open('esg:root/esg:sc~RDK-1/esg:predtable~RDK-1',
    `?tc.mode=fixed&tc.startBound=${start}&tc.endBound=${end}&tc.timeSystem=utc`);
  await page.waitForFunction(() => document.querySelector('.c-telemetry-table__body tr.noselect')?.textContent.includes('inertial hold'),
    { timeout: 20_000 });
});

// A late frame within esgd's reorder window (docs/service.md "Several ground stations"): RDK-R's
// first 200 minutes are sent with minutes 150-159 missing, those follow last, as a second
// station relaying a pass late would send them (`esg replay --from-sequence` gives them the
// sequences the station never used). esgd re-runs the filter from its window checkpoint before
// them and marks the snapshots it supersedes revised. The open coefficient table must end with
// esgd's current history (the late minutes in it, every value as `esg history` prints it) without
// a reload, the page must say that a re-run happened, and the table with revised rows must list
// the superseded snapshots with the time they were revised, as `esg history --include-revised`.
test('a late frame re-runs the filter: the open table is read again, superseded rows are marked', async () => {
  const SC = 'RDK-R';
  const { config, recording } = await simulateSpacecraft(SC, 4, 3);
  const lines = fs.readFileSync(recording, 'utf8').split('\n');
  const header = lines.filter((l) => l.startsWith('#'));
  const columns = lines.find((l) => l.startsWith('time_utc'));
  const data = lines.slice(lines.indexOf(columns) + 1).filter((l) => l);
  const rowTime = (n) => Date.parse(data[n - 1].split(',')[0]);
  // Rows first..last, with the sequences of their row numbers.
  const send = (first, last) => {
    const file = path.join(tmp, `late_${first}.csv`);
    fs.writeFileSync(file, [...header, columns, ...data.slice(0, last), ''].join('\n'));
    return cli('replay', '--recording', file, '--from-sequence', String(first), '--wait');
  };
  const history = async (...extra) => (await cliJson('history', '--spacecraft', SC, '--gyro', '1', ...extra)).snapshots;
  await cli('configure', '--config', config, '--model', '10+11');
  await send(1, 149);
  const bounds = `?tc.mode=fixed&tc.startBound=${rowTime(140)}&tc.endBound=${rowTime(200) + 600e3}&tc.timeSystem=utc`;
  await open(`esg:root/esg:sc~${SC}/esg:coefs~${SC}~1/esg:coeftable~${SC}~1`, bounds);
  await waitForTableRows(5);
  await page.evaluate(() => { window.esgRevision = 1; });
  // Minutes 160-200 arrive live; the table follows them.
  await send(160, 200);
  const newest = Date.parse((await history()).at(-1).measurementTime);
  await page.waitForFunction((t) => {
    const td = document.querySelector('.c-telemetry-table__body tr.noselect td');
    return td && Date.parse(td.textContent.trim().replace(' ', 'T')) === t;
  }, { timeout: 20_000 }, newest);
  const inGap = (t) => t >= rowTime(150) && t <= rowTime(159);
  assert.equal((await tableRows()).filter((r) => inGap(cellTime(r['Time (UTC)']))).length, 0);
  // The late minutes. `--wait` may return before the re-run or while it catches up (the last
  // applied frame steps back and forward again), and the late frames may make more than one
  // re-run: esgd's history is final when it holds a snapshot at each late frame (one per step)
  // and again reaches the newest.
  await send(150, 159);
  const lateTimes = Array.from({ length: 10 }, (_, i) => rowTime(150 + i));
  const done = (h) => lateTimes.every((t) => h.some((s) => Date.parse(s.measurementTime) === t)) &&
    Date.parse(h.at(-1).measurementTime) === newest;
  let current = await history();
  for (let i = 0; i < 200 && !done(current); i++) {
    await sleep(100);
    current = await history();
  }
  assert.ok(done(current), 'esgd stored snapshots at the late frames and re-ran up to the newest');
  const late = current.filter((s) => inGap(Date.parse(s.measurementTime)));
  const all = await history('--include-revised');
  assert.ok(all.some((s) => s.revisedTime), 'the late frames revised snapshots (esg history --include-revised)');
  await page.waitForFunction((from, to) => [...document.querySelectorAll('.c-telemetry-table__body tr.noselect')]
    .some((tr) => {
      const t = Date.parse(tr.querySelector('td').textContent.trim().replace(' ', 'T'));
      return t >= from && t <= to;
    }), { timeout: 20_000 }, rowTime(150), rowTime(159));
  await page.waitForFunction(() => /re-ran the filter/.test(document.body.textContent), { timeout: 20_000 });
  const notice = await page.evaluate(() => [...document.querySelectorAll('.c-message-banner__message')]
    .map((m) => m.textContent).join(' '));
  assert.match(notice, new RegExp(`${SC}: esgd re-ran the filter from`));
  // Every row shown is esgd's current snapshot at that time, once (the newest again at the top).
  await page.waitForFunction((t) => {
    const td = document.querySelector('.c-telemetry-table__body tr.noselect td');
    return td && Date.parse(td.textContent.trim().replace(' ', 'T')) === t;
  }, { timeout: 20_000 }, newest);
  const byTime = new Map(current.map((s) => [Date.parse(s.measurementTime), s]));
  const rows = await waitForTableRows(20);
  const times = rows.map((r) => cellTime(r['Time (UTC)']));
  assert.equal(new Set(times).size, times.length, 'one row per measurement time');
  assert.ok(times.filter(inGap).length > 0, 'the late frames\' snapshots are in the table');
  for (const row of rows) {
    const snapshot = byTime.get(cellTime(row['Time (UTC)']));
    assert.ok(snapshot, `no current snapshot at ${row['Time (UTC)']}`);
    assert.equal(Number(row['k0 [deg/h]']).toFixed(5), coef(snapshot.model, 'k0').toFixed(5), `k0 at ${row['Time (UTC)']}`);
    assert.equal(Number(row['k0 1-sigma [deg/h]']).toFixed(5), coef(snapshot.sigma, 'k0').toFixed(5), `k0 1-sigma at ${row['Time (UTC)']}`);
    assert.equal(Number(row['C11 [deg/h]']).toFixed(5), coef(snapshot.model, 'c1x').toFixed(5), `C11 at ${row['Time (UTC)']}`);
  }
  assert.equal(await page.evaluate(() => window.esgRevision), 1, 'the page was not reloaded');
  // The table with revised rows over the last quarter hour: each snapshot esg lists with
  // --include-revised, the superseded ones with the time they were revised.
  const from = rowTime(186);
  const to = rowTime(200);
  await open(`esg:root/esg:sc~${SC}/esg:coefs~${SC}~1/esg:coefrevtable~${SC}~1`,
    `?tc.mode=fixed&tc.startBound=${from}&tc.endBound=${to}&tc.timeSystem=utc`);
  // The late frames may make esgd re-run once more after its history looked final (each
  // re-run supersedes the previous one's snapshots): the table must converge on what esg lists.
  // Times compared as milliseconds: esg prints as many fractional digits as esgd stored.
  const key = (t, revised) => `${t} ${revised ? Date.parse(revised) : ''}`;
  const rowKey = (row) => key(cellTime(row['Time (UTC)']), (row['Revised at (UTC)'] || '').replace(' ', 'T'));
  let expected = [];
  let revisedRows = [];
  for (let i = 0; i < 20; i++) {
    expected = (await history('--include-revised')).filter((s) =>
      Date.parse(s.measurementTime) >= from && Date.parse(s.measurementTime) <= to);
    revisedRows = await waitForTableRows(expected.length);
    const shown = new Set(revisedRows.map(rowKey));
    if (revisedRows.length === expected.length &&
      expected.every((s) => shown.has(key(Date.parse(s.measurementTime), s.revisedTime || '')))) break;
    await sleep(500);
  }
  assert.equal(revisedRows.length, expected.length);
  const byKey = new Map(expected.map((s) => [key(Date.parse(s.measurementTime), s.revisedTime || ''), s]));
  let superseded = 0;
  for (const row of revisedRows) {
    const revised = row['Revised at (UTC)'];
    const snapshot = byKey.get(rowKey(row));
    assert.ok(snapshot, `no snapshot of esg history --include-revised at ${row['Time (UTC)']} revised "${revised}"`);
    assert.equal(Number(row['k0 [deg/h]']).toFixed(5), coef(snapshot.model, 'k0').toFixed(5));
    if (revised) superseded++;
  }
  assert.equal(superseded, expected.filter((s) => s.revisedTime).length);
  assert.ok(superseded > 0, 'the span holds superseded snapshots');
  await shot('coefficient_revisions');
  process.stdout.write(`# ${SC}: ${late.length} snapshots at the late frames; ${all.length - current.length} revised in all, ` +
    `${superseded} of them in the table with revised rows\n`);
});

// The whole fleet at the end of the run (five spacecraft: the demo flight, the faulty one, the
// star-tracker defects, the new and the late-frame ones): every row as esg reports it, worst first.
test('fleet overview of the whole fleet: every row as esg reports, the worst first, on a 1600x900 screen', async () => {
  await page.setViewport({ width: 1600, height: 900 });
  try {
    await open('esg:root/esg:fleet');
    const n = (await cliJson('status')).sessions.length;
    await page.waitForFunction((count) => document.querySelectorAll('tr[data-spacecraft]').length === count,
      { timeout: 20_000 }, n);
    const rows = await fleetRows();
    await checkFleet(rows);
    assert.equal(rows[rows.length - 1].attention, 'NOMINAL');
    assert.ok(['CRITICAL', 'DISTRESS'].includes(rows[0].attention), rows[0].attention);
    // The table fits the view: no column cut at 1600 px.
    const overflow = await page.$eval('table.esg-fleet', (t) => t.getBoundingClientRect().right - t.closest('.esg-view').getBoundingClientRect().right);
    assert.ok(overflow <= 0, `the fleet table overflows by ${overflow} px`);
    await shot('fleet', 900, 1600);
  } finally {
    await page.setViewport({ width: 1500, height: 900 });
  }
});

// docs/discovery.md's worked example: the model (model1.json) lacks gyro 2's rotor displacement.
// Diagnosed on esgd, the report offers "Apply to the model"; confirmed, esgd stores the
// configuration with the freed coefficients and re-runs the archive, as `esg status` shows.
// Clicks the report's Apply button as found when clicked: the view may be drawn again between a
// wait for the button and a click on the element that wait returned (Open MCT re-shows a view
// when the tree reloads), which detached it.
async function clickApply() {
  await page.waitForSelector('.esg-apply-button:not([disabled])', { timeout: 20_000 });
  await page.$eval('.esg-apply-button', (button) => button.click());
}

test('a diagnosis is applied to the model from its report after a confirmation, as esg status then shows; a read-only token is not offered the button; the MODEL_DIAGNOSED alert links to its diagnosis', async () => {
  const SC = 'DISC-1';
  const model1 = path.join(tmp, 'model1.json');
  fs.writeFileSync(model1, JSON.stringify({
    spacecraftId: SC,
    gyros: [
      { id: 1, caseToBody: [1, 0, 0, 0, 1, 0, 0, 0, 1], model: { k0DegH: 0.25 }, modelSigma: { k0DegH: 0.3 } },
      { id: 2, caseToBody: [0, 0, -1, 0, 1, 0, 1, 0, 0], model: { k0DegH: -0.18 }, modelSigma: { k0DegH: 0.3 } },
      { id: 3, caseToBody: [0, -1, 0, 1, 0, 0, 0, 0, 1], model: { k0DegH: 0.31 }, modelSigma: { k0DegH: 0.3 } },
      { id: 4, caseToBody: [0, 0, 1, 1, 0, 0, 0, 1, 0], model: { k0DegH: 0.2 }, modelSigma: { k0DegH: 0.3 } },
    ],
    workingPair: [1, 2], reservePair: [1, 3],
    starTracker: { noiseArcsec: [5, 5, 30] }, readoutNoiseArcsec: 3, randomWalkDegHSqrtH: 0.0015,
  }));
  const displaced = path.join(tmp, 'displaced.json');
  fs.writeFileSync(displaced, JSON.stringify({
    profile: 'mixed', profileSeed: 3, gyros: [{ id: 2, rotorDisplacementUm: [0.8, -1.0, 0.6] }],
    starTracker: { outlierRate: 0.01, outlierArcmin: 1, outages: [{ startHours: 5, endHours: 6 }] },
  }));
  const recording = path.join(tmp, 'displaced.csv');
  await esg(['simulate', '--config', model1, '--scenario', displaced, '--hours', '12', '--seed', '3',
    '--out', recording]);
  await cli('configure', '--config', model1);
  await cli('replay', '--recording', recording, '--wait');
  // esgd diagnoses the mismatch itself (docs/service.md "Automatic diagnosis"): the diagnosis is
  // listed and shown as automatic, answering the MODEL_INCONSISTENT alert, and its MODEL_DIAGNOSED
  // alert is in the alert list.
  let automatic;
  await timed(`automatic diagnosis of ${SC}`, async () => {
    for (let i = 0; i < 600 && !automatic; i++) {
      const listed = (await cliJson('diagnoses', 'list', '--spacecraft', SC)).diagnoses || [];
      automatic = listed.find((d) => d.requestedBy === 'service');
      if (!automatic) await sleep(200);
    }
  });
  assert.ok(automatic, `no automatic diagnosis of ${SC}`);
  let followUp;
  for (let i = 0; i < 100 && !followUp; i++) {
    followUp = (await cliJson('alerts', '--spacecraft', SC)).alerts
      .find((a) => a.reason === 'ALERT_REASON_MODEL_DIAGNOSED');
    if (!followUp) await sleep(200);
  }
  assert.ok(followUp, 'no MODEL_DIAGNOSED alert');
  assert.equal(Number(followUp.value), Number(automatic.id));
  assert.equal(Number(followUp.threshold), Number(automatic.answersAlert));
  const answered = (await cliJson('alerts', '--spacecraft', SC)).alerts
    .find((a) => Number(a.sequence) === Number(automatic.answersAlert));
  assert.equal(answered.reason, 'ALERT_REASON_MODEL_INCONSISTENT');
  assert.match(followUp.message, new RegExp(`answers alert #${automatic.answersAlert} \\(MODEL_INCONSISTENT ${answered.subsystem} at `));
  await open(`esg:root/esg:sc~${SC}/esg:diags~${SC}/esg:diag~${SC}~${automatic.id}`);
  await page.waitForSelector('.esg-automatic', { timeout: 20_000 });
  assert.equal(await page.$eval('.esg-automatic', (p) => p.dataset.answersAlert), String(automatic.answersAlert));
  await open('faults.taxonomy:faultManagement.view');
  await page.waitForFunction((text) => [...document.querySelectorAll('.c-fault-mgmt__list')]
    .some((li) => li.querySelector('.c-fault-mgmt__list-faultname')?.textContent.trim() === text),
  { timeout: 20_000 }, `MODEL_DIAGNOSED #${followUp.sequence}`);
  // The alert leads to its diagnosis: selected in the fault view, its inspector tab "Diagnosis"
  // links to the report; the health panel's line of the active alert links there too.
  const row = await page.waitForFunction((text) => [...document.querySelectorAll('.c-fault-mgmt__list')]
    .find((li) => li.querySelector('.c-fault-mgmt__list-faultname')?.textContent.trim() === text),
  { timeout: 20_000 }, `MODEL_DIAGNOSED #${followUp.sequence}`);
  await (await row.evaluateHandle((li) => li.querySelector('.c-fault-mgmt__list-checkbox input'))).click();
  const inspectorTab = await page.waitForFunction(() => [...document.querySelectorAll('.c-inspector__tab')]
    .find((t) => t.title === 'Diagnosis'), { timeout: 20_000 });
  await inspectorTab.click();
  const faultLink = await page.waitForSelector('.esg-fault-diagnosis a.esg-diagnosis-link', { timeout: 20_000 });
  assert.equal(await faultLink.evaluate((a) => a.dataset.diagnosis), String(automatic.id));
  await faultLink.click();
  await page.waitForSelector('.esg-automatic', { timeout: 20_000 });
  assert.equal(await page.$eval('.esg-automatic', (p) => p.dataset.answersAlert), String(automatic.answersAlert));
  assert.match(await page.evaluate(() => location.hash), new RegExp(`esg:diag~${SC}~${automatic.id}$`));
  await open(`esg:root/esg:sc~${SC}/esg:health~${SC}`);
  const healthLink = await page.waitForSelector(
    `.esg-health [data-alert="${followUp.sequence}"] a.esg-diagnosis-link`, { timeout: 20_000 });
  assert.equal(await healthLink.evaluate((a) => a.dataset.diagnosis), String(automatic.id));
  await healthLink.click();
  await page.waitForSelector('.esg-automatic', { timeout: 20_000 });
  assert.match(await page.evaluate(() => location.hash), new RegExp(`esg:diag~${SC}~${automatic.id}$`));
  const diagnosis = await timed(`esg diagnose --spacecraft ${SC}`, () => cliJson('diagnose', '--spacecraft', SC));
  assert.equal(diagnosis.verdict, 'rotor_displacement');
  assert.ok(diagnosis.applies && diagnosis.applies.length > 0, JSON.stringify(diagnosis.applies));
  // A token without the write role sees what applying would set, not the button (esgd would
  // refuse the call: PERMISSION_DENIED).
  const viewer = await browser.newPage(); // a tab of its own: its own sessionStorage, its own sign-in
  try {
    await viewer.setViewport({ width: 1500, height: 900 });
    await viewer.goto(`${gateway.url}#/browse/esg:root/esg:sc~${SC}/esg:diags~${SC}/esg:diag~${SC}~${diagnosis.id}`,
      { waitUntil: 'domcontentloaded' });
    await viewer.waitForSelector('#esg-signin:not([hidden])', { timeout: 20_000 });
    await viewer.type('#esg-token', viewerToken);
    await viewer.click('#esg-signin-submit');
    await viewer.waitForSelector('.esg-apply-read-only', { timeout: 20_000 });
    assert.equal(await viewer.$('.esg-apply-button'), null, 'a read-only token is offered Apply');
    assert.match(await viewer.$eval('.esg-apply-read-only', (p) => p.textContent),
      new RegExp(`needs the write role.*esg model apply --spacecraft ${SC} --diagnosis ${diagnosis.id}`));
    assert.deepEqual(await viewer.$$eval('.esg-apply li', (lis) => lis.map((li) => li.textContent)), diagnosis.applies);
  } finally {
    await viewer.close();
  }
  await open(`esg:root/esg:sc~${SC}/esg:diags~${SC}/esg:diag~${SC}~${diagnosis.id}`);
  // The page showed the automatic diagnosis's report, which has an Apply button too: wait for
  // this one's report before its button (the old report's matched, then went with its view).
  await page.waitForFunction((title) => [...document.querySelectorAll('.esg-diagnosis h2')]
    .map((h) => h.textContent).join('|') === title, { timeout: 20_000 }, `Diagnosis ${diagnosis.id} of ${SC}`);
  await page.waitForSelector('.esg-apply-button', { timeout: 20_000 });
  // What it would set, as esgd says (the same lines as esg diagnoses show).
  const offered = await page.$$eval('.esg-apply li', (lis) => lis.map((li) => li.textContent));
  assert.deepEqual(offered, diagnosis.applies);
  // Cancelled: nothing changes.
  await clickApply();
  await page.waitForSelector('#esg-apply-dialog');
  await page.click('#esg-apply-cancel');
  await page.waitForFunction(() => !document.getElementById('esg-apply-dialog'));
  const held = (await cliJson('status', '--spacecraft', SC)).config.gyros.find((g) => g.id === 2);
  assert.ok(!['c1x', 'c1y', 'c1z'].some((t) => coef(held.modelSigma, t) > 0), JSON.stringify(held));
  // Confirmed: applied, the result on the page.
  await clickApply();
  await page.waitForSelector('#esg-apply-dialog');
  const dialog = await page.$eval('#esg-apply-dialog', (d) => d.textContent);
  assert.match(dialog, /rotor_displacement \(gyro 2\)/);
  await page.click('#esg-apply-ok');
  await page.waitForFunction(() => /Applied as configuration version 2/.test(
    document.querySelector('.esg-apply-result').textContent), { timeout: 20_000 });
  await shot('diagnosis_apply', 1350);
  const status = await cliJson('status', '--spacecraft', SC);
  const gyro2 = status.config.gyros.find((g) => g.id === 2);
  assert.deepEqual(['c1x', 'c1y', 'c1z'].map((t) => coef(gyro2.modelSigma, t)), [0.1, 0.1, 0.1]);
  assert.deepEqual(['c2x', 'c2y', 'c2z'].map((t) => coef(gyro2.modelSigma, t)), [0.1, 0.1, 0.1]);
  // Applied again (the report opened anew), the same diagnosis is refused: the configuration
  // changed since.
  await open('esg:root/esg:fleet');
  await page.waitForSelector('table.esg-fleet', { timeout: 20_000 });
  await open(`esg:root/esg:sc~${SC}/esg:diags~${SC}/esg:diag~${SC}~${diagnosis.id}`);
  // The report is fetched while esgd re-runs the archive under the applied configuration (the
  // apply's own work), so it is given 60 s; a timeout says which answers the page lacked.
  try {
    await page.waitForSelector('.esg-apply-button:not([disabled])', { timeout: 60_000 });
  } catch (err) {
    throw new Error(`${err.message}\n${apiRequestsReport()}`);
  }
  await clickApply();
  await page.waitForSelector('#esg-apply-dialog');
  await page.click('#esg-apply-ok');
  await page.waitForFunction(() => /Not applied: .*changed since/.test(
    document.querySelector('.esg-apply-result').textContent), { timeout: 20_000 });
});
