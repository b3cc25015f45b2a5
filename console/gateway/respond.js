// Writing a JSON answer: the one place that sets the headers every /api/ answer and every error
// of the static files carry.
'use strict';

// How long a connection answered before its whole body arrived stays open after the answer.
const LINGER_MS = 1000;

// Node closes a connection answered with "Connection: close" as soon as the answer is written.
// With body bytes still arriving unread, that close is a TCP reset, which throws away the
// answer if it has not left yet: the operator would see "connection reset" instead of the 413
// saying why. So the sending side is closed after the answer, nothing more is read (the client's
// writes stall once the system's buffers are full; nothing reaches the gateway's memory), and
// the connection is closed for good LINGER_MS later, when the answer is long delivered.
function closeAfterAnswer(res) {
  res.setHeader('Connection', 'close');
  const socket = res.socket;
  if (!socket) return;
  socket.destroySoon = () => {
    socket.end();
    socket.pause();
    // The request's reader asks the socket to resume when it wants more of the body.
    socket.resume = () => socket;
    setTimeout(() => socket.destroy(), LINGER_MS).unref();
  };
}

function sendJson(res, httpStatus, body) {
  const text = JSON.stringify(body);
  // Answered before its whole body arrived (refused on its head, or past its bound): the rest of
  // that body is never read into memory, and the connection ends with the answer.
  if (res.req && !res.req.complete) closeAfterAnswer(res);
  res.writeHead(httpStatus, {
    'Content-Type': 'application/json; charset=utf-8',
    'Content-Length': Buffer.byteLength(text),
    'Cache-Control': 'no-store',
    'X-Content-Type-Options': 'nosniff',
  });
  res.end(text);
}

module.exports = { sendJson };
