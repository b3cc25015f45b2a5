// REST client of the gateway (docs/console-gateway.md). Every /api/ request carries the operator's
// token from sessionStorage, because the gateway holds none of its own and forwards ours to esgd.

const TOKEN_KEY = 'esg.token';

export function getToken() {
  return sessionStorage.getItem(TOKEN_KEY) || '';
}

export function setToken(token) {
  if (token) sessionStorage.setItem(TOKEN_KEY, token);
  else sessionStorage.removeItem(TOKEN_KEY);
}

// An HTTP error with the gateway's {"error": {code, message}} body kept, so callers can tell
// UNIMPLEMENTED (501: esgd has no such RPC yet) from real failures.
export class ApiError extends Error {
  constructor(status, code, message) {
    super(`${status} ${code}: ${message}`);
    this.status = status;
    this.code = code;
  }
}

// A token esgd stops accepting (revoked, rotated) sends the operator back to the sign-in form:
// the page is reloaded without it. The sign-in itself checks tokens with signOutOn401 = false.
export async function apiFetch(path, { method = 'GET', body, token = getToken(), signOutOn401 = true } = {}) {
  const headers = {};
  if (token) headers.Authorization = `Bearer ${token}`;
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  const response = await fetch(path, {
    method,
    headers,
    body: body === undefined ? undefined : JSON.stringify(body)
  });
  const text = await response.text();
  let json = null;
  try {
    json = text ? JSON.parse(text) : null;
  } catch (err) {
    throw new ApiError(response.status, 'BAD_JSON', `${path}: ${err.message}`);
  }
  if (response.status === 401 && token && signOutOn401) {
    setToken('');
    location.reload();
  }
  if (!response.ok) {
    const error = (json && json.error) || {};
    throw new ApiError(response.status, error.code || 'HTTP', error.message || text);
  }
  return json;
}

// Whether this caller may use the page's write actions (applying a diagnosis): GET /api/auth's
// can_write, which the gateway asks esgd (docs/console-gateway.md); esgd without tokens lets
// everyone write. Asked once per page load (a new token reloads the page). It only decides what
// the page offers: esgd checks the role of every write call itself.
let writeRole = null;
export function canWrite() {
  if (!writeRole) {
    writeRole = apiFetch('/api/auth').then((body) => !body.auth_required || body.can_write === true,
      () => { writeRole = null; return false; });
  }
  return writeRole;
}

// Query string from an object, skipping null/undefined values.
export function query(params) {
  const entries = Object.entries(params).filter(([, v]) => v !== undefined && v !== null);
  if (entries.length === 0) return '';
  return '?' + entries.map(([k, v]) => `${k}=${encodeURIComponent(v)}`).join('&');
}

export function isoTime(ms) {
  return new Date(ms).toISOString();
}

// Concurrent requests for the same URL share one fetch: an overlay plot asks for the value,
// +1-sigma and -1-sigma series of one coefficient at once, all cut from the same snapshots. Only
// requests in flight are shared; a later one fetches again (new data may have been stored).
const inflight = new Map();
export function sharedFetch(path) {
  if (!inflight.has(path)) {
    inflight.set(path, apiFetch(path).finally(() => inflight.delete(path)));
  }
  return inflight.get(path);
}
