// The WebSocket /api/live (docs/console-gateway.md "WebSocket"): the browser signs in with its
// first message, then each subscription is one server-streaming call to esgd (SubscribeAlerts or
// SubscribeEstimates) with the operator's token, always with replay_marker, whose messages are
// forwarded as they come. Unsubscribing or closing the socket cancels the call.
//
// Life of a socket:
//   OPEN      -> first message {"type":"auth","token":...}; esgd checks the token
//                (tokencheck.js) -> READY, sends {"type":"ready"};
//                a refused token, another first message or 10 s of silence -> error, closed.
//   READY     -> subscribe / unsubscribe, at most PER_SOCKET subscriptions running at once (and
//                the operator's cap over all their sockets, operators.js).
//   CLOSED    -> every subscription's call cancelled.
'use strict';

const { WebSocketServer } = require('ws');
const { isoToTimestamp } = require('./convert');
const { errorObject } = require('./errors');
const { Operators, PER_OPERATOR } = require('./operators');

const AUTH_TIMEOUT_MS = 10_000;
// Ping period: a browser that vanished without closing (laptop lid, network gone) is dropped
// after at most two periods, and its esgd streams with it.
const PING_MS = 30_000;
// A subscription whose browser reads slower than esgd sends is paused above the high mark (esgd
// then holds the alerts, up to its own limit) and resumed below the low one.
const HIGH_WATER_BYTES = 8 * 1024 * 1024;
const LOW_WATER_BYTES = 1024 * 1024;
// Subscriptions one socket runs at once. The console page runs a few over all spacecraft and one
// per spacecraft whose estimates it plots; a socket that asks for more is not the page.
const PER_SOCKET = 32;

const STREAMS = {
  alerts: { method: 'SubscribeAlerts', type: 'alert', field: 'alert' },
  estimates: { method: 'SubscribeEstimates', type: 'estimate', field: 'estimate' },
};

// Close codes (RFC 6455 private range 4000-4999, with the HTTP status in the last three digits).
const CLOSE_UNAUTHENTICATED = 4401;
const CLOSE_BAD_REQUEST = 4400;

function invalid(message) {
  return { code: 'INVALID_ARGUMENT', message };
}

function exhausted(message) {
  return { code: 'RESOURCE_EXHAUSTED', message };
}

class LiveSocket {
  // shared: {esgd, log, tokens (TokenCheck), operators (Operators)}; peer: "address:port".
  constructor(ws, shared, peerAddress, peer) {
    this.ws = ws;
    this.esgd = shared.esgd;
    this.log = shared.log;
    this.tokens = shared.tokens;
    this.operators = shared.operators;
    this.peerAddress = peerAddress;
    this.peer = peer;
    this.authorization = null;
    this.operator = null;
    this.state = 'OPEN';
    this.subscriptions = new Map();
    this.alive = true;
    this.authTimer = setTimeout(() => this.fail(CLOSE_UNAUTHENTICATED,
      { code: 'UNAUTHENTICATED', message: 'auth: no auth message within 10 s' }), AUTH_TIMEOUT_MS);
    ws.on('message', (data, isBinary) => this.onMessage(data, isBinary));
    ws.on('close', () => this.onClose());
    ws.on('error', () => {});
    ws.on('pong', () => { this.alive = true; });
  }

  send(message, done) {
    if (this.ws.readyState !== this.ws.OPEN) return;
    this.ws.send(JSON.stringify(message), done);
  }

  fail(closeCode, error) {
    this.send({ type: 'error', id: null, error });
    // A close reason is at most 123 bytes of UTF-8.
    let reason = error.message.slice(0, 120);
    while (Buffer.byteLength(reason) > 123) reason = reason.slice(0, -1);
    this.ws.close(closeCode, reason);
  }

  onMessage(data, isBinary) {
    let message;
    try {
      if (isBinary) throw new Error('binary');
      message = JSON.parse(data.toString('utf8'));
      if (message === null || typeof message !== 'object' || Array.isArray(message)) throw new Error('object');
    } catch {
      if (this.state === 'OPEN') this.fail(CLOSE_BAD_REQUEST, invalid('message: expected a JSON object'));
      else this.send({ type: 'error', id: null, error: invalid('message: expected a JSON object') });
      return;
    }
    if (this.state === 'OPEN') {
      this.onAuth(message);
    } else if (this.state === 'READY') {
      if (message.type === 'subscribe') this.onSubscribe(message);
      else if (message.type === 'unsubscribe') this.onUnsubscribe(message);
      else if (message.type === 'auth') this.send({ type: 'error', id: null, error: invalid('type: already signed in') });
      else this.send({ type: 'error', id: message.id ?? null, error: invalid(`type: expected subscribe or unsubscribe, got ${JSON.stringify(message.type)}`) });
    }
  }

  onAuth(message) {
    if (message.type !== 'auth') {
      this.fail(CLOSE_UNAUTHENTICATED, { code: 'UNAUTHENTICATED', message: 'type: the first message must be {"type":"auth","token":"..."}' });
      return;
    }
    if (message.token !== undefined && message.token !== null && typeof message.token !== 'string') {
      this.fail(CLOSE_BAD_REQUEST, invalid('token: expected a string'));
      return;
    }
    clearTimeout(this.authTimer);
    this.state = 'CHECKING';
    const authorization = message.token ? `Bearer ${message.token}` : undefined;
    this.tokens.check(authorization)
      .then(() => this.tokens.operatorKey(message.token || '', this.peerAddress))
      .then((operator) => {
        if (this.state !== 'CHECKING') return;
        this.authorization = authorization;
        this.operator = operator;
        this.state = 'READY';
        this.log(`live: ${this.peer} signed in`);
        this.send({ type: 'ready' });
      }, (err) => {
        if (this.state !== 'CHECKING') return;
        const error = errorObject(err);
        this.log(`live: ${this.peer} refused: ${error.code}`);
        this.fail(error.code === 'UNAUTHENTICATED' ? CLOSE_UNAUTHENTICATED : 1011, error);
      });
  }

  onSubscribe(message) {
    const id = message.id;
    if (typeof id !== 'string' || id === '') {
      this.send({ type: 'error', id: null, error: invalid('id: expected a non-empty string') });
      return;
    }
    const reject = (text) => this.send({ type: 'error', id, error: invalid(text) });
    if (this.subscriptions.has(id)) return reject(`id: subscription '${id}' is already running`);
    const stream = STREAMS[message.stream];
    if (!stream) return reject(`stream: expected "alerts" or "estimates", got ${JSON.stringify(message.stream)}`);
    const spacecraftId = message.spacecraft_id ?? '';
    if (typeof spacecraftId !== 'string') return reject('spacecraft_id: expected a string');
    const request = { spacecraft_id: spacecraftId, replay_marker: true };
    if (message.since !== undefined && message.since !== null && message.since !== '') {
      const since = isoToTimestamp(message.since);
      if (!since) return reject(`since: expected an ISO-8601 UTC time or null, got ${JSON.stringify(message.since)}`);
      request.since = since;
    }
    // The caps come after the request's own checks: a wrong request is told what is wrong.
    if (this.subscriptions.size >= PER_SOCKET) {
      this.send({ type: 'error', id, error: exhausted(`subscribe: this socket already runs ${PER_SOCKET} subscriptions (the most one socket may run); unsubscribe one first`) });
      return;
    }
    const slot = this.operators.take(this.operator);
    if (!slot) {
      this.send({ type: 'error', id, error: exhausted(`subscribe: this operator already runs ${PER_OPERATOR} subscriptions over all their sockets (the most one operator may run); unsubscribe one, or close another console tab`) });
      return;
    }
    const subscription = { paused: false, call: null, release: slot.release };
    subscription.call = this.esgd.subscribe(stream.method, request, this.authorization, {
      client: slot.client,
      onMessage: (record) => {
        if (record.replay_complete) {
          this.send({ type: 'replay_complete', id });
          return;
        }
        this.send({ type: stream.type, id, [stream.field]: record }, () => this.drained(subscription));
        if (!subscription.paused && this.ws.bufferedAmount > HIGH_WATER_BYTES) {
          subscription.paused = true;
          subscription.call.pause();
        }
      },
      onEnd: (err) => {
        subscription.release();
        // Ended by unsubscribe or close: the browser asked for it, nothing to report.
        if (this.subscriptions.get(id) !== subscription) return;
        this.subscriptions.delete(id);
        const error = err ? errorObject(err)
          : { code: 'OK', message: 'esgd ended the subscription' };
        this.send({ type: 'error', id, error });
      },
    });
    this.subscriptions.set(id, subscription);
  }

  drained(subscription) {
    if (subscription.paused && this.ws.bufferedAmount < LOW_WATER_BYTES) {
      subscription.paused = false;
      subscription.call.resume();
    }
  }

  onUnsubscribe(message) {
    const subscription = this.subscriptions.get(message.id);
    if (!subscription) {
      this.send({ type: 'error', id: message.id ?? null, error: { code: 'NOT_FOUND', message: `id: no subscription '${message.id}'` } });
      return;
    }
    this.subscriptions.delete(message.id);
    subscription.release();
    subscription.call.cancel();
  }

  onClose() {
    clearTimeout(this.authTimer);
    if (this.state === 'CLOSED') return;
    if (this.state === 'READY') this.log(`live: ${this.peer} closed (${this.subscriptions.size} subscriptions cancelled)`);
    this.state = 'CLOSED';
    for (const subscription of this.subscriptions.values()) {
      subscription.release();
      subscription.call.cancel();
    }
    this.subscriptions.clear();
  }
}

// Refuses an upgrade with an HTTP answer and the API's error body.
function refuseUpgrade(socket, httpStatus, reason, error) {
  const body = JSON.stringify({ error });
  socket.end(`HTTP/1.1 ${httpStatus} ${reason}\r\nConnection: close\r\n`
    + `Content-Type: application/json; charset=utf-8\r\nContent-Length: ${Buffer.byteLength(body)}\r\n\r\n${body}`);
}

const REASONS = { 403: 'Forbidden', 421: 'Misdirected Request' };

// Attaches /api/live to an HTTP(S) server; returns {close()} that closes every socket (1001,
// going away) and cancels their calls. tokens: a TokenCheck; checkRequest: the Host/Origin check
// of hosts.js.
function attachLive(server, esgd, log, { tokens, checkRequest }) {
  const wss = new WebSocketServer({ noServer: true, maxPayload: 64 * 1024 });
  const sockets = new Set();
  const shared = { esgd, log, tokens, operators: new Operators(esgd) };
  server.on('upgrade', (req, socket, head) => {
    const pathname = new URL(req.url, 'http://localhost').pathname;
    if (pathname !== '/api/live') {
      socket.end('HTTP/1.1 404 Not Found\r\nConnection: close\r\nContent-Length: 0\r\n\r\n');
      return;
    }
    // Browsers send the page's origin with every WebSocket; one from another site's page, or a
    // request under a name the console does not serve under (DNS rebinding), is refused, so that
    // site cannot read live alerts of an esgd without tokens through the operator's browser.
    // Clients that are not browsers send no Origin.
    const refused = checkRequest(req);
    if (refused) {
      refuseUpgrade(socket, refused.httpStatus, REASONS[refused.httpStatus],
        { code: refused.code, message: refused.message });
      return;
    }
    wss.handleUpgrade(req, socket, head, (ws) => {
      const address = req.socket.remoteAddress;
      const live = new LiveSocket(ws, shared, address, `${address}:${req.socket.remotePort}`);
      sockets.add(live);
      ws.on('close', () => sockets.delete(live));
    });
  });
  const pinger = setInterval(() => {
    for (const live of sockets) {
      if (!live.alive) {
        live.ws.terminate();
        continue;
      }
      live.alive = false;
      live.ws.ping();
    }
  }, PING_MS);
  pinger.unref();
  return {
    close() {
      clearInterval(pinger);
      for (const live of sockets) {
        live.onClose();
        live.ws.close(1001, 'console gateway shutting down');
      }
      shared.operators.close();
      wss.close();
    },
  };
}

module.exports = { attachLive };
