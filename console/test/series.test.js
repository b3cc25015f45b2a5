// The console's reading of a GyroDriftModel (console/plugin/series.js COEFFICIENTS get): a
// coefficient from its keyed entry in `coefficients` (docs/formats.md; what esgd writes), or from
// its deprecated field (what the release before wrote), in proto field names; 0 when the message
// has neither. No esgd needed.
//   node --test console/test/series.test.js
'use strict';

const { test } = require('node:test');
const assert = require('node:assert/strict');
const path = require('node:path');
const { pathToFileURL } = require('node:url');

const SERIES = pathToFileURL(path.join(__dirname, '..', 'plugin', 'series.js')).href;

// A GyroDriftModel as the release before wrote it (the gateway printed defaults): every field, no
// keyed entry.
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

test('an empty vector field (none given that way) reads 0, not undefined', async () => {
  const { COEFFICIENTS } = await import(SERIES);
  const m = { k0_deg_h: 0, c1_deg_h: [], c2_deg_h: [], mu_deg_h: [], nu_deg_h: [], coefficients: [] };
  assert.deepEqual(COEFFICIENTS.map((c) => c.get(m)), FIELD_VALUES.map(() => 0));
});

// The gateway's JSON of a drift model (console/gateway/convert.js, from the real .proto files):
// the keyed coefficients esgd writes, the deprecated fields left out while they hold nothing (as
// `esg --json` leaves them out); a model of the release before keeps its fields, and reads the same.
test('the gateway writes a drift model keyed and leaves its empty deprecated fields out', () => {
  const { Esgd } = require('../gateway/esgd.js');
  const esgd = new Esgd({ address: '127.0.0.1:1' });
  try {
    const keyed = esgd.convert.toJson('esg.v1.GyroDriftModel', {
      k0_deg_h: 0, c1_deg_h: [], c2_deg_h: [], mu_deg_h: [], nu_deg_h: [],
      coefficients: [{ term: 'k0', value_deg_h: 0.25 }, { term: 'c1y', value_deg_h: -0.5 }],
    });
    assert.deepEqual(keyed, {
      coefficients: [{ term: 'k0', value_deg_h: 0.25 }, { term: 'c1y', value_deg_h: -0.5 }],
    });
    const older = esgd.convert.toJson('esg.v1.GyroDriftModel', {
      k0_deg_h: 0.25, c1_deg_h: [0, -0.5, 0], c2_deg_h: [], mu_deg_h: [], nu_deg_h: [],
      coefficients: [],
    });
    assert.deepEqual(older, { k0_deg_h: 0.25, c1_deg_h: [0, -0.5, 0], coefficients: [] });
    // A field that is not deprecated keeps its default (every field present, docs/console-gateway.md).
    const snapshot = esgd.convert.toJson('esg.v1.CoefficientSnapshot', { gyro_id: 0 });
    assert.equal(snapshot.gyro_id, 0);
  } finally {
    esgd.close();
  }
});
