// The gateway's side of esgd: loads proto/esg/v1 with @grpc/proto-loader, opens one channel
// (plain or TLS), and offers the calls the routes need with the operator's token forwarded as the
// gRPC `authorization` metadata. Every call is registered with a Calls set so shutdown and a
// closed browser connection can cancel it. Results come back already converted to the console's
// JSON (convert.js).
'use strict';

const path = require('node:path');
const grpc = require('@grpc/grpc-js');
const protoLoader = require('@grpc/proto-loader');
const { Converter } = require('./convert');

const PROTO_DIR = path.resolve(__dirname, '..', '..', 'proto');
const SERVICE = 'esg.v1.EstimationService';

// Unary calls and stream replays get this long before they fail with DEADLINE_EXCEEDED (a 48 h
// prediction of 100 000 samples takes about 2 s on a loaded server; paging a month of
// coefficient history about as long).
const CALL_DEADLINE_MS = 120_000;
// A streamed answer (PredictAttitudeStream) is read as fast as the browser reads it: its deadline
// is for the whole answer, a slow browser's too (100 000 samples are some 60 MB of JSON).
const STREAM_DEADLINE_MS = 600_000;

// esgd's largest responses (a prediction at its 100 000-sample limit) are about 17 MB; esg
// itself accepts 64 MiB.
const MAX_RECEIVE_BYTES = 64 * 1024 * 1024;

function loadDefinition() {
  return protoLoader.loadSync('esg/v1/estimation_service.proto', {
    includeDirs: [PROTO_DIR],
    keepCase: true,
    longs: Number,
    enums: String,
    defaults: true,
    arrays: true,
  });
}

// The set of running gRPC calls, so they can be cancelled together (shutdown) or by owner
// (an HTTP request whose browser went away, a WebSocket that closed).
class Calls {
  constructor() {
    this.running = new Set();
  }

  add(call) {
    this.running.add(call);
    const forget = () => this.running.delete(call);
    call.on('status', forget);
    call.on('error', forget);
    return call;
  }

  cancelAll() {
    for (const call of this.running) call.cancel();
    this.running.clear();
  }
}

// gRPC errors without a message (UNIMPLEMENTED from an esgd that predates a call) get one that
// names the call, so the browser never shows "12 UNIMPLEMENTED: ".
function explained(method, err) {
  if (!err.details) {
    err.details = err.code === grpc.status.UNIMPLEMENTED
      ? `${method}: not implemented by this esgd (an older version)`
      : `${method}: failed without a message (gRPC code ${err.code})`;
  }
  return err;
}

class Esgd {
  // options: {address, ca (PEM buffer) | null, serverName | null}
  constructor(options) {
    this.definition = loadDefinition();
    this.convert = new Converter(this.definition);
    this.Client = grpc.makeGenericClientConstructor(this.definition[SERVICE], SERVICE);
    this.address = options.address;
    const channelOptions = {
      'grpc.max_receive_message_length': MAX_RECEIVE_BYTES,
      // esgd accepts client pings no closer than 30 s; 60 s keeps a long alert stream's
      // connection alive across NATs and finds a dead esgd within 80 s.
      'grpc.keepalive_time_ms': 60_000,
      'grpc.keepalive_timeout_ms': 20_000,
    };
    let credentials;
    if (options.ca) {
      credentials = grpc.credentials.createSsl(options.ca);
      if (options.serverName) {
        channelOptions['grpc.ssl_target_name_override'] = options.serverName;
        channelOptions['grpc.default_authority'] = options.serverName;
      }
    } else {
      credentials = grpc.credentials.createInsecure();
    }
    this.credentials = credentials;
    this.channelOptions = channelOptions;
    this.client = new this.Client(options.address, credentials, channelOptions);
    this.calls = new Calls();
  }

  // A client on a connection of its own (grpc-js shares one connection per address between
  // clients unless told otherwise): the live subscriptions of one operator go over one, so they
  // never wait for streams, or flow-control window, that other operators or the REST calls hold
  // (operators.js). close() it when done.
  ownConnection() {
    return new this.Client(this.address, this.credentials,
      { ...this.channelOptions, 'grpc.use_local_subchannel_pool': 1 });
  }

  close() {
    this.calls.cancelAll();
    this.client.close();
  }

  static metadata(authorization, request) {
    const md = new grpc.Metadata();
    // Forwarded unchanged: esgd parses the scheme itself ("Bearer TOKEN", case-insensitive).
    if (authorization) md.set('authorization', authorization);
    // A call about one spacecraft names it for a router in front of several esgd (nginx hashing
    // on x-esg-spacecraft: docs/deploy.md), as the esg CLI does; calls over all carry none.
    if (request && request.spacecraft_id) md.set('x-esg-spacecraft', request.spacecraft_id);
    return md;
  }

  // Full name of a method's response message (the key of its definition entry).
  responseType(method) {
    // proto-loader gives the method its own copy of the descriptor, named without its package.
    const short = this.definition[SERVICE][method].responseType.type.name;
    const matches = Object.keys(this.definition).filter((name) =>
      (name === short || name.endsWith(`.${short}`)) && this.definition[name].type.field);
    if (matches.length !== 1) throw new Error(`proto: cannot tell the type of ${method}'s response`);
    return matches[0];
  }

  // One unary call; resolves with the response converted to JSON, rejects with the gRPC error
  // (err.code, err.details). `owner` (optional) is a Calls set of the HTTP request.
  unary(method, request, authorization, owner, deadlineMs = CALL_DEADLINE_MS) {
    return new Promise((resolve, reject) => {
      const deadline = Date.now() + deadlineMs;
      const call = this.client[method](request, Esgd.metadata(authorization, request), { deadline },
        (err, response) => {
          if (err) reject(explained(method, err));
          else resolve(this.convert.toJson(this.responseType(method), response));
        });
      this.calls.add(call);
      if (owner) owner.add(call);
    });
  }

  // Every page of a paged call: `field` is the repeated field of the response collected across
  // pages. `limit` (optional): stop and reject with {code: 'LIMIT'} once more records than that
  // arrived.
  async pageAll(method, request, field, authorization, owner, limit = Infinity) {
    const records = [];
    let pageToken = '';
    do {
      const page = await this.unary(method, { ...request, page_token: pageToken }, authorization,
        owner);
      records.push(...page[field]);
      if (records.length > limit) {
        const err = new Error(`more than ${limit} records`);
        err.code = 'LIMIT';
        throw err;
      }
      pageToken = page.next_page_token;
    } while (pageToken);
    return records;
  }

  // A server-streaming subscription (SubscribeAlerts, SubscribeEstimates). Calls onMessage(json)
  // for each message converted to JSON and onEnd(err | null) once when the call ends; returns the
  // call (cancel() it to end; onEnd then gets an error with code CANCELLED). `client`: the
  // client to call through (ownConnection()), else the shared one.
  subscribe(method, request, authorization, { onMessage, onEnd, deadline, client }) {
    const options = deadline ? { deadline } : {};
    const call = (client || this.client)[method](request, Esgd.metadata(authorization, request), options);
    const type = this.responseType(method);
    let ended = false;
    const end = (err) => {
      if (ended) return;
      ended = true;
      onEnd(err);
    };
    call.on('data', (message) => onMessage(this.convert.toJson(type, message)));
    call.on('error', (err) => end(explained(method, err)));
    call.on('status', (status) => {
      if (status.code === grpc.status.OK) end(null);
    });
    this.calls.add(call);
    return call;
  }

  // A finite server stream (PredictAttitudeStream) read as it arrives: returns an async iterator
  // of its messages converted to JSON, which rejects with the gRPC error (err.code, err.details)
  // if the call fails. grpc-js reads ahead of its reader up to 16 messages (its object-mode
  // buffer); here one: a message is asked of esgd only once the one before was taken, so a
  // reader that stops (a browser that stops reading) holds one or two messages, not 16 (a
  // prediction chunk is 2000 samples). Leaving the iteration early (return(), a throw in a
  // for-await body) cancels the call.
  streamed(method, request, authorization, owner, deadlineMs = STREAM_DEADLINE_MS) {
    const call = this.client[method](request, Esgd.metadata(authorization, request),
      { deadline: Date.now() + deadlineMs });
    if (call._readableState) call._readableState.highWaterMark = 1;
    this.calls.add(call);
    if (owner) owner.add(call);
    const type = this.responseType(method);
    const convert = this.convert;
    let ended = false;
    async function* messages() {
      try {
        for await (const message of call) yield convert.toJson(type, message);
        ended = true;
      } catch (err) {
        ended = true;
        throw explained(method, err);
      } finally {
        if (!ended) call.cancel();
      }
    }
    return messages();
  }

  // The stored part of a subscription: every message up to the replay marker, collected, then
  // the call is cancelled. The routes read it as it arrives (replayEach); the tests compare with
  // this whole.
  replay(method, request, authorization, owner) {
    const messages = [];
    return this.replayEach(method, request, authorization, owner, (message) => messages.push(message))
      .then(() => messages);
  }

  // The same, each message handed to onMessage(json) as it arrives instead of collected;
  // resolves once the replay marker arrived.
  replayEach(method, request, authorization, owner, onMessage) {
    return new Promise((resolve, reject) => {
      let done = false;
      const call = this.subscribe(method, { ...request, replay_marker: true }, authorization, {
        deadline: Date.now() + CALL_DEADLINE_MS,
        onMessage: (message) => {
          if (done) return;
          if (message.replay_complete) {
            done = true;
            call.cancel();
            resolve();
          } else {
            onMessage(message);
          }
        },
        onEnd: (err) => {
          if (done) return;
          done = true;
          if (err) {
            reject(err);
          } else {
            const e = new Error('the stream ended before its replay marker');
            e.code = grpc.status.UNAVAILABLE;
            e.details = e.message;
            reject(e);
          }
        },
      });
      if (owner) owner.add(call);
    });
  }
}

module.exports = { Esgd, Calls, grpc };
