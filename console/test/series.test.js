// The console's reading of a GyroDriftModel (console/plugin/series.js COEFFICIENTS get): a
// coefficient from its field, or from its keyed entry in `coefficients` (docs/formats.md), as esgd
// sends either in proto field names; 0 when the message has neither. No esgd needed.
//   node --test console/test/series.test.js
'use strict';

const { test } = require('node:test');
const assert = require('node:assert/strict');
const path = require('node:path');
const { pathToFileURL } = require('node:url');

const SERIES = pathToFileURL(path.join(__dirname, '..', 'plugin', 'series.js')).href;

// A GyroDriftModel as esgd writes it (the gateway prints defaults): every field, no keyed entry.
function fieldModel() {
  return {
    k0_deg_h: 0.25, c1_deg_h: [0.01, -0.02, 0.03], c2_deg_h: [0.04, -0.05, 0.06],
    mu_deg_h: [0.07, -0.08, 0.09], nu_deg_h: [0.1, -0.11, 0.12], coefficients: [],
  };
}
const FIELD_VALUES = [
  0.25, 0.01, -0.02, 0.03, 0.04, -0.05, 0.06, 0.07, -0.08, 0.09, 0.1, -0.11, 0.12,
];

test('each coefficient is read from its field, in theta order', async () => {
  const { COEFFICIENTS } = await import(SERIES);
  assert.deepEqual(COEFFICIENTS.map((c) => c.get(fieldModel())), FIELD_VALUES);
});

test('a keyed coefficient is read from its entry, the others from their fields', async () => {
  const { COEFFICIENTS } = await import(SERIES);
  const m = fieldModel();
  delete m.c1_deg_h;
  m.coefficients = [{ term: 'c1z', value_deg_h: 1.5 }, { term: 'c1x', value_deg_h: -2.5 },
    { term: 'c1y', value_deg_h: 0.125 }];
  const expected = [...FIELD_VALUES];
  expected.splice(1, 3, -2.5, 0.125, 1.5);
  assert.deepEqual(COEFFICIENTS.map((c) => c.get(m)), expected);
});

test('every coefficient keyed, none in fields, reads the same values', async () => {
  const { COEFFICIENTS } = await import(SERIES);
  const keyed = COEFFICIENTS.map((c, i) => ({ term: c.term, value_deg_h: FIELD_VALUES[i] }));
  const m = { coefficients: keyed.reverse() };
  assert.deepEqual(COEFFICIENTS.map((c) => c.get(m)), FIELD_VALUES);
  assert.deepEqual(COEFFICIENTS.map((c) => c.get({ coefficients: [] })), FIELD_VALUES.map(() => 0));
});
