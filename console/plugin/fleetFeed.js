// The alerts and per-step estimates of every spacecraft as esgd pushes them (live only), for the
// modules that watch the whole fleet for the page's life (tree.js, revisions.js): one
// subscription of each over the WebSocket, shared, so each push crosses it once.
import { live } from './live.js';

const listeners = { alert: new Set(), estimate: new Set(), replayComplete: new Set() };
let started = false;

function start() {
  if (started) return;
  started = true;
  const emit = (kind) => (message) => listeners[kind].forEach((fn) => fn(message));
  // The end-of-replay marker comes at the first subscription and after each reconnect of the
  // WebSocket: what changed while it was down was not pushed.
  live.subscribe('alerts', '', null, emit('alert'), () => {}, emit('replayComplete'));
  // An esgd without per-step estimates ends this one (UNIMPLEMENTED): alerts remain.
  live.subscribe('estimates', '', null, emit('estimate'), () => {});
}

// kind: "alert" (an Alert), "estimate" (an EstimateRecord) or "replayComplete" (no argument).
export function onFleet(kind, fn) {
  listeners[kind].add(fn);
  start();
}
