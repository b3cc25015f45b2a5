// The children of the root folder "ESG spacecraft" (the fleet overview and one folder per
// spacecraft), kept in step with esgd's sessions without a reload and without polling. esgd has
// no push for a new session, but every alert and per-step estimate it pushes names its
// spacecraft: one the page does not know makes it read the sessions again (at most once a
// second) and announce the new folders through Open MCT's composition API, where the tree and any
// view of the root folder add them like the ones read at load. A reconnect of the WebSocket (its
// end-of-replay marker) reads them again too, for what was configured while it was down.
import { NAMESPACE, id } from './keys.js';
import { onFleet } from './fleetFeed.js';
import { rootComposition } from './objects.js';
import { reloadSessions, sessions } from './sessions.js';

const REREAD_MIN_MS = 1000;

function isRoot(identifier) {
  return identifier.namespace === NAMESPACE && identifier.key === 'root';
}

// The composition provider of the root folder (registered before Open MCT's default one, which
// only reads the object's own `composition` and cannot be changed here: nothing is persisted).
export function makeSpacecraftTree() {
  const known = new Set(); // spacecraft ids the root's children were last given with
  const listeners = { add: [], remove: [], reorder: [] };
  let timer = null;
  let last = 0;
  let reading = false;
  let again = false;

  function notify(event, identifier) {
    for (const l of listeners[event]) l.callback.call(l.context, identifier);
  }

  // Reads the sessions and announces the folders added and removed since the last read.
  async function reread() {
    if (reading) {
      again = true;
      return;
    }
    reading = true;
    last = Date.now();
    try {
      const ids = new Set((await reloadSessions()).map((s) => s.spacecraft_id));
      const added = [...ids].filter((sc) => !known.has(sc));
      const removed = [...known].filter((sc) => !ids.has(sc));
      known.clear();
      ids.forEach((sc) => known.add(sc));
      added.forEach((sc) => notify('add', id('sc', sc)));
      removed.forEach((sc) => notify('remove', id('sc', sc)));
    } catch (err) {
      console.warn(`esg: reading the spacecraft again: ${err.message}`);
    } finally {
      reading = false;
      if (again) {
        again = false;
        schedule();
      }
    }
  }

  function schedule() {
    if (timer) return;
    timer = setTimeout(() => { timer = null; reread(); }, Math.max(0, last + REREAD_MIN_MS - Date.now()));
  }

  function seen(spacecraftId) {
    if (spacecraftId && !known.has(spacecraftId)) schedule();
  }

  return {
    appliesTo: (domainObject) => isRoot(domainObject.identifier),

    async load() {
      const list = await sessions();
      known.clear();
      list.forEach((s) => known.add(s.spacecraft_id));
      return rootComposition(list);
    },

    on(domainObject, event, callback, context) {
      listeners[event].push({ callback, context });
    },

    off(domainObject, event, callback, context) {
      const i = listeners[event].findIndex((l) => l.callback === callback && l.context === context);
      if (i >= 0) listeners[event].splice(i, 1);
    },

    includes(parent, childId) {
      return childId.key === id('fleet').key || [...known].some((sc) => id('sc', sc).key === childId.key);
    },

    // The spacecraft are esgd's: an operator configures one with `esg configure`, not by dragging
    // an object into the folder.
    add() {
      throw new Error('ESG spacecraft: configure a spacecraft with esg configure');
    },
    remove() {
      throw new Error('ESG spacecraft: the folders follow the sessions of esgd');
    },
    reorder() {},

    // Listens to every spacecraft's alerts and per-step estimates for the rest of the page's life.
    watch() {
      onFleet('alert', (alert) => seen(alert.spacecraft_id));
      onFleet('estimate', (record) => seen(record.spacecraft_id));
      // The end-of-replay marker also comes at the first subscription: it closes the gap between
      // the page's first read of the sessions and the start of the feeds.
      onFleet('replayComplete', schedule);
    }
  };
}
