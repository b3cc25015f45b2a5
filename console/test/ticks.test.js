// Time ticks at round times on the console's time-series plots (docs/console.md "Time ticks",
// docs/decisions.md D113), in a real browser (Debian chromium through puppeteer-core) against a
// real esgd and the real gateway: RDK-1 fed with the demo's simulated flight (30 h, seed 1,
// `esg replay`). For the prediction plot and the k0 history of gyro 1 over spans of 20 min, 6 h
// and 2 days, the tick labels the page shows are read from the DOM: each stands at its time on the
// axis, consecutive ticks are one step apart, the step is in the round list and each tick's time
// is a multiple of it; the plot's vertical grid lines stand at the same times.
//   node --test console/test/ticks.test.js
// Environment: ESGD, ESG (default build/), CHROMIUM (default /usr/bin/chromium),
// ESG_TICKS_SHOTS=DIR to write a screenshot of each plot and span there (docs/console/*.png, made
// by browser.test.js, show the same ticks).
'use strict';

const { test, before, after } = require('node:test');
const assert = require('node:assert/strict');
const fs = require('node:fs');
const os = require('node:os');
const path = require('node:path');
const { pathToFileURL } = require('node:url');
const puppeteer = require('puppeteer-core');
const { REPO, startEsgd, startGateway, stop, esg } = require('./helpers');

const CHROMIUM = process.env.CHROMIUM || '/usr/bin/chromium';
const SHOT_DIR = process.env.ESG_TICKS_SHOTS || '';
const CONFIG = path.join(REPO, 'deploy', 'examples', 'rdk1.json');
const SCENARIOS = path.join(REPO, 'deploy', 'examples', 'scenarios');

const SECOND = 1000;
const MINUTE = 60 * SECOND;
const HOUR = 60 * MINUTE;
const DAY = 24 * HOUR;
// The round steps docs/console.md lists (below a second and beyond two weeks: 1, 2 or 5 times a
// power of ten of milliseconds or days). Written out here, not imported from the plugin.
const ROUND_STEPS = [
  1 * SECOND, 2 * SECOND, 5 * SECOND, 10 * SECOND, 15 * SECOND, 30 * SECOND,
  1 * MINUTE, 2 * MINUTE, 5 * MINUTE, 10 * MINUTE, 15 * MINUTE, 30 * MINUTE,
  1 * HOUR, 2 * HOUR, 3 * HOUR, 6 * HOUR, 12 * HOUR,
  1 * DAY, 2 * DAY, 7 * DAY, 14 * DAY,
];
// Weeks begin on Mondays (UTC); 1970-01-05 was one.
const MONDAY = 4 * DAY;
// Below a second and beyond two weeks: 1, 2 or 5 times a power of ten of milliseconds or days.
const oneTwoFive = (n) => /^[125]0*$/.test(String(n));
const isRound = (step) => ROUND_STEPS.includes(step) || (step < SECOND && oneTwoFive(step)) ||
  (step > 14 * DAY && step % DAY === 0 && oneTwoFive(step / DAY));
const TICKS = pathToFileURL(path.join(__dirname, '..', 'plugin', 'ticks.js')).href;

const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'esg-console-ticks-'));
let esgd;
let gateway;
let browser;
let page;
let last; // measurement time of the flight's last frame [ms]

const sleep = (ms) => new Promise((r) => setTimeout(r, ms));

async function shot(name) {
  if (!SHOT_DIR) return;
  fs.mkdirSync(SHOT_DIR, { recursive: true });
  await page.mouse.move(1, 880); // no hover toolbar or tooltip over the plot
  await sleep(1500);
  await page.screenshot({ path: path.join(SHOT_DIR, `ticks_${name}.png`) });
}

before(async () => {
  const flight = path.join(tmp, 'flight.csv');
  await esg(['simulate', '--config', CONFIG, '--profile', 'calibration', '--scenario',
    path.join(SCENARIOS, 'paper_calibration.json'), '--hours', '30', '--seed', '1', '--out', flight]);
  esgd = await startEsgd(['--db', path.join(tmp, 'esg.db'), '--sync', 'normal']);
  const cli = (...args) => esg(['--server', esgd.address, ...args]);
  await cli('configure', '--config', CONFIG, '--model', '10+11');
  await cli('replay', '--recording', flight, '--wait');
  const status = JSON.parse(await cli('status', '--spacecraft', 'RDK-1', '--json'));
  last = Date.parse((status.sessions ? status.sessions[0] : status).lastFrameTime);
  assert.ok(Number.isFinite(last));
  gateway = await startGateway(['--esgd', esgd.address]);
  browser = await puppeteer.launch({
    executablePath: CHROMIUM,
    headless: true,
    args: process.getuid && process.getuid() === 0 ? ['--no-sandbox'] : [],
  });
  page = await browser.newPage();
  await page.setViewport({ width: 1500, height: 900 });
  page.on('pageerror', (err) => process.stdout.write(`# page error: ${err.message}\n`));
  await page.goto(gateway.url, { waitUntil: 'domcontentloaded' });
  await page.waitForSelector('.l-shell', { timeout: 20_000 });
});

after(async () => {
  if (browser) await browser.close();
  if (gateway) await stop(gateway.child);
  if (esgd) await stop(esgd.child);
  fs.rmSync(tmp, { recursive: true, force: true });
});

// The time-axis tick labels and vertical grid lines each plot on the page shows (visible ones
// only), each with its position in percent of the plot's width from the left.
function visibleTicks() {
  return page.evaluate(() => {
    const shown = (el) => el.checkVisibility({ visibilityProperty: true });
    return [...document.querySelectorAll('.gl-plot')].map((plot) => ({
      labels: [...plot.querySelectorAll('.gl-plot-x .gl-plot-x-tick-label')].filter(shown)
        .map((el) => ({ text: el.textContent.trim(), full: el.getAttribute('aria-label'), left: parseFloat(el.style.left) })),
      grid: [...plot.querySelectorAll('.gl-plot-display-area .gl-plot-hash.hash-v')].filter(shown)
        .map((el) => 100 - parseFloat(el.style.right)),
    }));
  });
}

// Opens an object over [start, end] and waits until `plots` plots show time ticks. The first
// open of the run waited more than 20 s once (a full ctest run, the test alone on the machine;
// 18 s for the whole file when run again), so it is given 60 s; a timeout says what the page had.
async function open(browsePath, start, end, plots = 1) {
  await page.evaluate((hash) => { window.location.hash = hash; },
    `#/browse/${browsePath}?tc.mode=fixed&tc.startBound=${start}&tc.endBound=${end}&tc.timeSystem=utc`);
  try {
    await page.waitForFunction((n) => {
      const all = [...document.querySelectorAll('.gl-plot')];
      return all.length >= n && all.every((plot) => [...plot.querySelectorAll('.gl-plot-x .gl-plot-x-tick-label')]
        .filter((el) => el.checkVisibility({ visibilityProperty: true })).length >= 2);
    }, { timeout: 60_000 }, plots);
  } catch (err) {
    const seen = await page.evaluate(() => ({
      hash: window.location.hash,
      ticks: [...document.querySelectorAll('.gl-plot')].map((plot) =>
        plot.querySelectorAll('.gl-plot-x .gl-plot-x-tick-label').length),
      notices: [...document.querySelectorAll('.c-message, .esg-unavailable')].map((e) => e.textContent.trim()),
    }));
    throw new Error(`${err.message}: ${seen.ticks.length} plots of ${plots}, tick labels ` +
      `${JSON.stringify(seen.ticks)} (at ${seen.hash}; notices: ${JSON.stringify(seen.notices)})`);
  }
  await sleep(500); // the plots settle on their bounds
}

// Checks the ticks a plot shows over the time range [start, end] it spans; returns the step.
function checkTicks({ labels, grid }, start, end, what) {
  // Open MCT's utc format: "2026-11-26 08:00:00.000Z".
  const times = labels.map((x) => Date.parse(x.full.replace(' ', 'T')));
  const where = `${what}: ${labels.map((x) => x.full).join(', ')}`;
  assert.ok(times.length >= 2 && times.every(Number.isFinite), where);
  const step = times[1] - times[0];
  assert.ok(isRound(step), `step ${step / 1000} s is not a round one; ${where}`);
  const origin = step % (7 * DAY) === 0 ? MONDAY : 0;
  times.forEach((t, i) => {
    const tick = labels[i].full;
    assert.equal((t - origin) % step, 0, `tick ${tick} is not a multiple of ${step / 1000} s; ${where}`);
    if (i > 0) assert.equal(t - times[i - 1], step, `uneven ticks; ${where}`);
    assert.ok(t >= start && t <= end, `tick ${tick} outside the plot's range; ${where}`);
    // The label stands at its time on the axis, to 0.1 % of its width.
    const expected = (100 * (t - start)) / (end - start);
    assert.ok(Math.abs(labels[i].left - expected) < 0.1, `tick ${tick} at ${labels[i].left} %, its time at ${expected} %; ${what}`);
    // The text shown is part of the full time (the date at midnight, else the time of day).
    assert.ok(labels[i].full.includes(labels[i].text), `label "${labels[i].text}" of ${tick}`);
  });
  // No round tick of the step is left out within the range.
  assert.ok(times[0] - step < start && times[times.length - 1] + step > end, `ticks missing at an end; ${where}`);
  // The vertical grid lines at the same places as the labels.
  assert.equal(grid.length, labels.length, `grid lines ${grid.join(', ')}; ${where}`);
  grid.forEach((g, i) => assert.ok(Math.abs(g - labels[i].left) < 0.1, `grid line ${g} % against label ${labels[i].left} %; ${what}`));
  process.stdout.write(`# ${what}: step ${step / 1000} s, ticks ${labels.map((x) => x.text).join(' ')}\n`);
  return step;
}

// Bounds off round times (the flight ends on the hour).
const OFFSET = -37_250;
const PREDICTION = 'esg:root/esg:sc~RDK-1/esg:predplot~RDK-1';
const K0 = 'esg:root/esg:sc~RDK-1/esg:coefs~RDK-1~1/esg:coefplot~RDK-1~1~k0';

const SPANS = [
  { name: '20 min', ms: 20 * MINUTE },
  { name: '6 h', ms: 6 * HOUR },
  { name: '2 days', ms: 2 * DAY },
];

test('the prediction plot has time ticks at round times over 20 min, 6 h and 2 days', async () => {
  for (const span of SPANS) {
    // Across the last frame: recorded readings, then the inertial hold.
    const start = last - span.ms / 2 + OFFSET;
    const end = last + span.ms / 2 + OFFSET;
    await open(PREDICTION, start, end);
    checkTicks((await visibleTicks())[0], start, end, `prediction, ${span.name}`);
    await shot(`prediction_${span.name.replace(' ', '')}`);
  }
});

test('a coefficient history plot has time ticks at round times over 20 min, 6 h and 2 days', async () => {
  for (const span of SPANS) {
    const start = last - span.ms + OFFSET;
    const end = last + OFFSET;
    await open(K0, start, end);
    checkTicks((await visibleTicks())[0], start, end, `k0 gyro 1, ${span.name}`);
    await shot(`k0_${span.name.replace(' ', '')}`);
  }
});

test("zoomed in, a plot's ticks follow: round times over the zoomed range, a finer step", async () => {
  let start = last - 6 * HOUR + OFFSET;
  let end = last + OFFSET;
  await open(K0, start, end);
  const steps = [checkTicks((await visibleTicks())[0], start, end, 'k0 gyro 1, 6 h')];
  for (const zoom of [1, 2]) {
    // Open MCT's zoom button takes a fifth of the range off each end (MctPlot zoom('in', 0.2)).
    await page.$eval('.gl-plot .js-zoom .icon-plus', (button) => button.click());
    const cut = 0.2 * (end - start);
    start += cut;
    end -= cut;
    await page.waitForFunction((s) => [...document.querySelectorAll('.gl-plot-x .gl-plot-x-tick-label')]
      .filter((el) => el.checkVisibility({ visibilityProperty: true }))
      .every((el) => Date.parse(el.getAttribute('aria-label').replace(' ', 'T')) >= s), { timeout: 10_000 }, start);
    await sleep(300);
    steps.push(checkTicks((await visibleTicks())[0], start, end, `k0 gyro 1, zoomed in ${zoom}x`));
  }
  assert.ok(steps[2] < steps[0], `steps ${steps.join(', ')} ms`);
  await shot('k0_zoomed');
});

test('every plot of the summary layout has time ticks at round times, at least two on each', async () => {
  for (const hours of [6, 10]) {
    const start = last - hours * HOUR + OFFSET;
    const end = last + OFFSET;
    // The attitude 1-sigma envelope, k0 of the three running gyros and their innovations.
    await open('esg:root/esg:sc~RDK-1/esg:summary~RDK-1', start, end, 7);
    const plots = await visibleTicks();
    assert.equal(plots.length, 7);
    plots.forEach((plot, i) => checkTicks(plot, start, end, `summary plot ${i + 1}, ${hours} h`));
    await shot(`summary_${hours}h`);
  }
});

// The step rule of console/plugin/ticks.js alone (no page), over spans the plots above do not
// reach: a plot 1000 px wide, labels 6.5 px a character.
test('the step rule from 1.5 s to 400 days: round steps, at most 8 ticks, weeks on Mondays', async () => {
  const { chooseTicks } = await import(TICKS);
  const start = Date.UTC(2026, 10, 26, 7, 13, 17, 250);
  const expected = { 1.5e3: 500, 45e3: 10 * SECOND, 1.2e6: 5 * MINUTE, 2.16e7: HOUR, 1.728e8: 12 * HOUR,
    1.0368e9: 2 * DAY, 3.456e9: 7 * DAY, 3.456e10: 100 * DAY };
  for (const [span, step] of Object.entries(expected).map(([k, v]) => [Number(k), v])) {
    const chosen = chooseTicks(start, start + span, 1000, (text) => 6.5 * text.length);
    const times = chosen.ticks.map((x) => x.t);
    const where = `span ${span / 1000} s: step ${chosen.step / 1000} s, ${chosen.ticks.map((x) => x.text).join(' ')}`;
    assert.equal(chosen.step, step, where);
    assert.ok(isRound(step) && times.length >= 2 && times.length <= 8, where);
    const origin = step % (7 * DAY) === 0 ? MONDAY : 0;
    times.forEach((t, i) => {
      assert.equal((t - origin) % step, 0, where);
      assert.ok(t >= start && t <= start + span, where);
      if (i > 0) assert.equal(t - times[i - 1], step, where);
      if (origin) assert.equal(new Date(t).getUTCDay(), 1, `${new Date(t).toISOString()} is not a Monday`);
    });
    process.stdout.write(`# ${where}\n`);
  }
});
