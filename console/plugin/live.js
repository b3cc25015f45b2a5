// The one WebSocket to the gateway's /api/live (docs/console-gateway.md): real-time alerts and
// per-step estimates are pushed by esgd's streaming RPCs, never polled. Subscriptions are kept
// in a table and re-sent after a reconnect, so a dropped socket heals by itself.
import { getToken } from './api.js';

const RECONNECT_MS = 2000;

class Live {
  constructor() {
    this.subscriptions = new Map(); // id -> {stream, spacecraftId, since, onData, onError}
    this.nextId = 1;
    this.socket = null;
    this.ready = false;
  }

  connect() {
    const scheme = location.protocol === 'https:' ? 'wss:' : 'ws:';
    const socket = new WebSocket(`${scheme}//${location.host}/api/live`);
    this.socket = socket;
    socket.onopen = () => socket.send(JSON.stringify({ type: 'auth', token: getToken() }));
    socket.onmessage = (event) => this.onMessage(JSON.parse(event.data));
    socket.onclose = () => {
      this.ready = false;
      this.socket = null;
      if (this.subscriptions.size > 0) setTimeout(() => this.ensure(), RECONNECT_MS);
    };
  }

  ensure() {
    if (!this.socket) this.connect();
  }

  onMessage(message) {
    if (message.type === 'ready') {
      this.ready = true;
      for (const id of this.subscriptions.keys()) this.sendSubscribe(id);
      return;
    }
    const subscription = this.subscriptions.get(message.id);
    if (!subscription) return;
    if (message.type === 'alert') subscription.onData(message.alert);
    else if (message.type === 'estimate') subscription.onData(message.estimate);
    else if (message.type === 'replay_complete') subscription.onReplayComplete?.();
    else if (message.type === 'error') {
      // The gateway ended this subscription (e.g. UNIMPLEMENTED): drop it, tell the owner.
      this.subscriptions.delete(message.id);
      subscription.onError?.(message.error);
    }
  }

  sendSubscribe(id) {
    const s = this.subscriptions.get(id);
    this.socket.send(JSON.stringify({
      type: 'subscribe', id, stream: s.stream, spacecraft_id: s.spacecraftId, since: s.since
    }));
  }

  // stream: "alerts" | "estimates"; spacecraftId '' for all; since null for live only.
  // Returns the unsubscribe function Open MCT expects.
  subscribe(stream, spacecraftId, since, onData, onError, onReplayComplete) {
    const id = `s${this.nextId++}`;
    this.subscriptions.set(id, { stream, spacecraftId, since, onData, onError, onReplayComplete });
    this.ensure();
    if (this.ready) this.sendSubscribe(id);
    return () => {
      if (!this.subscriptions.delete(id)) return;
      if (this.ready) this.socket.send(JSON.stringify({ type: 'unsubscribe', id }));
    };
  }
}

export const live = new Live();
