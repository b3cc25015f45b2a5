// The fleet's sessions and whether esgd serves per-step estimates, shared by the object provider
// (which objects exist depends on both). The sessions are fetched when the page loads and again
// when esgd pushes data of a spacecraft the page does not know (tree.js).
import { apiFetch, ApiError, query } from './api.js';

let sessionsPromise = null;
const estimatesProbe = new Map();

export function sessions() {
  if (!sessionsPromise) {
    sessionsPromise = apiFetch('/api/sessions').then((body) => body.sessions);
  }
  return sessionsPromise;
}

// Reads the sessions again. The shared list is replaced only when the read succeeds, so a failed
// read leaves the page as it was.
export async function reloadSessions() {
  const list = (await apiFetch('/api/sessions')).sessions;
  sessionsPromise = Promise.resolve(list);
  return list;
}

export async function session(spacecraftId) {
  const found = (await sessions()).find((s) => s.spacecraft_id === spacecraftId);
  if (!found) throw new Error(`no session ${spacecraftId}`);
  return found;
}

// GetEstimateHistory over one instant: 200 means esgd keeps per-step estimates, 501 that this
// esgd does not implement them (the views then say "not available" instead of staying empty).
export function estimatesAvailable(spacecraftId, atIso) {
  if (!estimatesProbe.has(spacecraftId)) {
    const at = atIso || new Date().toISOString();
    const path = `/api/spacecraft/${encodeURIComponent(spacecraftId)}/estimates${query({ from: at, to: at })}`;
    estimatesProbe.set(spacecraftId, apiFetch(path).then(() => true, (err) => {
      if (err instanceof ApiError && err.status === 501) return false;
      throw err;
    }));
  }
  return estimatesProbe.get(spacecraftId);
}
