// Re-runs of esgd's filter (a late frame within the reorder window, docs/service.md "Several
// ground stations"; or a configuration replaced) as the page learns of them from esgd's pushes:
//   - a per-step estimate measured at or before the newest one of its spacecraft: esgd applies
//     frames in time order and sends the steps a re-run recomputes again, so only a re-run does
//     that (the newest starts at the session's latest attitude when the page read it);
//   - an alert pushed with revised_time set: a re-run superseded it.
// What the re-run superseded (coefficient snapshots, alerts) is kept by esgd marked revised; the
// per-step estimates after the re-run's start are rewritten. The page's views of that spacecraft
// then show the values of before the re-run, so on each re-run the views are read again
// (telemetry.js), the engineer is told, and the superseded snapshots stay in the "coefficients
// with revised rows" tables. A re-run pushes its steps and revised alerts in bursts: the page
// reacts once they pause for a second (at most 5 s after the first, for a long re-run).
import { onFleet } from './fleetFeed.js';
import { sessions } from './sessions.js';
import { rewindAfterRevision } from './telemetry.js';

const QUIET_MS = 1000;
const MAX_WAIT_MS = 5000;

// onRevision(spacecraftId, fromMs): called once per re-run (fromMs: the earliest measurement time
// the pushes showed recomputed or revised).
export function watchRevisions(onRevision) {
  const newest = new Map(); // spacecraft -> newest measurement time of its estimates seen [ms]
  const pending = new Map(); // spacecraft -> {from, first, timer}

  sessions().then((list) => {
    for (const s of list) {
      const t = Date.parse(s.latest_attitude && s.latest_attitude.time);
      if (!newest.has(s.spacecraft_id) && Number.isFinite(t)) newest.set(s.spacecraft_id, t);
    }
  }, () => {});

  function revised(spacecraft, from) {
    let p = pending.get(spacecraft);
    if (!p) {
      p = { from, first: Date.now(), timer: null };
      pending.set(spacecraft, p);
    }
    p.from = Math.min(p.from, from);
    clearTimeout(p.timer);
    const wait = Math.max(0, Math.min(QUIET_MS, p.first + MAX_WAIT_MS - Date.now()));
    p.timer = setTimeout(() => {
      pending.delete(spacecraft);
      onRevision(spacecraft, p.from);
    }, wait);
  }

  onFleet('estimate', (record) => {
    const t = Date.parse(record.measurement_time);
    if (!Number.isFinite(t)) return;
    const before = newest.get(record.spacecraft_id);
    if (before !== undefined && t <= before) revised(record.spacecraft_id, t);
    else newest.set(record.spacecraft_id, t);
  });

  onFleet('alert', (alert) => {
    if (!alert.revised_time) return;
    const t = Date.parse(alert.first_time || alert.measurement_time);
    revised(alert.spacecraft_id, Number.isFinite(t) ? t : 0);
  });
}

// "2019-03-01 02:00Z": the minute is enough to find the place in a plot.
function minute(ms) {
  return `${new Date(ms).toISOString().slice(0, 16).replace('T', ' ')}Z`;
}

// The page's reaction to a re-run: the coefficient followers step back; when views of that
// spacecraft are open, every view is emptied and read again over the same time bounds (Open
// MCT's plots and tables reload on a change of bounds; emptied first, because a plot keeps the
// points it has at a time it is sent again), and the engineer is told, in a notification kept in
// the list.
export function installRevisions(openmct) {
  watchRevisions((spacecraft, fromMs) => {
    if (!rewindAfterRevision(spacecraft, fromMs)) return;
    openmct.objectViews.emit('clearData');
    openmct.time.setBounds(openmct.time.getBounds());
    openmct.notifications.alert(`${spacecraft}: esgd re-ran the filter from ${minute(fromMs)} ` +
      '(measurement time; a late frame or a replaced configuration): the coefficients, per-step ' +
      'estimates and alerts after it were recomputed and the views read again. The superseded ' +
      'coefficients are in each gyro\'s "coefficients with revised rows" table.');
  });
}
