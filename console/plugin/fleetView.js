// Fleet overview: one row per spacecraft from GET /api/fleet (ListSessions, the alert replay, the
// newest diagnosis and the newest per-step estimate), the spacecraft needing attention first.
// Refreshed when esgd pushes an alert or an estimate, not polled.
import { apiFetch } from './api.js';
import { duration, el, fixed, shortName, STYLE } from './dom.js';
import { live } from './live.js';

export const SEVERITIES = ['CRITICAL', 'DISTRESS', 'WARNING', 'INFO'];
const REFRESH_MIN_MS = 1000;

// How much a row needs attention, 0 (nothing) to 4, in the alerts' severity words: the worse of
// the session's own condition and its worst active alert.
export const LEVEL_NAMES = ['NOMINAL', 'INFO', 'WARNING', 'DISTRESS', 'CRITICAL'];
const SEVERITY_LEVEL = { INFO: 1, WARNING: 2, DISTRESS: 3, CRITICAL: 4 };

export const words = (code) => (code || '').toLowerCase().replace(/_/g, ' ');
export const minute = (iso) => (iso ? `${iso.slice(0, 16).replace('T', ' ')}Z` : '-');

export function alertSeverity(alert) {
  return alert ? shortName(alert.severity, 'ALERT_SEVERITY_') : '';
}

// The model-consistency monitor: inconsistent when its latest test failed or the filter runs
// widened (esgd then reports consistent = false).
function modelCondition(s) {
  const m = s.model_consistency;
  if (!m) return 'untested';
  return m.consistent ? 'consistent' : 'inconsistent';
}

function sessionLevel(s) {
  const state = shortName(s.state, 'SESSION_STATE_');
  if (state === 'FAULTED' || state === 'QUARANTINED') return 4;
  if (s.degraded) return 3;
  if (modelCondition(s) === 'inconsistent' || state === 'AUTONOMOUS') return 2;
  if (state === 'NO_DATA' || state === 'CALIBRATING') return 1;
  return 0;
}

export function attention(entry) {
  return Math.max(sessionLevel(entry.session), SEVERITY_LEVEL[alertSeverity(entry.worst_alert)] || 0);
}

const activeCount = (entry) => SEVERITIES.reduce((n, sev) => n + ((entry.open_alerts || {})[sev] || 0), 0);

// Worst first: attention, then the worst alert's severity, then the number of active alerts,
// then the spacecraft id.
export function sortWorstFirst(fleet) {
  return [...fleet].sort((a, b) => attention(b) - attention(a) ||
    (SEVERITY_LEVEL[alertSeverity(b.worst_alert)] || 0) - (SEVERITY_LEVEL[alertSeverity(a.worst_alert)] || 0) ||
    activeCount(b) - activeCount(a) ||
    a.session.spacecraft_id.localeCompare(b.session.spacecraft_id));
}

// A muted second line; a first argument that is a plain object adds attributes.
function sub(...children) {
  const attrs = children.length && children[0] && children[0].constructor === Object ? children.shift() : {};
  return el('div', { ...attrs, class: 'muted sub' }, ...children);
}

// Sensor health, a dimension of its own beside the filter state.
export function healthCell(s) {
  const state = shortName(s.state, 'SESSION_STATE_');
  if (state === 'QUARANTINED') {
    return el('td', { class: 'wrap', 'data-health': 'quarantined' },
      el('div', { class: 'sev-CRITICAL' }, 'quarantined', s.rebuilding ? ', rebuilding from the archive' : ''),
      sub(s.quarantine_reason || 'no reason given'));
  }
  if (state === 'FAULTED') {
    return el('td', { 'data-health': 'faulted' },
      el('div', { class: 'sev-CRITICAL' }, 'faulted: no usable gyro pair'), sub('no attitude output'));
  }
  if (s.degraded) {
    const excluded = s.excluded_gyros || [];
    return el('td', { class: 'wrap', 'data-health': 'degraded', title: excluded.map((g) => g.message).join('\n') },
      el('div', { class: 'sev-DISTRESS' }, 'degraded: ',
        excluded.map((g, i) => el('span', { 'data-excluded-gyro': g.gyro_id, 'data-reason': g.reason },
          `${i ? ', ' : ''}gyro ${g.gyro_id} excluded (${words(g.reason)})`))),
      sub(excluded.length ? `since ${excluded.map((g) => minute(g.time)).join(', ')}; ` : '',
        'output on the clean pair'));
  }
  return el('td', { 'data-health': 'nominal' }, el('div', { class: 'ok' }, 'all running gyros in use'));
}

export function sigmaCell(s) {
  const sigma = s.latest_attitude && s.latest_attitude.sigma_arcsec;
  if (!sigma || sigma.length !== 3) return el('td', { 'data-sigma': '' }, el('span', { class: 'muted' }, 'no attitude'));
  return el('td', { class: 'num', 'data-sigma': sigma.join(' ') },
    sigma.map((v) => fixed(v, 1)).join(' / '));
}

export function modelCell(s) {
  const m = s.model_consistency;
  const condition = modelCondition(s);
  const widened = m && m.widened_drift_deg_h > 0 ? m.widened_drift_deg_h : 0;
  const attrs = { 'data-model': condition, 'data-widened': widened ? String(widened) : '' };
  if (condition === 'untested') return el('td', attrs, el('span', { class: 'muted' }, 'not tested yet'));
  if (condition === 'consistent') {
    return el('td', attrs, el('div', { class: 'ok' }, 'consistent'),
      sub(`${m.failing_tests} of ${m.tests} tests failed`));
  }
  return el('td', { ...attrs, title: `${m.channel}: ${fixed(m.value, 1)} against ${fixed(m.threshold, 1)} over ${m.window_steps} steps` },
    el('div', { class: 'sev-WARNING' }, widened ? 'inconsistent, filter widened' : 'inconsistent'),
    sub(widened ? `unmodelled drift ${fixed(widened, 3)} deg/h` : `${m.failing_tests} of ${m.tests} tests failed`));
}

export function diagnosisCell(d) {
  if (!d) return el('td', { 'data-verdict': '' }, el('span', { class: 'muted' }, 'none'));
  return el('td', { 'data-verdict': d.verdict },
    el('div', { class: d.verdict === 'none' ? 'ok' : 'verdict-small' }, d.verdict),
    sub(`#${d.id}, run ${minute(d.compute_time)}`));
}

// The worst active alert, and under it how many are active by severity: only the severities with
// active alerts are printed, each in its colour (no red zero).
function alertCell(entry) {
  const alert = entry.worst_alert;
  const counts = entry.open_alerts || {};
  const present = SEVERITIES.filter((sev) => counts[sev] > 0);
  const countLine = present.length
    ? sub('active: ', present.map((sev, i) => el('span', { class: `sev-${sev}`, 'data-severity': sev, 'data-count': counts[sev] },
      `${i ? ', ' : ''}${counts[sev]} ${sev}`)))
    : null;
  if (!alert) return el('td', { class: 'wrap', 'data-worst-alert': '', 'data-active': '0' }, el('span', { class: 'muted' }, 'none active'));
  const severity = alertSeverity(alert);
  return el('td', { class: 'wrap', 'data-worst-alert': shortName(alert.reason, 'ALERT_REASON_'), 'data-alert-severity': severity,
    'data-active': String(activeCount(entry)), title: alert.message },
  el('div', {}, el('span', { class: `sev-${severity}` }, severity), ` ${words(shortName(alert.reason, 'ALERT_REASON_'))} (${alert.subsystem})`),
  sub(`since ${minute(alert.first_time)}, ${alert.acknowledged ? `acknowledged by ${alert.acknowledged_by}` : 'not acknowledged'}`),
  countLine);
}

function row(entry) {
  const s = entry.session;
  const level = attention(entry);
  return el('tr', { 'data-spacecraft': s.spacecraft_id, 'data-attention': LEVEL_NAMES[level], class: `attention-${level}` },
    el('td', { class: 'name', 'data-last-frame': s.last_frame_time || '' },
      el('div', { class: 'id' }, s.spacecraft_id),
      sub(`last frame ${s.last_frame_time ? minute(s.last_frame_time) : '-'}`),
      sub({ 'data-star-tracker': '' }, entry.last_star_tracker_time
        ? `star tracker ${duration(entry.last_star_tracker_time, s.last_frame_time)} before it`
        : 'last star tracker: not available')),
    el('td', { 'data-state': shortName(s.state, 'SESSION_STATE_') }, shortName(s.state, 'SESSION_STATE_'),
      sub(s.working_pair && s.working_pair.length ? `output pair [${s.working_pair.join(',')}]` : 'no output pair')),
    healthCell(s),
    sigmaCell(s),
    modelCell(s),
    alertCell(entry),
    diagnosisCell(entry.last_diagnosis));
}

export const FLEET_STYLE = `
.esg-fleet td { vertical-align: top; padding: 4px 8px; }
.esg-fleet th { padding: 4px 8px; }
.esg-fleet td.wrap { white-space: normal; min-width: 170px; max-width: 240px; }
.esg-fleet td.name { border-left: 6px solid transparent; }
.esg-fleet td.name .id { font-weight: bold; font-size: 14px; }
.esg-fleet tr.attention-4 td.name { border-left-color: #ff4d4d; }
.esg-fleet tr.attention-3 td.name { border-left-color: #ff8c3a; }
.esg-fleet tr.attention-2 td.name { border-left-color: #ffd23f; }
.esg-fleet tr.attention-1 td.name { border-left-color: #6fc3ff; }
.esg-fleet tr.attention-0 td.name { border-left-color: #4caf50; }
.esg-fleet .sub { font-size: 11px; margin-top: 2px; }
.esg-fleet .ok { color: #8fd694; }
.esg-fleet .verdict-small { color: #ffd23f; }
`;

function render(container, fleet) {
  container.replaceChildren(
    el('style', {}, STYLE + FLEET_STYLE),
    el('h2', {}, 'Fleet overview ', el('span', { class: 'muted' }, '(needing attention first)')),
    el('table', { class: 'esg-fleet' },
      el('thead', {},
        el('tr', {},
          el('th', {}, 'Spacecraft', el('br'), 'last frame (UTC)'), el('th', {}, 'Filter state'), el('th', {}, 'Sensor health'),
          el('th', {}, 'Attitude 1-sigma now', el('br'), 'body x / y / z [arcsec]'), el('th', {}, 'Drift model'),
          el('th', {}, 'Worst active alert'), el('th', {}, 'Last diagnosis'))),
      el('tbody', {}, sortWorstFirst(fleet).map(row))),
    el('p', { class: 'muted' },
      'Active alerts: not yet cleared by esgd (acknowledged or not); cleared ones are in Fault Management. ',
      'Drift model: esgd\'s running chi-square test of the innovations; "filter widened" means the filter ',
      'added process noise (as an unmodelled drift) because the configured model does not explain the data: ',
      'run esg diagnose. "star tracker ... before": measurement time from the newest step that applied ',
      'the star tracker to the last frame (needs per-step estimates).'));
}

export function fleetViewProvider() {
  return {
    key: 'esg.fleet.view',
    name: 'Fleet overview',
    cssClass: 'icon-object',
    canView: (domainObject) => domainObject.type === 'esg.fleet',
    view() {
      let container = null;
      let unsubscribes = [];
      let timer = null;
      let last = 0;
      async function refresh() {
        last = Date.now();
        try {
          const body = await apiFetch('/api/fleet');
          if (container) render(container, body.fleet);
        } catch (err) {
          if (container) container.replaceChildren(el('p', { class: 'notice' }, `Fleet: ${err.message}`));
        }
      }
      // At most one refresh a second however fast alerts and estimates arrive.
      function schedule() {
        if (timer) return;
        timer = setTimeout(() => { timer = null; refresh(); }, Math.max(0, last + REFRESH_MIN_MS - Date.now()));
      }
      return {
        show(element) {
          container = el('div', { class: 'esg-view' }, 'Loading the fleet...');
          element.append(container);
          refresh();
          unsubscribes = [
            // The end-of-replay marker comes again after a reconnect: refresh then too.
            live.subscribe('alerts', '', null, schedule, undefined, schedule),
            live.subscribe('estimates', '', null, schedule, () => {})
          ];
        },
        destroy() {
          unsubscribes.forEach((u) => u());
          clearTimeout(timer);
          container = null;
        }
      };
    }
  };
}
