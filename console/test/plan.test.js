// The console's planned attitude (console/plugin/plan.js parsePlan) reads its times as the service
// and esg do (console/plugin/time.js parseRfc3339, docs/cli.md "Time spans"): an RFC 3339 time
// with its zone; a time without one, a date alone or a day the month does not have is refused
// with its line, not read in the browser's time zone or rolled into the next month. No esgd.
//   node --test console/test/plan.test.js
'use strict';

const { test } = require('node:test');
const assert = require('node:assert/strict');
const path = require('node:path');
const { pathToFileURL } = require('node:url');

const PLAN = pathToFileURL(path.join(__dirname, '..', 'plugin', 'plan.js')).href;
const TIME = pathToFileURL(path.join(__dirname, '..', 'plugin', 'time.js')).href;

test('RFC 3339 times with a zone are read, to the millisecond', async () => {
  const { parseRfc3339 } = await import(TIME);
  assert.equal(parseRfc3339('2019-03-01T00:00:00Z'), Date.UTC(2019, 2, 1));
  assert.equal(parseRfc3339(' 2019-03-01 01:30:00.25+01:30 '), Date.UTC(2019, 2, 1, 0, 0, 0, 250));
  assert.equal(parseRfc3339('2019-03-01t00:00:00.123456789z'), Date.UTC(2019, 2, 1, 0, 0, 0, 123));
  assert.equal(parseRfc3339('2020-02-29T12:00:00-05:00'), Date.UTC(2020, 1, 29, 17));
});

test('a time without its zone, a date alone or an impossible date is not a time', async () => {
  const { parseRfc3339 } = await import(TIME);
  for (const text of ['2019-03-01T00:00:00', '2019-03-01', '2019-02-30T00:00:00Z',
    '2019-13-01T00:00:00Z', '2019-03-01T24:00:00Z', '2019-03-01T00:60:00Z', 'March 1, 2019',
    '1551398400', '', 'infinite-future', '2019-3-1T00:00:00Z']) {
    assert.ok(Number.isNaN(parseRfc3339(text)), text);
  }
});

test('a plan refuses a time it cannot read, naming the line', async () => {
  const { parsePlan } = await import(PLAN);
  const good = parsePlan('time,q0,q1,q2,q3\n2019-03-01T00:00:00Z,1,0,0,0\n2019-03-01T01:00:00+00:00,0,0,0,1\n');
  assert.deepEqual(good.map((s) => s.time), ['2019-03-01T00:00:00.000Z', '2019-03-01T01:00:00.000Z']);
  assert.throws(() => parsePlan('2019-03-01T00:00:00Z,1,0,0,0\n2019-03-01T02:00:00,1,0,0,0\n'),
    /^Error: line 2: '2019-03-01T02:00:00' is not an RFC 3339 time such as 2019-03-01T00:00:00Z$/);
  assert.throws(() => parsePlan('2019-02-30T00:00:00Z,1,0,0,0\n'), /line 1: '2019-02-30T00:00:00Z'/);
});
