// What each telemetry point of the console is made of: the fields cut from esgd's messages
// (CoefficientSnapshot, EstimateRecord, PredictResponse samples), with their units, and the
// Open MCT metadata (domain: UTC time; ranges: the plotted values) of the objects built on them.

const TIME = { key: 'utc', source: 'utc', name: 'Time (UTC)', format: 'utc', hints: { domain: 1 } };

// The drift model of one gyro, eq. (1), (8), (9), (10): the fixed terms of estimator/model_terms.h
// in theta order, checked row for row against it by tests/estimator/model_terms_test.cc (a plain
// module cannot read the C++ table). Each row: label, the GyroDriftModel JSON key and the
// component in it (-1: the key holds a number), the term's key, what the term is; case frame k,
// deg/h. Each entry also has its telemetry key (the label in lower case) and get(model), the value
// from a GyroDriftModel message: its keyed entry in `coefficients` (docs/formats.md; what esgd
// writes), otherwise its deprecated field as the release before wrote it (proto field names:
// "c1DegH" is read as c1_deg_h); 0 when the message has neither (a term added after the fields
// has none).
export const COEFFICIENTS = [
  ['k0', 'k0DegH', -1, 'k0', '4th shape harmonic'],
  ['C11', 'c1DegH', 0, 'c1x', 'rotor displacement (1st harmonic)'],
  ['C12', 'c1DegH', 1, 'c1y', 'rotor displacement (1st harmonic)'],
  ['C13', 'c1DegH', 2, 'c1z', 'rotor displacement (1st harmonic)'],
  ['C21', 'c2DegH', 0, 'c2x', 'rotor displacement (3rd harmonic)'],
  ['C22', 'c2DegH', 1, 'c2y', 'rotor displacement (3rd harmonic)'],
  ['C23', 'c2DegH', 2, 'c2z', 'rotor displacement (3rd harmonic)'],
  ['mu12', 'muDegH', 0, 'mu12', 'unequal stiffness'],
  ['mu23', 'muDegH', 1, 'mu23', 'unequal stiffness'],
  ['mu31', 'muDegH', 2, 'mu31', 'unequal stiffness'],
  ['nu23', 'nuDegH', 0, 'nu23', 'unequal stiffness'],
  ['nu31', 'nuDegH', 1, 'nu31', 'unequal stiffness'],
  ['nu12', 'nuDegH', 2, 'nu12', 'unequal stiffness']
].map(([label, jsonKey, component, term, meaning]) => {
  const field = jsonKey.replace(/[A-Z]/g, (c) => `_${c.toLowerCase()}`);
  const get = (m) => {
    const keyed = (m.coefficients || []).find((c) => c.term === term);
    if (keyed) return keyed.value_deg_h;
    const value = m[field] === undefined || component < 0 ? m[field] : m[field][component];
    return value === undefined ? 0 : value;
  };
  return { key: label.toLowerCase(), label, jsonKey, component, term, meaning, get };
});

const AXES = ['x', 'y', 'z'];
const DEG_H = { unit: 'deg/h', formatString: '%.5f' };
const ARCSEC = { unit: 'arcsec', formatString: '%.3f' };

function range(key, name, units, priority = 1) {
  return { key, source: key, name, ...units, hints: { range: priority } };
}

// Table columns carry the unit in their title (the unit columns are hidden).
function column(key, name, units, priority) {
  return range(key, units.unit ? `${name} [${units.unit}]` : name, units, priority);
}

// One snapshot -> one datum: value, 1-sigma, value+sigma, value-sigma of every coefficient.
export function snapshotDatum(snapshot) {
  const datum = { utc: Date.parse(snapshot.measurement_time) };
  for (const c of COEFFICIENTS) {
    const value = c.get(snapshot.model);
    const sigma = c.get(snapshot.sigma);
    datum[c.key] = value;
    datum[`${c.key}_sigma`] = sigma;
    // For the log-scale plot of the 1-sigma: Open MCT's log mode is log10(1 + |x|), flat below 1.
    datum[`${c.key}_sigma_mdeg`] = sigma * 1000;
    datum[`${c.key}_hi`] = value + sigma;
    datum[`${c.key}_lo`] = value - sigma;
  }
  return datum;
}

// A snapshot of the history with the revised ones (include_revised): the same datum, and when a
// re-run over a late frame superseded it, the wall-clock time it did ("" on a current snapshot).
export function revisedSnapshotDatum(snapshot) {
  const datum = snapshotDatum(snapshot);
  datum.revised = snapshot.revised_time ? snapshot.revised_time.replace('T', ' ') : '';
  return datum;
}

const REVISED = { key: 'revised', source: 'revised', name: 'Revised at (UTC)', format: 'string' };

// withRevised: the table of the history with the revised snapshots, "Revised at" after the time.
export function coefficientTableValues(withRevised = false) {
  const values = withRevised ? [TIME, REVISED] : [TIME];
  COEFFICIENTS.forEach((c, i) => {
    values.push(column(c.key, c.label, DEG_H, 2 * i + 1));
    values.push(column(`${c.key}_sigma`, `${c.label} 1-sigma`, DEG_H, 2 * i + 2));
  });
  return values;
}

export const BANDS = {
  value: { suffix: '', label: '' },
  hi: { suffix: '_hi', label: ' +1-sigma' },
  lo: { suffix: '_lo', label: ' -1-sigma' }
};

// Per-step estimate -> datum: the attitude 1-sigma about the body axes and its +/- envelope, the
// quaternion, the attitude error estimate of the step's star-tracker update with its 1-sigma, and
// each gyro's star-tracker innovation components with their 1-sigma.
export function estimateDatum(record) {
  const datum = {
    utc: Date.parse(record.measurement_time),
    state: (record.state || '').replace(/^SESSION_STATE_/, ''),
    pair: (record.output_pair || []).join(','),
    star_tracker_used: record.star_tracker_used ? 'yes' : 'no',
    test_ratio: record.star_tracker_test_ratio
  };
  addAttitude(datum, record.attitude);
  addAttitudeError(datum, record);
  for (const innovation of record.star_tracker_innovations || []) {
    for (let i = 0; i < 2; i++) {
      const prefix = `g${innovation.gyro_id}_z${i + 1}`;
      const z = innovation.innovation_arcsec[i];
      const s = innovation.sigma_arcsec[i];
      datum[prefix] = z;
      datum[`${prefix}_sigma`] = s;
      datum[`${prefix}_hi`] = s;
      datum[`${prefix}_lo`] = -s;
    }
  }
  return datum;
}

// The attitude's 1-sigma envelope is drawn about zero (+sigma, -sigma per body axis): the
// estimate itself is the centre, its error is within the envelope with 68 % probability.
function addAttitude(datum, attitude) {
  if (!attitude) return;
  AXES.forEach((axis, i) => {
    const s = attitude.sigma_arcsec[i];
    datum[`s${axis}`] = s;
    datum[`s${axis}_hi`] = s;
    datum[`s${axis}_lo`] = -s;
  });
  (attitude.q_in_b || []).forEach((q, i) => { datum[`q${i}`] = q; });
}

// The attitude error estimate (EstimateRecord.attitude_error_b_arcsec): the correction the step's
// star-tracker update applied to the attitude, about the body axes, i.e. the error the output had
// accumulated on the gyros since the previous update; with its 1-sigma (the part of the attitude
// 1-sigma the update removed). Drawn like an innovation: the estimate, and +sigma and -sigma about
// zero, so a consistent filter keeps about 68 % of the points inside the envelope. Steps without a
// star-tracker update have none (their fields are left out).
function addAttitudeError(datum, record) {
  const error = record.attitude_error_b_arcsec || [];
  const sigma = record.attitude_error_sigma_b_arcsec || [];
  if (error.length !== 3 || sigma.length !== 3) return;
  AXES.forEach((axis, i) => {
    datum[`e${axis}`] = error[i];
    datum[`e${axis}_sigma`] = sigma[i];
    datum[`e${axis}_hi`] = sigma[i];
    datum[`e${axis}_lo`] = -sigma[i];
  });
}

export function predictDatum(sample, source) {
  const datum = { utc: Date.parse(sample.time), source };
  addAttitude(datum, sample);
  return datum;
}

export function attitudeTableValues(extra = []) {
  const values = [TIME];
  AXES.forEach((axis, i) => values.push(column(`s${axis}`, `1-sigma body ${axis}`, ARCSEC, i + 1)));
  for (let i = 0; i < 4; i++) {
    values.push(range(`q${i}`, `q${i}`, { formatString: '%.9f' }, 10 + i));
  }
  return values.concat(extra);
}

export const ESTIMATE_EXTRA = [
  { key: 'state', source: 'state', name: 'Session state', format: 'string' },
  { key: 'pair', source: 'pair', name: 'Output pair', format: 'string' },
  { key: 'star_tracker_used', source: 'star_tracker_used', name: 'Star tracker used', format: 'string' },
  range('test_ratio', 'Largest normalised innovation', { formatString: '%.3f' }, 20)
];

export function attitudeErrorTableValues() {
  const values = [TIME];
  AXES.forEach((axis, i) => {
    values.push(column(`e${axis}`, `Attitude error body ${axis}`, ARCSEC, 2 * i + 1));
    values.push(column(`e${axis}_sigma`, `Attitude error body ${axis} 1-sigma`, ARCSEC, 2 * i + 2));
  });
  values.push({ key: 'star_tracker_used', source: 'star_tracker_used', name: 'Star tracker used', format: 'string' });
  return values;
}

export const PREDICT_EXTRA = [
  { key: 'source', source: 'source', name: 'Attitude source', format: 'string' }
];

export function innovationTableValues(gyros) {
  const values = [TIME];
  let priority = 1;
  for (const g of gyros) {
    for (const i of [1, 2]) {
      values.push(column(`g${g}_z${i}`, `gyro ${g} z${i}`, ARCSEC, priority++));
      values.push(column(`g${g}_z${i}_sigma`, `gyro ${g} z${i} 1-sigma`, ARCSEC, priority++));
    }
  }
  return values;
}

// The metadata of a single plotted series: time and one value. Every such series has the same
// key ("value", read from the datum's field `field`): an overlay plot labels its y axis only
// when all its series share the key.
// unit null: no unit (a marker whose value only places it).
export function singleSeriesValues(field, name, unit) {
  const units = unit === 'deg/h' ? DEG_H : unit === null ? { formatString: '%.1f' }
    : unit === '0.001 deg/h' ? { unit, formatString: '%.2f' } : ARCSEC;
  return [TIME, { ...range('value', name, units), source: field }];
}

export { AXES, TIME };
