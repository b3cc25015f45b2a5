// Fleet overview: one row per spacecraft from GET /api/fleet (ListSessions, the alert replay and
// the newest per-step estimate). Refreshed when esgd pushes an alert or an estimate, not polled.
import { apiFetch } from './api.js';
import { duration, el, shortName, STYLE } from './dom.js';
import { live } from './live.js';

const SEVERITIES = ['CRITICAL', 'DISTRESS', 'WARNING', 'INFO'];
const REFRESH_MIN_MS = 1000;

// Sensor health beside the state: a degraded session runs on a clean pair, its output valid.
function health(s) {
  if (!s.degraded) return [];
  const excluded = (s.excluded_gyros || [])
    .map((g) => `gyro ${g.gyro_id} excluded (${g.reason})`).join(', ');
  return [el('div', { class: 'sev-DISTRESS', 'data-health': 'degraded', title: (s.excluded_gyros || []).map((g) => g.message).join('\n') },
    `degraded: ${excluded || 'a gyro excluded'}; output from the clean pair`)];
}

function row(entry) {
  const s = entry.session;
  const alerts = SEVERITIES.map((sev) => el('td', { class: `num sev-${sev}`, 'data-severity': sev },
    String(entry.open_alerts ? entry.open_alerts[sev] : 0)));
  return el('tr', { 'data-spacecraft': s.spacecraft_id },
    el('td', {}, s.spacecraft_id),
    el('td', {}, shortName(s.state, 'SESSION_STATE_'), ...health(s)),
    el('td', {}, s.working_pair && s.working_pair.length ? `[${s.working_pair.join(',')}]` : '-'),
    el('td', {}, s.last_frame_time || '-'),
    ...alerts,
    el('td', {}, entry.last_star_tracker_time
      ? `${duration(entry.last_star_tracker_time, s.last_frame_time)} before the last frame`
      : 'not available'));
}

function render(container, fleet) {
  container.replaceChildren(
    el('style', {}, STYLE),
    el('h2', {}, 'Fleet overview'),
    el('table', { class: 'esg-fleet' },
      el('thead', {},
        el('tr', {},
          el('th', { rowspan: 2 }, 'Spacecraft'), el('th', { rowspan: 2 }, 'Session state'),
          el('th', { rowspan: 2 }, 'Output pair'), el('th', { rowspan: 2 }, 'Last frame (UTC)'),
          el('th', { colspan: 4 }, 'Open alerts'),
          el('th', { rowspan: 2 }, 'Last star-tracker correction')),
        el('tr', {}, ...SEVERITIES.map((sev) => el('th', { class: `sev-${sev}` }, sev)))),
      el('tbody', {}, fleet.map(row))),
    el('p', { class: 'muted' },
      'Open alerts: not yet cleared by esgd (acknowledged or not). Last star-tracker correction: ',
      'measurement time between the newest step that applied the star tracker and the last frame; ',
      'it needs per-step estimates (GetEstimateHistory) and reads "not available" without them.'));
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
