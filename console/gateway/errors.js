// Errors of the console API: one mapping from gRPC status codes to HTTP, and the one error body
// {"error": {"code": "<GRPC_CODE_NAME>", "message": "..."}} every endpoint answers with.
'use strict';

const { status } = require('@grpc/grpc-js');

const CODE_NAMES = Object.fromEntries(Object.entries(status).map(([name, n]) => [n, name]));

const HTTP_OF_CODE = {
  UNAUTHENTICATED: 401,
  PERMISSION_DENIED: 403,
  NOT_FOUND: 404,
  INVALID_ARGUMENT: 400,
  OUT_OF_RANGE: 400,
  FAILED_PRECONDITION: 409,
  RESOURCE_EXHAUSTED: 429,
  UNAVAILABLE: 503,
  // esgd builds that predate an RPC (the per-step estimates): the console shows "not available".
  UNIMPLEMENTED: 501,
};

// An error the gateway itself raises (a bad request, an unknown endpoint), carried with the
// gRPC code name that describes it and the HTTP status it is answered with.
class ApiError extends Error {
  constructor(httpStatus, code, message) {
    super(message);
    this.httpStatus = httpStatus;
    this.code = code;
  }
}

function badRequest(message) {
  return new ApiError(400, 'INVALID_ARGUMENT', message);
}

// Any error -> {httpStatus, body}. gRPC errors carry a numeric code and esgd's message in
// `details`; anything else is the gateway's own fault (500).
function toHttp(err) {
  if (err instanceof ApiError) {
    return { httpStatus: err.httpStatus, body: { error: { code: err.code, message: err.message } } };
  }
  if (typeof err.code === 'number' && err.code in CODE_NAMES) {
    const name = CODE_NAMES[err.code];
    return {
      httpStatus: HTTP_OF_CODE[name] || 502,
      body: { error: { code: name, message: err.details || err.message } },
    };
  }
  return { httpStatus: 500, body: { error: { code: 'INTERNAL', message: `gateway: ${err.message}` } } };
}

// The {code, message} pair of an error, for WebSocket error messages.
function errorObject(err) {
  return toHttp(err).body.error;
}

module.exports = { ApiError, badRequest, toHttp, errorObject, CODE_NAMES };
