// The names the console answers to (docs/console-gateway.md "Security"). A browser sends the
// name it used in the Host header and the page's address in Origin. With DNS rebinding another
// site's page reaches the gateway under the attacker's name (evil.example resolving to
// 127.0.0.1): its Host is that name, so an API request or WebSocket whose Host is not in the list
// is refused (421) before anything else, and one whose Origin is not is refused too (403):
// against an esgd without tokens nothing else would stop such a page from reading the console or
// acknowledging alerts.
'use strict';

// One entry of --allowed-hosts: a DNS name, an IPv4 address or an IPv6 address in brackets,
// optionally with :PORT. Lower case, without a trailing dot (a name and the same name with the
// DNS root's dot are one name).
const ENTRY = /^(\[[0-9a-f:.]+\]|[a-z0-9]([a-z0-9-]*[a-z0-9])?(\.[a-z0-9]([a-z0-9-]*[a-z0-9])?)*)(?::(\d{1,5}))?$/;

// "Name[:port]" -> {name, port | null}; null when it is not a host in the form above.
function parseHost(text) {
  const m = ENTRY.exec(String(text).toLowerCase().replace(/\.(?=(:\d+)?$)/, ''));
  if (!m) return null;
  const port = m[5] === undefined ? null : Number(m[5]);
  if (port !== null && (port < 1 || port > 65535)) return null;
  return { name: m[1], port };
}

// --allowed-hosts: comma-separated entries -> [{name, port | null}]; throws Error with the
// reason for the first entry that is not a host.
function parseAllowedHosts(text) {
  return text.split(',').map((entry) => {
    const host = parseHost(entry.trim());
    if (!host) {
      throw new Error(`'${entry}' is not HOST or HOST:PORT (a name, an IPv4 address, or an IPv6 address in brackets: [::1])`);
    }
    return host;
  });
}

// Loopback names, and the --listen host when it is one address (not 0.0.0.0 or ::).
function defaultHosts(listenHost) {
  const names = ['127.0.0.1', 'localhost', '[::1]'];
  const listen = listenHost.includes(':') ? `[${listenHost}]` : listenHost;
  if (!['0.0.0.0', '[::]'].includes(listen) && parseHost(listen)) names.push(parseHost(listen).name);
  return [...new Set(names)].map((name) => ({ name, port: null }));
}

// An entry without a port allows the gateway's own port, and no port (the scheme's default:
// a proxy in front serves the console on 443 or 80); one with a port allows that port only.
function allowed(entries, host, listenPort) {
  return entries.some((entry) => entry.name === host.name
    && (entry.port !== null ? host.port === entry.port : host.port === listenPort || host.port === null));
}

// checkRequest(req) -> null when Host (and Origin, if sent) are allowed, else
// {httpStatus, code, message}. listenPort() is the port the gateway listens on.
function makeHostCheck(entries, listenPort) {
  return function checkRequest(req) {
    const hostHeader = req.headers.host;
    const host = hostHeader === undefined ? null : parseHost(hostHeader);
    if (!host || !allowed(entries, host, listenPort())) {
      return {
        httpStatus: 421,
        code: 'INVALID_ARGUMENT',
        message: hostHeader === undefined ? 'Host: missing (the console gateway answers only to the names it is given with --allowed-hosts)'
          : `Host: '${String(hostHeader).slice(0, 100)}' is not a name this console gateway serves under (its operator adds names with --allowed-hosts)`,
      };
    }
    const origin = req.headers.origin;
    if (origin !== undefined && !allowedOrigin(entries, origin, listenPort())) {
      return {
        httpStatus: 403,
        code: 'PERMISSION_DENIED',
        message: `Origin: '${String(origin).slice(0, 100)}' is not this console (a page of another site cannot use it)`,
      };
    }
    return null;
  };
}

function allowedOrigin(entries, origin, listenPort) {
  let url;
  try {
    url = new URL(origin);
  } catch {
    return false; // "null" (a sandboxed or file: page) and anything else that is not an address
  }
  if (url.protocol !== 'http:' && url.protocol !== 'https:') return false;
  const host = parseHost(url.host);
  return host !== null && allowed(entries, host, listenPort);
}

module.exports = { parseAllowedHosts, defaultHosts, makeHostCheck };
