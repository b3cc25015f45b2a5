// HTTP at the byte level, for the tests of the gateway's request bounds: Node's http client
// sends a body as soon as it can, so it cannot show whether the gateway answered on a request's
// head alone, nor how much of a body the gateway took before it refused it.
'use strict';

const net = require('node:net');
const fs = require('node:fs');

// One HTTP/1.1 request written by hand. `head`: {method, path, headers}; the Host header is the
// url's unless given. Resolves with the connection and a promise of the answer:
//   {socket, answer: Promise<{status, headers, json, ms, sentAtAnswer}>, sent()}
// where ms is the time from the head's write to the answer's head, and sentAtAnswer the body
// bytes written by then. The answer rejects when the connection closes without one.
function openRequest(url, head) {
  const target = new URL(url);
  return new Promise((resolve, reject) => {
    const socket = net.connect(Number(target.port), target.hostname);
    socket.once('error', reject);
    socket.once('connect', () => {
      socket.off('error', reject);
      let sent = 0;
      let started;
      let received = Buffer.alloc(0);
      const answer = new Promise((done, fail) => {
        let parsed = null;
        socket.on('data', (chunk) => {
          received = Buffer.concat([received, chunk]);
          if (!parsed) {
            const end = received.indexOf('\r\n\r\n');
            if (end < 0) return;
            const lines = received.subarray(0, end).toString('latin1').split('\r\n');
            const headers = {};
            for (const line of lines.slice(1)) {
              const colon = line.indexOf(':');
              headers[line.slice(0, colon).trim().toLowerCase()] = line.slice(colon + 1).trim();
            }
            parsed = { status: Number(lines[0].split(' ')[1]), headers, ms: Date.now() - started,
              sentAtAnswer: sent, bodyStart: end + 4 };
          }
          const length = Number(parsed.headers['content-length'] || 0);
          if (received.length - parsed.bodyStart < length) return;
          const text = received.subarray(parsed.bodyStart, parsed.bodyStart + length).toString('utf8');
          const { bodyStart: _, ...rest } = parsed;
          done({ ...rest, text, json: text ? JSON.parse(text) : undefined });
        });
        socket.on('error', () => {});
        socket.on('close', () => fail(new Error(`connection closed without an answer (${sent} body bytes sent)`)));
      });
      answer.catch(() => {});
      const given = head.headers || {};
      const headers = Object.keys(given).some((k) => k.toLowerCase() === 'host')
        ? given : { host: target.host, ...given };
      const text = `${head.method} ${head.path} HTTP/1.1\r\n${Object.entries(headers)
        .map(([k, v]) => `${k}: ${v}\r\n`).join('')}\r\n`;
      started = Date.now();
      socket.write(text);
      const write = (buffer) => new Promise((done) => {
        if (socket.destroyed || !socket.writable) {
          done(false);
          return;
        }
        sent += buffer.length;
        if (socket.write(buffer)) done(true);
        else {
          const finish = (ok) => { socket.off('drain', onDrain); socket.off('close', onClose); done(ok); };
          const onDrain = () => finish(true);
          const onClose = () => finish(false);
          socket.once('drain', onDrain);
          socket.once('close', onClose);
        }
      });
      resolve({ socket, answer, write, sent: () => sent });
    });
  });
}

// Writes `total` bytes of `body` (repeated) in 64 KiB pieces as fast as the connection takes
// them, chunked when `chunked`, until all is written, the connection closes, or `stopWhen()`.
// Resolves with the bytes written.
async function pour(connection, body, total, { chunked = false, stopWhen = () => false } = {}) {
  const piece = 64 * 1024;
  let written = 0;
  while (written < total && !stopWhen()) {
    const n = Math.min(piece, total - written);
    let bytes = body.subarray(written % body.length, written % body.length + n);
    if (bytes.length < n) bytes = Buffer.concat([bytes, body.subarray(0, n - bytes.length)]);
    const framed = chunked
      ? Buffer.concat([Buffer.from(`${n.toString(16)}\r\n`), bytes, Buffer.from('\r\n')]) : bytes;
    if (!await connection.write(framed)) break;
    written += n;
  }
  if (chunked && written >= total) await connection.write(Buffer.from('0\r\n\r\n'));
  return written;
}

// Resident memory of a process [bytes] (Linux /proc).
function rssBytes(pid) {
  const m = /VmRSS:\s+(\d+) kB/.exec(fs.readFileSync(`/proc/${pid}/status`, 'utf8'));
  return Number(m[1]) * 1024;
}

module.exports = { openRequest, pour, rssBytes };
