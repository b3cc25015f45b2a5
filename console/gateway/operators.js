// What each operator holds on esgd through the live feed (docs/console-gateway.md "Security"):
// at most PER_OPERATOR subscriptions over all their sockets, carried by one gRPC connection of
// the operator's own. An operator is a token, or a browser's address against an esgd without
// tokens (tokencheck.js operatorKey).
//
// Why a connection per operator and not only the cap: every call on one HTTP/2 connection shares
// its streams (esgd allows 100 at once, then calls wait in the client) and its flow-control
// window (a paused subscription of a slow browser holds part of it). On the one connection the
// REST calls use, a few operators within their caps could still fill it and stall everybody's
// requests. On its own connection, an operator's subscriptions can only wait behind their own:
// the cap (below esgd's 100 streams) keeps even that from happening.
'use strict';

const PER_OPERATOR = 64;
// An operator's connection outlives their last subscription this long: a page reloading, or
// unsubscribing and subscribing again, does not connect anew.
const IDLE_CLOSE_MS = 30_000;

class Operators {
  constructor(esgd) {
    this.esgd = esgd;
    this.held = new Map(); // key -> {count, client, idle}
  }

  // One more subscription of `key`: {client, release()} (release is idempotent), or null when
  // the operator already holds PER_OPERATOR.
  take(key) {
    let operator = this.held.get(key);
    if (!operator) {
      operator = { count: 0, client: this.esgd.ownConnection(), idle: null };
      this.held.set(key, operator);
    }
    if (operator.count >= PER_OPERATOR) return null;
    clearTimeout(operator.idle);
    operator.idle = null;
    operator.count++;
    let released = false;
    const release = () => {
      if (released) return;
      released = true;
      operator.count--;
      if (operator.count > 0) return;
      operator.idle = setTimeout(() => {
        if (operator.count > 0 || this.held.get(key) !== operator) return;
        this.held.delete(key);
        operator.client.close();
      }, IDLE_CLOSE_MS);
      operator.idle.unref();
    };
    return { client: operator.client, release };
  }

  close() {
    for (const operator of this.held.values()) {
      clearTimeout(operator.idle);
      operator.client.close();
    }
    this.held.clear();
  }
}

module.exports = { Operators, PER_OPERATOR };
