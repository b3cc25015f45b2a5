// Sign-in before Open MCT starts: GET /api/auth tells whether esgd wants a token. If it does, the
// operator pastes theirs; it is checked (GET /api/auth with it) and kept in sessionStorage for
// this tab only. Skipped when esgd runs without tokens.
import { apiFetch, getToken, setToken } from './api.js';

async function tokenWorks(token) {
  try {
    const body = await apiFetch('/api/auth', { token, signOutOn401: false });
    return body.ok === true;
  } catch (err) {
    if (err.status === 401 || err.status === 403) return false;
    throw err;
  }
}

function askToken(message) {
  return new Promise((resolve) => {
    const form = document.getElementById('esg-signin');
    const input = document.getElementById('esg-token');
    const note = document.getElementById('esg-signin-message');
    note.textContent = message;
    form.hidden = false;
    input.focus();
    form.onsubmit = (event) => {
      event.preventDefault();
      resolve(input.value.trim());
    };
  });
}

export async function signIn() {
  const { auth_required: required } = await apiFetch('/api/auth', { token: '' });
  if (!required) {
    setToken('');
    return;
  }
  let message = 'esgd requires a token. Paste your operator token.';
  if (getToken() && (await tokenWorks(getToken()))) return;
  for (;;) {
    const token = await askToken(message);
    if (token && (await tokenWorks(token))) {
      setToken(token);
      document.getElementById('esg-signin').hidden = true;
      return;
    }
    message = 'esgd refused this token. Try again.';
  }
}
