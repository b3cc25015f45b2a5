// Telemetry provider of the esg.telemetry objects. History comes from the gateway's REST
// endpoints over the time conductor's bounds; real time from esgd's SubscribeEstimates pushed over
// the WebSocket. Coefficient snapshots have no subscription RPC: each new per-step estimate of a
// spacecraft is the trigger to fetch the snapshots stored since the last one we have. After a
// re-run of the filter (revisions.js) the open views are read again and the followers step back
// to where the re-run started.
import { apiFetch, isoTime, query, sharedFetch } from './api.js';
import { live } from './live.js';
import { PREDICT_SOURCES, TELEMETRY_TYPE } from './objects.js';
import { planSamples } from './plan.js';
import { estimateDatum, predictDatum, revisedSnapshotDatum, snapshotDatum } from './series.js';

// Predictions are sampled so that a request over any span returns about this many points.
const PREDICT_SAMPLES = 400;
const MIN_PREDICT_STEP_S = 10;

function spacecraftPath(sc) {
  return `/api/spacecraft/${encodeURIComponent(sc)}`;
}

// Every item of a paged list (`what`: "history" for its snapshots, "estimates"): the gateway
// answers at most 50 000 snapshots or 20 000 estimates per request, with a next_page_token to go
// on from (docs/console-gateway.md "Large answers").
async function pagedAll(spacecraft, what, field, params) {
  const items = [];
  let pageToken;
  do {
    const body = await sharedFetch(`${spacecraftPath(spacecraft)}/${what}${query({
      ...params, page_token: pageToken
    })}`);
    for (const item of body[field]) items.push(item);
    pageToken = body.next_page_token;
  } while (pageToken);
  return items;
}

const historyAll = (spacecraft, params) => pagedAll(spacecraft, 'history', 'snapshots', params);

const requesters = {
  async coef({ spacecraft, gyro }, { start, end }) {
    const snapshots = await historyAll(spacecraft, { gyro, from: isoTime(start), to: isoTime(end) });
    return snapshots.map(snapshotDatum);
  },

  // The same with the snapshots re-runs superseded, marked with the time they were.
  async coefrev({ spacecraft, gyro }, { start, end }) {
    const snapshots = await historyAll(spacecraft, {
      gyro, from: isoTime(start), to: isoTime(end), include_revised: true
    });
    return snapshots.map(revisedSnapshotDatum);
  },

  async est({ spacecraft }, { start, end }) {
    const estimates = await pagedAll(spacecraft, 'estimates', 'estimates', {
      from: isoTime(start), to: isoTime(end)
    });
    return estimates.map(estimateDatum);
  },

  // PredictAttitude over the conductor's bounds: recorded samples up to the last archived frame,
  // then the spacecraft's planned attitude (plan.js) or, without one, an inertial hold of the
  // last estimate; each sample's source in words ("recorded", "planned", "inertial hold").
  async pred(esg, bounds) {
    const body = await predict(esg, bounds);
    const recorded = body.recorded_samples || 0;
    const later = (body.attitude_source || '').replace(/^ATTITUDE_SOURCE_/, '');
    const words = (source) => PREDICT_SOURCES[source]?.words ?? source.toLowerCase().replace(/_/g, ' ');
    return body.samples.map((s, i) => predictDatum(s, words(i < recorded ? 'RECORDED' : later)));
  },

  // Where the samples of one source begin, as a vertical line across the plotted 1-sigma (two
  // points 1 ms apart, from the smallest to the largest 1-sigma of the samples): RECORDED at the
  // first sample, PLANNED or INERTIAL_HOLD at the first sample after the last archived frame.
  async predmark(esg, bounds) {
    const body = await predict(esg, bounds);
    const recorded = body.recorded_samples || 0;
    const later = (body.attitude_source || '').replace(/^ATTITUDE_SOURCE_/, '');
    const sigmas = body.samples.flatMap((s) => s.sigma_arcsec || []).filter((v) => v > 0);
    if (sigmas.length === 0) return [];
    let first = -1;
    if (esg.mark === 'RECORDED' && recorded > 0) first = 0;
    if (esg.mark === later && recorded < body.samples.length) first = recorded;
    if (first < 0) return [];
    const t = Date.parse(body.samples[first].time);
    return [{ utc: t, mark: Math.min(...sigmas) }, { utc: t + 1, mark: Math.max(...sigmas) }];
  }
};

// PredictAttitude over the conductor's bounds: recorded samples up to the last archived frame,
// then the spacecraft's planned attitude (plan.js) or, without one, an inertial hold of the last
// estimate. The plot's series and markers share one GET (sharedFetch).
async function predict({ spacecraft }, { start, end }) {
  const step = Math.max(MIN_PREDICT_STEP_S, Math.ceil((end - start) / 1000 / PREDICT_SAMPLES));
  const plan = planSamples(spacecraft);
  if (!plan) {
    return sharedFetch(`${spacecraftPath(spacecraft)}/predict${query({
      from: isoTime(start), to: isoTime(end), step_s: step
    })}`);
  }
  const body = { from: isoTime(start), to: isoTime(end), step_s: step, planned_attitude: plan };
  const key = `${spacecraft}\u0000${JSON.stringify(body)}`;
  if (!plannedInflight.has(key)) {
    plannedInflight.set(key, apiFetch(`${spacecraftPath(spacecraft)}/predict`, { method: 'POST', body })
      .finally(() => plannedInflight.delete(key)));
  }
  return plannedInflight.get(key);
}

// Requests with a plan in flight, shared like sharedFetch's GETs.
const plannedInflight = new Map();

// One estimate subscription per spacecraft, shared by every object that listens to it.
const estimateFeeds = new Map(); // spacecraft -> {listeners:Set, unsubscribe}

function subscribeEstimates(spacecraft, listener) {
  let feed = estimateFeeds.get(spacecraft);
  if (!feed) {
    feed = { listeners: new Set(), unsubscribe: null };
    feed.unsubscribe = live.subscribe('estimates', spacecraft, null,
      (record) => feed.listeners.forEach((l) => l(record)),
      (error) => {
        // UNIMPLEMENTED (no per-step estimates in this esgd) or the stream ended: no live updates.
        console.warn(`esg: estimates of ${spacecraft}: ${error.code} ${error.message}`);
        estimateFeeds.delete(spacecraft);
      });
    estimateFeeds.set(spacecraft, feed);
  }
  feed.listeners.add(listener);
  return () => {
    feed.listeners.delete(listener);
    if (feed.listeners.size === 0) {
      feed.unsubscribe();
      estimateFeeds.delete(spacecraft);
    }
  };
}

// The coefficient followers of each spacecraft, so a re-run can move them back.
const followers = new Map(); // spacecraft -> Set of rewind(ms)

// New coefficient snapshots of one gyro after `lastTime`, fetched when an estimate arrives; one
// fetch at a time per gyro, so a burst of estimates costs one request. `lastTime` starts at the
// session's last frame: the historical request covers what came before. A re-run moves it back
// to the re-run's start, where the snapshots are new again. `toDatum` makes the datum of the
// table or plot being followed (new snapshots are current ones).
function coefficientFollower({ spacecraft, gyro }, callback, toDatum) {
  let lastTime = null;
  let busy = false;
  let again = false;
  const rewind = (ms) => {
    if (lastTime !== null) lastTime = Math.min(lastTime, ms - 1);
  };
  const started = apiFetch('/api/sessions').then((body) => {
    const info = body.sessions.find((s) => s.spacecraft_id === spacecraft);
    lastTime = info && info.last_frame_time ? Date.parse(info.last_frame_time) : 0;
  });
  async function fetchNew() {
    if (busy) {
      again = true;
      return;
    }
    busy = true;
    try {
      await started;
      const snapshots = await historyAll(spacecraft, { gyro, from: isoTime(lastTime + 1) });
      for (const s of snapshots) {
        const datum = toDatum(s);
        if (datum.utc <= lastTime) continue;
        lastTime = datum.utc;
        callback(datum);
      }
    } catch (err) {
      console.warn(`esg: coefficient update of ${spacecraft} gyro ${gyro}: ${err.message}`);
    } finally {
      busy = false;
      if (again) {
        again = false;
        fetchNew();
      }
    }
  }
  if (!followers.has(spacecraft)) followers.set(spacecraft, new Set());
  followers.get(spacecraft).add(rewind);
  const unsubscribe = subscribeEstimates(spacecraft, () => fetchNew());
  return () => {
    const set = followers.get(spacecraft);
    set.delete(rewind);
    if (set.size === 0) followers.delete(spacecraft);
    unsubscribe();
  };
}

// A re-run of the filter of `spacecraft` from `fromMs` on (revisions.js): the coefficient
// followers step back to it. Returns whether the page shows live views of that spacecraft
// (which then need reading again).
export function rewindAfterRevision(spacecraft, fromMs) {
  for (const rewind of followers.get(spacecraft) || []) rewind(fromMs);
  return estimateFeeds.has(spacecraft);
}

// Open MCT answers a failed request with "see console for details"; the operator needs esgd's or
// the gateway's own words (e.g. "history: this operator already has 4 large answers running and
// 32 waiting ..."), so they are shown once per distinct message.
let notify = () => {};
const shown = new Set();
export function setNotifier(openmct) {
  notify = (message) => {
    if (shown.has(message)) return;
    shown.add(message);
    setTimeout(() => shown.delete(message), 10_000);
    openmct.notifications.error(message);
  };
}

export const telemetryProvider = {
  supportsRequest(domainObject) {
    return domainObject.type === TELEMETRY_TYPE;
  },
  supportsSubscribe(domainObject) {
    return domainObject.type === TELEMETRY_TYPE && !['pred', 'predmark'].includes(domainObject.esg.source);
  },
  async request(domainObject, options) {
    try {
      return await requesters[domainObject.esg.source](domainObject.esg, options);
    } catch (err) {
      notify(`${domainObject.name}: ${err.message}`);
      throw err;
    }
  },
  subscribe(domainObject, callback) {
    const esg = domainObject.esg;
    if (esg.source === 'coef') return coefficientFollower(esg, callback, snapshotDatum);
    if (esg.source === 'coefrev') return coefficientFollower(esg, callback, revisedSnapshotDatum);
    return subscribeEstimates(esg.spacecraft, (record) => callback(estimateDatum(record)));
  }
};
