// The console's object tree (Open MCT object provider, namespace "esg"):
//   ESG spacecraft (root)
//     Fleet overview                         esg.fleet view
//     <spacecraft> (folder)
//       Drift coefficients gyro N (folder)   table of all coefficients + one plot per estimated
//                                            coefficient (value, +/-1-sigma) + the table with
//                                            the snapshots re-runs superseded (revisions.js)
//       Attitude 1-sigma envelope / table    per-step estimates (or esg.unavailable)
//       Attitude error body x, y, z / table  per-step estimates: the error estimate of each
//                                            star-tracker update with its +/-1-sigma
//       Innovations gyro N / table           per-step estimates (or esg.unavailable)
//       Predicted attitude envelope / table  PredictAttitude over the time conductor's bounds
//       Planned attitude for predictions     esg.plan editor
//       Diagnoses (folder)                   one esg.diagnosis report view each
// Objects are computed from the sessions on every get(); nothing is persisted. The root's children
// follow the sessions without a reload (tree.js).
import { apiFetch } from './api.js';
import { NAMESPACE, id, parseKey } from './keys.js';
import { estimatesAvailable, session, sessions } from './sessions.js';
import {
  AXES, BANDS, COEFFICIENTS, ESTIMATE_EXTRA, PREDICT_EXTRA, attitudeErrorTableValues,
  attitudeTableValues, coefficientTableValues, innovationTableValues, singleSeriesValues
} from './series.js';

export const TELEMETRY_TYPE = 'esg.telemetry';

// Band colours: the value bright, its 1-sigma band the same hue, dimmer, so the band reads as
// belonging to the curve.
const BAND_COLOURS = { value: '#4fb3ff', hi: '#9a6a2f', lo: '#9a6a2f' };
const AXIS_COLOURS = { x: '#ff6b6b', y: '#7bd389', z: '#4fb3ff' };
// The sources of predicted samples (PredictResponse.attitude_source without its ATTITUDE_SOURCE_
// prefix), each marked on the plot: `words` in the table (esg's words,
// proto/attitude_source_words.h), `marker` in the legend at the line where the source begins. The
// 1-sigma is continuous there: the recorded samples are the gyros' alone since a star-tracker
// fix, and the plan or the hold continues that run with its covariance carried across
// (docs/console.md, docs/physics.md "The prediction's envelope").
export const PREDICT_SOURCES = {
  RECORDED: {
    words: 'recorded',
    marker: 'recorded gyro readings from here (star tracker withheld: the gyros alone)',
    color: '#c8c8c8'
  },
  INERTIAL_HOLD: {
    words: 'inertial hold',
    marker: 'inertial hold from here, the 1-sigma carried on from the recorded readings',
    color: '#ff7fe0'
  },
  PLANNED: {
    words: 'planned',
    marker: 'planned attitude from here, the 1-sigma carried on from the recorded readings',
    color: '#ffd23f'
  }
};
const SIGMA_COLOURS = ['#4fb3ff', '#ff6b6b', '#7bd389', '#ffd23f', '#c58cff', '#ff9d4f', '#5fe0d0'];
const AXIS_DIM = { x: '#8a3a3a', y: '#3f7047', z: '#2a5f88' };

// Open MCT's plot legend, expanded, with the series' names only.
const EXPANDED_NAMES_ONLY = {
  expandByDefault: true, showTimestampWhenExpanded: false, showValueWhenExpanded: false,
  showMinimumWhenExpanded: false, showMaximumWhenExpanded: false, showUnitsWhenExpanded: false
};

function folder(identifier, name, composition, location) {
  return { identifier, name, type: 'folder', composition, location };
}

function telemetryObject(identifier, name, values, esg, location) {
  return { identifier, name, type: TELEMETRY_TYPE, telemetry: { values }, esg, location };
}

// An overlay plot with the series' colours fixed, lines joined, no point markers, and the
// quantity with its unit as the y-axis label.
// logMode: Open MCT's symmetric log scale of the y axis (a 1-sigma that spans decades).
// legendRows: the legend expanded, one row per series with its whole name and nothing else (for
// names that explain what the plot shows and would be cut in the one-line legend).
function overlay(identifier, name, series, location, yLabel, logMode = false, legendRows = false) {
  return {
    identifier,
    name,
    type: 'telemetry.plot.overlay',
    location,
    composition: series.map((s) => s.identifier),
    configuration: {
      yAxis: logMode ? { label: yLabel, logMode: true } : { label: yLabel },
      ...(legendRows ? { legend: EXPANDED_NAMES_ONLY } : {}),
      series: series.map((s) => ({
        identifier: s.identifier, color: s.color, interpolate: 'linear', markers: false
      }))
    }
  };
}

// A telemetry table of one object. The name column (always the same object) and the unit
// columns (the unit is in each column's title) are hidden to leave room for the numbers.
// Columns as wide as their content (scrolling sideways when they do not fit), not Open MCT's
// equal widths, which cut the time and the column titles at 1600 px.
function table(identifier, name, child, values, location, fitContent = true) {
  const hiddenColumns = { name: true };
  for (const v of values) if (v.unit) hiddenColumns[`${v.key}-unit`] = true;
  const configuration = { columnWidths: { utc: 200 }, hiddenColumns };
  if (fitContent) configuration.autosize = false;
  return { identifier, name, type: 'table', location, composition: [child], configuration };
}

function unavailable(identifier, name, location) {
  return { identifier, name, type: 'esg.unavailable', location };
}

function keyString(identifier) {
  return `${identifier.namespace}:${identifier.key}`;
}

// Coefficients estimated in the session's configuration (prior 1-sigma > 0): the others are
// held at their configured value and their plot would be a flat line.
function estimatedCoefficients(gyroConfig) {
  const sigma = gyroConfig.model_sigma;
  if (!sigma) return [];
  return COEFFICIENTS.filter((c) => {
    try {
      return c.get(sigma) > 0;
    } catch (err) {
      return false;
    }
  });
}

function gyroIds(info) {
  return ((info.config && info.config.gyros) || []).map((g) => g.id);
}

// The gyros that run: the configured working and reserve pairs. A cold spare outside both has no
// readings, hence no innovations.
export function runningGyros(info) {
  const config = info.config || {};
  const running = new Set([...(config.working_pair || []), ...(config.reserve_pair || [])]);
  return gyroIds(info).filter((g) => running.has(g));
}

function gyroConfig(info, gyro) {
  return info.config.gyros.find((g) => g.id === gyro);
}

// The root folder's children: the fleet overview, then one folder per spacecraft session.
export function rootComposition(list) {
  return [id('fleet'), ...list.map((s) => id('sc', s.spacecraft_id))];
}

const builders = {
  async root(identifier) {
    return folder(identifier, 'ESG spacecraft', rootComposition(await sessions()), 'ROOT');
  },

  async fleet(identifier) {
    return { identifier, name: 'Fleet overview', type: 'esg.fleet', location: keyString(id('root')) };
  },

  async sc(identifier, [sc]) {
    const info = await session(sc);
    const gyros = gyroIds(info);
    const running = runningGyros(info);
    return folder(identifier, sc, [
      id('summary', sc),
      id('health', sc),
      ...gyros.map((g) => id('coefs', sc, g)),
      id('attplot', sc),
      id('atttable', sc),
      ...AXES.map((axis) => id('errplot', sc, axis)),
      id('errtable', sc),
      ...running.map((g) => id('innovplot', sc, g)),
      id('innovtable', sc),
      id('predplot', sc),
      id('predtable', sc),
      id('plan', sc),
      id('diags', sc)
    ], keyString(id('root')));
  },

  // One screen per spacecraft: its health panel and attitude 1-sigma envelope, then k0 with its
  // 1-sigma band and the star-tracker innovations of each running gyro (Open MCT display layout,
  // 10 px grid; sized for the view pane of a 1600x900 screen with the tree and inspector open).
  async summary(identifier, [sc]) {
    const info = await session(sc);
    const running = runningGyros(info);
    const withEstimates = await estimatesAvailableFor(sc);
    const k0 = running.filter((g) => estimatedCoefficients(gyroConfig(info, g)).some((c) => c.key === 'k0'));
    const items = [];
    const place = (child, x, y, width, height) => items.push({
      type: 'subobject-view', identifier: child, x, y, width, height, hasFrame: true,
      fontSize: 'default', font: 'default', id: `${identifier.key}-${items.length}`
    });
    const TOP = 29;
    const ROW = 22;
    const FULL = 106;
    place(id('health', sc), 0, 0, 46, TOP);
    place(id('attplot', sc), 46, 0, FULL - 46, TOP);
    const rowOf = (list, y, make) => {
      const w = Math.floor(FULL / Math.max(1, list.length));
      list.forEach((g, i) => place(make(g), i * w, y, w, ROW));
    };
    rowOf(k0, TOP, (g) => id('coefplot', sc, g, 'k0'));
    if (withEstimates) rowOf(running, TOP + ROW, (g) => id('innovplot', sc, g));
    return {
      identifier,
      name: 'Summary',
      type: 'layout',
      location: keyString(id('sc', sc)),
      composition: items.map((item) => item.identifier),
      configuration: { items, layoutGrid: [10, 10], objectStyles: {} }
    };
  },

  async health(identifier, [sc]) {
    return { identifier, name: 'Health, alerts and last diagnosis', type: 'esg.health', esg: { spacecraft: sc },
      location: keyString(id('sc', sc)) };
  },

  async coefs(identifier, [sc, gyro]) {
    const info = await session(sc);
    const g = Number(gyro);
    const plots = estimatedCoefficients(gyroConfig(info, g)).map((c) => id('coefplot', sc, g, c.key));
    return folder(identifier, `Drift coefficients gyro ${g}`,
      [id('coeftable', sc, g), ...plots, id('coefsigplot', sc, g), id('coefrevtable', sc, g)], keyString(id('sc', sc)));
  },

  // The 1-sigma of every estimated coefficient of one gyro on a log scale: the band about a value
  // narrows to a hair at linear scale once the calibration converges; its width stays readable
  // here over decades. In 0.001 deg/h, since Open MCT's log mode is log10(1 + |x|): linear below 1.
  async coefsigplot(identifier, [sc, gyro]) {
    const info = await session(sc);
    const series = estimatedCoefficients(gyroConfig(info, Number(gyro))).map((c, i) => ({
      identifier: id('coefsig', sc, gyro, c.key), color: SIGMA_COLOURS[i % SIGMA_COLOURS.length]
    }));
    return overlay(identifier, `1-sigma of the coefficients of gyro ${gyro}`, series,
      keyString(id('coefs', sc, gyro)), '1-sigma [0.001 deg/h], log scale', true);
  },

  async coefsig(identifier, [sc, gyro, coef]) {
    const c = COEFFICIENTS.find((x) => x.key === coef);
    const label = `gyro ${gyro} ${c.label} 1-sigma`;
    return telemetryObject(identifier, label, singleSeriesValues(`${coef}_sigma_mdeg`, label, '0.001 deg/h'),
      { source: 'coef', spacecraft: sc, gyro: Number(gyro) }, keyString(id('coefsigplot', sc, gyro)));
  },

  // The coefficient history with what re-runs over late frames superseded: each snapshot once
  // current, and those a re-run replaced with the time it did, next to their replacement.
  async coefrevtable(identifier, [sc, gyro]) {
    // Both times in full: a superseded row and its replacement share the first.
    return table(identifier, `Gyro ${gyro} coefficients with revised rows`,
      id('coefrev', sc, gyro), coefficientTableValues(true), keyString(id('coefs', sc, gyro)), true);
  },

  async coefrev(identifier, [sc, gyro]) {
    return telemetryObject(identifier, `Gyro ${gyro} drift coefficients, current and revised`,
      coefficientTableValues(true), { source: 'coefrev', spacecraft: sc, gyro: Number(gyro) },
      keyString(id('coefs', sc, gyro)));
  },

  async coeftable(identifier, [sc, gyro]) {
    return table(identifier, `Gyro ${gyro} coefficients table`,
      id('coef', sc, gyro), coefficientTableValues(), keyString(id('coefs', sc, gyro)));
  },

  async coef(identifier, [sc, gyro]) {
    return telemetryObject(identifier, `Gyro ${gyro} drift coefficients`, coefficientTableValues(),
      { source: 'coef', spacecraft: sc, gyro: Number(gyro) }, keyString(id('coefs', sc, gyro)));
  },

  async coefplot(identifier, [sc, gyro, coef]) {
    const c = COEFFICIENTS.find((x) => x.key === coef);
    const series = Object.keys(BANDS).map((band) => ({
      identifier: id('coefband', sc, gyro, coef, band), color: BAND_COLOURS[band]
    }));
    return overlay(identifier, `${c.label} gyro ${gyro} with 1-sigma band`, series,
      keyString(id('coefs', sc, gyro)), c.key === 'k0' ? 'k0 [deg/h]' : `${c.label} [deg/h], gyro ${gyro} case frame`);
  },

  async coefband(identifier, [sc, gyro, coef, band]) {
    const c = COEFFICIENTS.find((x) => x.key === coef);
    const key = `${coef}${BANDS[band].suffix}`;
    return telemetryObject(identifier, `gyro ${gyro} ${c.label}${BANDS[band].label}`,
      singleSeriesValues(key, `${c.label}${BANDS[band].label}`, 'deg/h'),
      { source: 'coef', spacecraft: sc, gyro: Number(gyro) }, keyString(id('coefplot', sc, gyro, coef)));
  },

  async attplot(identifier, [sc]) {
    const name = 'Attitude 1-sigma envelope';
    if (!(await estimatesAvailableFor(sc))) return unavailable(identifier, name, keyString(id('sc', sc)));
    const series = [];
    for (const axis of AXES) {
      series.push({ identifier: id('estser', sc, `s${axis}_hi`), color: AXIS_COLOURS[axis] });
      series.push({ identifier: id('estser', sc, `s${axis}_lo`), color: AXIS_DIM[axis] });
    }
    return overlay(identifier, name, series, keyString(id('sc', sc)), '1-sigma [arcsec]');
  },

  async atttable(identifier, [sc]) {
    const name = 'Attitude 1-sigma table';
    if (!(await estimatesAvailableFor(sc))) return unavailable(identifier, name, keyString(id('sc', sc)));
    return table(identifier, name, id('est', sc), attitudeTableValues(ESTIMATE_EXTRA), keyString(id('sc', sc)));
  },

  async est(identifier, [sc]) {
    return telemetryObject(identifier, `${sc} per-step estimates`, attitudeTableValues(ESTIMATE_EXTRA),
      { source: 'est', spacecraft: sc }, keyString(id('atttable', sc)));
  },

  async estser(identifier, [sc, key]) {
    const label = seriesLabel(key);
    return telemetryObject(identifier, label, singleSeriesValues(key, label, 'arcsec'),
      { source: 'est', spacecraft: sc }, keyString(id('sc', sc)));
  },

  // The attitude error estimate about one body axis with its 1-sigma envelope (series.js): one
  // plot per axis, since the star tracker's noise about its boresight (body z) is several times
  // that about x and y.
  async errplot(identifier, [sc, axis]) {
    const name = `Attitude error body ${axis}`;
    if (!(await estimatesAvailableFor(sc))) return unavailable(identifier, name, keyString(id('sc', sc)));
    const series = [
      { identifier: id('estser', sc, `e${axis}`), color: AXIS_COLOURS[axis] },
      { identifier: id('estser', sc, `e${axis}_hi`), color: AXIS_DIM[axis] },
      { identifier: id('estser', sc, `e${axis}_lo`), color: AXIS_DIM[axis] }
    ];
    return overlay(identifier, name, series, keyString(id('sc', sc)),
      `attitude error estimate about body ${axis} [arcsec]`);
  },

  async errtable(identifier, [sc]) {
    const name = 'Attitude error table';
    if (!(await estimatesAvailableFor(sc))) return unavailable(identifier, name, keyString(id('sc', sc)));
    return table(identifier, name, id('err', sc), attitudeErrorTableValues(), keyString(id('sc', sc)));
  },

  async err(identifier, [sc]) {
    return telemetryObject(identifier, `${sc} attitude error estimates`, attitudeErrorTableValues(),
      { source: 'est', spacecraft: sc }, keyString(id('errtable', sc)));
  },

  async innovplot(identifier, [sc, gyro]) {
    const name = `Innovations gyro ${gyro}`;
    if (!(await estimatesAvailableFor(sc))) return unavailable(identifier, name, keyString(id('sc', sc)));
    // The components first, their 1-sigma lines after (drawn on top, lighter), so the band stays
    // visible over a dense cloud of innovations.
    const colours = { 1: ['#2f7fd0', '#a8d8ff'], 2: ['#d0801e', '#ffd9a0'] };
    const series = [];
    for (const i of [1, 2]) series.push({ identifier: id('estser', sc, `g${gyro}_z${i}`), color: colours[i][0] });
    for (const i of [1, 2]) {
      const k = `g${gyro}_z${i}`;
      series.push({ identifier: id('estser', sc, `${k}_hi`), color: colours[i][1] });
      series.push({ identifier: id('estser', sc, `${k}_lo`), color: colours[i][1] });
    }
    return overlay(identifier, name, series, keyString(id('sc', sc)), 'innovation [arcsec]');
  },

  async innovtable(identifier, [sc]) {
    const name = 'Innovations table';
    if (!(await estimatesAvailableFor(sc))) return unavailable(identifier, name, keyString(id('sc', sc)));
    const info = await session(sc);
    return table(identifier, name, id('innov', sc), innovationTableValues(runningGyros(info)), keyString(id('sc', sc)));
  },

  async innov(identifier, [sc]) {
    const info = await session(sc);
    return telemetryObject(identifier, `${sc} star-tracker innovations`,
      innovationTableValues(runningGyros(info)), { source: 'est', spacecraft: sc },
      keyString(id('innovtable', sc)));
  },

  // The predicted 1-sigma per body axis on a log scale (it spans decades across a gap), and a
  // vertical line where each source of the samples begins (PredictResponse: the recorded readings
  // up to the last archived frame, then the plan or the inertial hold), named in the legend: the
  // envelope goes on through the last archived frame, where the source changes.
  async predplot(identifier, [sc]) {
    const series = AXES.map((axis) => ({ identifier: id('predser', sc, `s${axis}`), color: AXIS_COLOURS[axis] }));
    for (const source of Object.keys(PREDICT_SOURCES)) {
      series.push({ identifier: id('predmark', sc, source), color: PREDICT_SOURCES[source].color });
    }
    return overlay(identifier, 'Predicted attitude 1-sigma',
      series, keyString(id('sc', sc)), 'predicted 1-sigma [arcsec], log scale', true, true);
  },

  async predmark(identifier, [sc, source]) {
    const label = PREDICT_SOURCES[source].marker;
    return telemetryObject(identifier, label, singleSeriesValues('mark', label, null),
      { source: 'predmark', spacecraft: sc, mark: source }, keyString(id('predplot', sc)));
  },

  async predtable(identifier, [sc]) {
    return table(identifier, 'Predicted attitude table', id('pred', sc), attitudeTableValues(PREDICT_EXTRA),
      keyString(id('sc', sc)));
  },

  async pred(identifier, [sc]) {
    return telemetryObject(identifier, `${sc} predicted attitude`, attitudeTableValues(PREDICT_EXTRA),
      { source: 'pred', spacecraft: sc }, keyString(id('predtable', sc)));
  },

  async predser(identifier, [sc, key]) {
    const label = seriesLabel(key);
    return telemetryObject(identifier, label, singleSeriesValues(key, label, 'arcsec'),
      { source: 'pred', spacecraft: sc }, keyString(id('predplot', sc)));
  },

  async plan(identifier, [sc]) {
    return { identifier, name: 'Planned attitude for predictions', type: 'esg.plan', esg: { spacecraft: sc },
      location: keyString(id('sc', sc)) };
  },

  async diags(identifier, [sc]) {
    const body = await loadDiagnosisSummaries(sc);
    // Newest first: the one an engineer just ran is at the top.
    const ids = body.diagnoses.map((d) => d.id).reverse();
    return folder(identifier, 'Diagnoses', ids.map((n) => id('diag', sc, n)), keyString(id('sc', sc)));
  },

  async diag(identifier, [sc, n]) {
    if (!diagnosisSummaries.has(`${sc}\u0000${n}`)) await loadDiagnosisSummaries(sc);
    const summary = diagnosisSummaries.get(`${sc}\u0000${n}`);
    const name = summary
      ? `Diagnosis ${n}: ${summary.verdict}${summary.requested_by === 'service' ? ', automatic' : ''} (${(summary.compute_time || '').slice(0, 16).replace('T', ' ')})`
      : `Diagnosis ${n}`;
    return { identifier, name, type: 'esg.diagnosis', esg: { spacecraft: sc, id: Number(n) },
      location: keyString(id('diags', sc)) };
  }
};

// The name of a plotted series from its datum field (series.js): s<axis>_hi / _lo for the attitude
// envelope, e<axis>[_hi|_lo] for the attitude error estimate and its band, g<gyro>_z<i>[_hi|_lo]
// for an innovation and its band.
function seriesLabel(field) {
  const band = field.endsWith('_hi') ? ' +1-sigma' : field.endsWith('_lo') ? ' -1-sigma' : '';
  const base = field.replace(/_(hi|lo)$/, '');
  const attitude = /^s([xyz])$/.exec(base);
  if (attitude) return band ? `${band.trim()} body ${attitude[1]}` : `body ${attitude[1]}`;
  const error = /^e([xyz])$/.exec(base);
  if (error) return `attitude error body ${error[1]}${band}`;
  const innovation = /^g(\d)_z(\d)$/.exec(base);
  if (innovation) return `gyro ${innovation[1]} z${innovation[2]}${band}`;
  return field;
}

// Summaries of the diagnoses seen in a list, so each one's name can carry its verdict.
const diagnosisSummaries = new Map();

async function loadDiagnosisSummaries(sc) {
  const body = await apiFetch(`/api/spacecraft/${encodeURIComponent(sc)}/diagnoses`);
  for (const d of body.diagnoses) diagnosisSummaries.set(`${sc}\u0000${d.id}`, d);
  return body;
}

async function estimatesAvailableFor(sc) {
  const info = await session(sc);
  return estimatesAvailable(sc, info.last_frame_time);
}

export const objectProvider = {
  async get(identifier) {
    const { kind, parts } = parseKey(identifier.key);
    const build = builders[kind];
    if (!build) throw new Error(`esg: unknown object ${identifier.key}`);
    return build({ namespace: NAMESPACE, key: identifier.key }, parts);
  }
};
