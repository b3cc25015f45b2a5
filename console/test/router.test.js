// The console gateway behind the router (docs/console-gateway.md "Behind a router, several
// esgd"): three real esgd on loopback, each with its own SQLite file, behind a real nginx running
// the shipped deploy/nginx/esg.conf, and the gateway's --esgd pointed at nginx. Spacecraft are
// configured and fed through the router with the esg CLI, so each lives on the node its id hashes
// to; every per-spacecraft answer of the gateway must then come from that node (the gateway sets
// x-esg-spacecraft as the CLI does): with separate databases a call sent elsewhere finds no such
// spacecraft (404). The access log shows which node served each call.
//   node --test console/test/router.test.js     (ESGD, ESG: the binaries; default build/)
'use strict';

const { test, before, after } = require('node:test');
const assert = require('node:assert/strict');
const fs = require('node:fs');
const os = require('node:os');
const path = require('node:path');
const { REPO, startEsgd, startGateway, stop, esg, request, EsgJson } = require('./helpers');
const { startRouter } = require('./router');

const CONFIG = path.join(REPO, 'deploy', 'examples', 'rdk1.json');
const SCENARIO = path.join(REPO, 'deploy', 'examples', 'scenarios', 'paper_calibration.json');
const SPACECRAFT = ['RT-1', 'RT-2', 'RT-3', 'RT-4', 'RT-5', 'RT-6'];

const tmp = fs.mkdtempSync(path.join(os.tmpdir(), 'esg-console-router-'));
const esgJson = new EsgJson();
const nodes = [];
let router;
let gateway;

const cli = (...args) => esg(['--server', router.address, ...args]);
const api = (pathAndQuery) => request(new URL(pathAndQuery, gateway.url));

// The router's access log, one [spacecraft header, node (host:port), status, URI] per call whose
// URI ends with `method`.
function callsOf(method) {
  return router.accessLog().split('\n')
    .map((line) => line.split(' '))
    .filter(([, , , uri]) => uri && uri.endsWith(`/${method}`));
}

// The node that served each spacecraft's calls whose URI ends with `method`.
function nodesOf(method) {
  const served = new Map();
  for (const call of callsOf(method)) {
    const [id, node, status] = call;
    if (!SPACECRAFT.includes(id)) continue;
    assert.equal(status, '200', call.join(' '));
    if (!served.has(id)) served.set(id, new Set());
    served.get(id).add(node);
  }
  return served;
}

before(async () => {
  for (let n = 0; n < 3; n += 1) {
    nodes.push(await startEsgd(['--db', path.join(tmp, `node${n}.db`)]));
  }
  router = await startRouter(path.join(tmp, 'nginx'), nodes.map((n) => n.address));
  const flight = path.join(tmp, 'flight.csv');
  await esg(['simulate', '--config', CONFIG, '--profile', 'calibration', '--scenario', SCENARIO,
    '--hours', '1', '--seed', '4', '--out', flight]);
  const frames = fs.readFileSync(flight, 'utf8');
  for (const id of SPACECRAFT) {
    const config = path.join(tmp, `${id}.json`);
    const recording = path.join(tmp, `${id}.csv`);
    fs.writeFileSync(config, fs.readFileSync(CONFIG, 'utf8')
      .replace('"spacecraftId": "RDK-1"', `"spacecraftId": "${id}"`));
    fs.writeFileSync(recording, frames.replace(/^(# spacecraft_id: )RDK-1$/m, `$1${id}`));
    await cli('configure', '--config', config);
    await cli('replay', '--recording', recording, '--spacecraft', id, '--wait');
  }
  gateway = await startGateway(['--esgd', router.address]);
});

after(async () => {
  if (gateway) await stop(gateway.child);
  if (router) await stop(router.child);
  for (const n of nodes) await stop(n.child);
  fs.rmSync(tmp, { recursive: true, force: true });
});

test('through the router each spacecraft\'s history comes from its node and equals esg history', async () => {
  // The six spacecraft live on more than one node, or this test proves nothing.
  const configured = nodesOf('ConfigureSpacecraft');
  assert.equal(configured.size, SPACECRAFT.length);
  const homes = new Set([...configured.values()].map((s) => [...s][0]));
  assert.ok(homes.size >= 2, `all six spacecraft hashed to one node: ${[...homes]}`);

  for (const id of SPACECRAFT) {
    const answer = await api(`/api/spacecraft/${id}/history`);
    assert.equal(answer.status, 200, `${id}: ${answer.text}`);
    const expected = JSON.parse(await cli('history', '--spacecraft', id, '--json'))
      .snapshots.map((s) => esgJson.normalize('esg.v1.CoefficientSnapshot', s));
    assert.ok(expected.length > 10, `${id}: only ${expected.length} snapshots`);
    assert.deepEqual(answer.json.snapshots, expected, id);
  }
  // Every history call of a spacecraft (the gateway's and the CLI's) reached the node that was
  // configured with it.
  const histories = nodesOf('GetCoefficientHistory');
  for (const id of SPACECRAFT) {
    assert.deepEqual([...(histories.get(id) || [])], [...configured.get(id)], id);
  }
});

test('a call over all spacecraft reaches one node, which knows only its own (SQLite per node)', async () => {
  const sessions = await api('/api/sessions');
  assert.equal(sessions.status, 200, sessions.text);
  const listed = sessions.json.sessions.map((s) => s.spacecraft_id).sort();
  // The node that served it (the call carries no spacecraft, so any node may; one may hold none
  // of the six) lists exactly the spacecraft configured on it.
  const served = callsOf('ListSessions');
  assert.equal(served.length, 1, `ListSessions calls in the access log: ${served.length}`);
  const [[, node, status]] = served;
  assert.equal(status, '200');
  const own = [...nodesOf('ConfigureSpacecraft')]
    .filter(([, homes]) => homes.has(node)).map(([id]) => id).sort();
  assert.ok(own.length < SPACECRAFT.length, `all six spacecraft on ${node}`);
  assert.deepEqual(listed, own, `listed by ${node}`);
});

// gRPC 1.51 in esgd has no connection cap (docs/service.md "Limits"): the shipped nginx bounds
// the calls one client address has open at 128 (limit_conn, which with HTTP/2 counts each call
// in progress), and answers the next one as gRPC RESOURCE_EXHAUSTED.
test('the router bounds one address\'s open calls at 128 and refuses the next RESOURCE_EXHAUSTED', async () => {
  const { Esgd } = require('../gateway/esgd');
  const esgd = new Esgd({ address: router.address, ca: null, serverName: null });
  const clients = [esgd.ownConnection(), esgd.ownConnection()];
  const calls = [];
  const subscribe = (client) => new Promise((resolve) => {
    const call = esgd.subscribe('SubscribeAlerts',
      { spacecraft_id: '', since: { seconds: 0, nanos: 0 }, replay_marker: true }, undefined, {
        client,
        onMessage: (message) => { if (message.replay_complete) resolve(null); },
        onEnd: (err) => resolve(err || new Error('ended')),
      });
    calls.push(call);
  });
  try {
    // 64 on each of two connections (nginx allows 100 calls per connection).
    const held = await Promise.all(Array.from({ length: 128 }, (_, i) => subscribe(clients[i % 2])));
    assert.deepEqual(held.filter((r) => r !== null).map((e) => e.message), []);
    const third = esgd.ownConnection();
    clients.push(third);
    const refused = await subscribe(third);
    assert.ok(refused, 'the 129th call was served');
    assert.equal(refused.code, 8); // RESOURCE_EXHAUSTED
    assert.match(refused.details, /^esg router \(nginx\): this address already has 128 calls open/);
  } finally {
    for (const call of calls) call.cancel();
    for (const client of clients) client.close();
    esgd.close();
  }
});
