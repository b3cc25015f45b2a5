// The health panel of one spacecraft (its summary layout's first panel): the filter state, the
// sensor health, the attitude 1-sigma now, the drift model's consistency, the last diagnosis and
// every active alert, worst first. The same words and colours as the fleet overview; refreshed
// when esgd pushes an alert or an estimate of the spacecraft, not polled.
import { apiFetch } from './api.js';
import { el, shortName, STYLE } from './dom.js';
import { alertDiagnosis } from './keys.js';
import {
  FLEET_STYLE, LEVEL_NAMES, SEVERITIES, alertSeverity, attention, diagnosisCell, healthCell, minute,
  modelCell, sigmaCell, words
} from './fleetView.js';
import { live } from './live.js';

const REFRESH_MIN_MS = 1000;

const HEALTH_STYLE = `
.esg-health { font-size: 12px; }
.esg-health th { text-align: left; padding: 2px 8px 2px 4px; }
.esg-health td { padding: 2px 6px; white-space: normal; }
.esg-health .alerts div { white-space: nowrap; overflow: hidden; text-overflow: ellipsis; max-width: 330px; }
.esg-health td.num { text-align: left; }
.esg-health .alerts td { white-space: normal; }
.esg-health h2 { margin: 0 0 4px; }
.esg-view:has(.esg-health) { padding: 4px 6px; }
`;

function diagnosisLink(diagnosis) {
  return el('a', { class: 'esg-diagnosis-link', href: diagnosis.hash, 'data-diagnosis': String(diagnosis.id) },
    `diagnosis #${diagnosis.id}`);
}

function render(container, entry, alerts) {
  const s = entry.session;
  const level = attention(entry);
  const state = shortName(s.state, 'SESSION_STATE_');
  const active = alerts.filter((a) => !a.cleared && !a.revised_time)
    .sort((a, b) => SEVERITIES.indexOf(alertSeverity(a)) - SEVERITIES.indexOf(alertSeverity(b)) ||
      (b.measurement_time || '').localeCompare(a.measurement_time || ''));
  const line = (label, cell) => el('tr', {}, el('th', {}, label), cell);
  container.replaceChildren(
    el('style', {}, STYLE + FLEET_STYLE + HEALTH_STYLE),
    el('table', { class: 'esg-fleet esg-health', 'data-spacecraft': s.spacecraft_id, 'data-attention': LEVEL_NAMES[level] },
      el('tbody', {},
        el('tr', { class: `attention-${level}` }, el('td', { class: 'name', colspan: 2 },
          el('span', { class: 'id' }, s.spacecraft_id), ` ${state}`,
          el('span', { class: 'muted' }, s.working_pair && s.working_pair.length ? `, output pair [${s.working_pair.join(',')}]` : ', no output pair',
            s.last_frame_time ? `, last frame ${minute(s.last_frame_time)}` : ''))),
        line('Sensor health', healthCell(s)),
        line(el('span', {}, '1-sigma now [arcsec]'), sigmaCell(s)),
        line('Drift model', modelCell(s)),
        line('Last diagnosis', diagnosisCell(entry.last_diagnosis)),
        line(`Active alerts (${active.length})`, el('td', { class: 'alerts', 'data-active-alerts': String(active.length) },
          active.length === 0 ? el('span', { class: 'muted' }, 'none') : null,
          active.map((a) => el('div', { 'data-alert': a.sequence, title: a.message },
            el('span', { class: `sev-${alertSeverity(a)}` }, alertSeverity(a)),
            ` ${words(shortName(a.reason, 'ALERT_REASON_'))}`,
            // A MODEL_DIAGNOSED alert leads to the diagnosis it answers with.
            ...(alertDiagnosis(a) ? [': ', diagnosisLink(alertDiagnosis(a))] : []),
            ` (${a.subsystem})`,
            el('span', { class: 'muted' }, ` since ${minute(a.first_time)}${a.acknowledged ? ', acknowledged' : ''}`))))))));
}

export function healthViewProvider() {
  return {
    key: 'esg.health.view',
    name: 'Spacecraft health',
    cssClass: 'icon-object',
    canView: (domainObject) => domainObject.type === 'esg.health',
    view(domainObject) {
      const sc = domainObject.esg.spacecraft;
      let container = null;
      let unsubscribes = [];
      let timer = null;
      let last = 0;
      async function refresh() {
        last = Date.now();
        try {
          const [fleet, alerts] = await Promise.all([apiFetch('/api/fleet'),
            apiFetch(`/api/spacecraft/${encodeURIComponent(sc)}/alerts`)]);
          const entry = fleet.fleet.find((e) => e.session.spacecraft_id === sc);
          if (!container) return;
          if (!entry) container.replaceChildren(el('p', { class: 'notice' }, `${sc}: no such session`));
          else render(container, entry, alerts.alerts);
        } catch (err) {
          if (container) container.replaceChildren(el('p', { class: 'notice' }, `${sc}: ${err.message}`));
        }
      }
      function schedule() {
        if (timer) return;
        timer = setTimeout(() => { timer = null; refresh(); }, Math.max(0, last + REFRESH_MIN_MS - Date.now()));
      }
      return {
        show(element) {
          container = el('div', { class: 'esg-view' }, `Loading ${sc}...`);
          element.append(container);
          refresh();
          unsubscribes = [
            live.subscribe('alerts', sc, null, schedule, undefined, schedule),
            live.subscribe('estimates', sc, null, schedule, () => {})
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
