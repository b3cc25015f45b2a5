// The REST endpoints under /api/ (docs/console-gateway.md "REST API"). Each handler turns the
// HTTP request into esgd calls with the operator's token, pages through every paged call, and
// returns the JSON body; errors are thrown and answered by api.js with the one error mapping.
// A route is [method, pattern, handler, options]: options.body is the largest body it reads
// (limits.js; none without), options.public that api.js does not check the token first.
'use strict';

const { badRequest, ApiError } = require('./errors');
const { timeParam, boolParam, intParam, intValue, numberParam, jsonBody } = require('./params');
const { ConvertError } = require('./convert');
const { grpc } = require('./esgd');
const { PREDICT_BODY_BYTES, ACKNOWLEDGE_BODY_BYTES } = require('./limits');
const { StreamedJson, SpooledText, LargeAnswers, MAX_HISTORY } = require('./large');

// A streamed history's pages (large.js): what one request holds at a time. Smaller than esgd's
// largest: 1000 snapshots are about 0.8 MB of JSON, and four parallel 20-day histories cost the
// gateway less than half the memory they did at 5000 (measured in console/test/large_answers.test.js).
const HISTORY_STREAM_PAGE = 1000;
// The same for an estimate list: 1000 estimates are about 1.2 MB of JSON.
const ESTIMATE_STREAM_PAGE = 1000;
const ESTIMATE_PAGE = 5000;
const SESSION_PAGE = 500;
// Alerts of an alert list written at a time (some 0.5 MB of JSON).
const ALERT_PAGE = 1000;
const DIAGNOSIS_PAGE = 100;

// The most per-step estimates one request returns (a fortnight at 60 s steps); a next_page_token
// goes on from there.
const MAX_ESTIMATES = 20000;

// A prediction refused by esgd's prediction slots (RESOURCE_EXHAUSTED) before its first chunk is
// asked again after these waits (1.5 s in all), then answered 429 with esgd's message.
const PREDICT_RETRY_MS = [100, 200, 400, 800];

const EPOCH = { seconds: 0, nanos: 0 };
const HOUR_S = 3600;
const DAY_S = 86400;
const SEVERITIES = ['INFO', 'WARNING', 'DISTRESS', 'CRITICAL'];

// Alerts of a replay, the latest state of each (spacecraft, sequence) at the place the alert
// first appeared: a live change that arrives during the replay repeats an alert.
function latestStates(alerts) {
  const byKey = new Map();
  for (const alert of alerts) byKey.set(`${alert.spacecraft_id}\u0000${alert.sequence}`, alert);
  return [...byKey.values()];
}

// Whether `alert` is worse than `other` (or there is no other): the higher severity, then the
// later latest occurrence.
function worseAlert(alert, other) {
  if (!other) return true;
  const rank = (a) => SEVERITIES.indexOf(a.severity.replace(/^ALERT_SEVERITY_/, ''));
  if (rank(alert) !== rank(other)) return rank(alert) > rank(other);
  return (alert.measurement_time || '') > (other.measurement_time || '');
}

function isUnimplemented(err) {
  return err && err.code === grpc.status.UNIMPLEMENTED;
}

// esgd's page tokens are short (base64 of a position); longer is not one of them.
const MAX_PAGE_TOKEN = 1024;

// tokens: the TokenCheck api.js checks each request's token with. large: the LargeAnswers
// (large.js) whose slots the history and estimate requests take.
function makeRoutes(esgd, tokens, large = new LargeAnswers()) {
  // PredictResponse's fields after `samples`, in their order in the .proto.
  const PREDICT_TAIL = esgd.convert.descriptor('esg.v1.PredictResponse').field
    .map((f) => f.name).filter((name) => name !== 'samples');
  const call = (ctx, method, request) => esgd.unary(method, request, ctx.authorization, ctx.owner);
  const pages = (ctx, method, request, field, limit) =>
    esgd.pageAll(method, request, field, ctx.authorization, ctx.owner, limit);

  // A slot of the operator's large answers (large.js); resolves with its release().
  async function largeSlot(ctx, what) {
    const key = await tokens.operatorKey(ctx.authorization, ctx.req.socket.remoteAddress);
    const release = await large.take(key, what);
    if (ctx.req.socket.destroyed) {
      release(); // the browser went away while the request waited
      throw new ApiError(499, 'CANCELLED', `${what}: the client went away`);
    }
    return release;
  }

  // The answer {"<field>": [...], "next_page_token": "..."} of a paged esgd call, streamed a page
  // of `streamPage` at a time (large.js) in a slot of the operator's large answers: at most
  // `limit` items from the query's page_token on, then next_page_token when more remain.
  async function streamedPages(ctx, what, method, request, field, maxItems, streamPage) {
    const limit = intParam(ctx.query, 'limit', 1, maxItems, maxItems);
    const pageToken = ctx.query.get('page_token') || '';
    if (pageToken.length > MAX_PAGE_TOKEN) {
      throw badRequest(`page_token: longer than ${MAX_PAGE_TOKEN} characters; pass the next_page_token of an answer`);
    }
    const release = await largeSlot(ctx, what);
    let sent = 0;
    let next = pageToken;
    const page = () => call(ctx, method, {
      ...request, page_size: Math.min(streamPage, limit - sent), page_token: next,
    }).then((answer) => {
      sent += answer[field].length;
      next = answer.next_page_token;
      return answer[field];
    });
    let first;
    try {
      // The first page before the answer starts: an error (unknown spacecraft, a bad token)
      // is still answered with its own status.
      first = await page();
    } catch (err) {
      release();
      throw err;
    }
    async function* rest() {
      yield first;
      while (next && sent < limit) yield await page();
    }
    return new StreamedJson(field, rest(), {
      tail: () => (next ? { next_page_token: next } : {}),
      done: release,
    });
  }

  // A prediction's answer, the JSON of PredictAttitude's PredictResponse, written from
  // PredictAttitudeStream as its chunks arrive (docs/console-gateway.md "Large answers") in a
  // slot of the operator's large answers: the samples chunk by chunk, each chunk asked of esgd
  // once the one before went to the socket and drained; then the fields PredictResponse has
  // after its samples, from the chunks (recorded_samples and the times from the first, the
  // source from the last, the assumptions joined with "; " as esgd joins them, the AEM pieces
  // concatenated, kept aside meanwhile in a SpooledText). An error before the first chunk is
  // answered with its own status as PredictAttitude's was; after it, the connection is ended.
  // An esgd without the stream (UNIMPLEMENTED) is asked PredictAttitude, answered whole.
  async function predictAnswer(ctx, request) {
    const release = await largeSlot(ctx, 'predict');
    let chunks;
    let first;
    try {
      for (let attempt = 0; ; attempt++) {
        chunks = esgd.streamed('PredictAttitudeStream', request, ctx.authorization, ctx.owner);
        try {
          first = await chunks.next();
          break;
        } catch (err) {
          // esgd's prediction slots (per caller, in total) are given back when a cancelled stream's
          // chunk in the making is done, some time after the browser that read it went away and
          // gave this request its gateway slot: asked again a few times before it is answered.
          if (err.code !== grpc.status.RESOURCE_EXHAUSTED || attempt === PREDICT_RETRY_MS.length ||
              ctx.req.socket.destroyed) throw err;
          await new Promise((resolve) => setTimeout(resolve, PREDICT_RETRY_MS[attempt]));
        }
      }
    } catch (err) {
      if (!isUnimplemented(err)) {
        release();
        throw err;
      }
      try {
        return await call(ctx, 'PredictAttitude', request);
      } finally {
        release();
      }
    }
    const aem = new SpooledText();
    const fields = {
      aem_text: aem,
      attitude_source: 'ATTITUDE_SOURCE_RECORDED',
      recorded_samples: 0,
      assumption: [],
    };
    async function* samples() {
      for (let next = first, n = 0; !next.done; next = await chunks.next(), n++) {
        const chunk = next.value;
        if (n === 0) {
          fields.recorded_samples = chunk.recorded_samples;
          if (chunk.last_applied_time) fields.last_applied_time = chunk.last_applied_time;
          if (chunk.last_archived_time) fields.last_archived_time = chunk.last_archived_time;
        }
        fields.attitude_source = chunk.attitude_source;
        if (chunk.assumption) fields.assumption.push(chunk.assumption);
        await aem.append(chunk.aem_text);
        yield chunk.samples;
      }
    }
    return new StreamedJson('samples', samples(), {
      // In PredictResponse's order of fields, as its JSON (convert.js) has them.
      tail: () => Object.fromEntries(PREDICT_TAIL
        .filter((name) => fields[name] !== undefined)
        .map((name) => [name, name === 'assumption' ? fields.assumption.join('; ') : fields[name]])),
      done: () => {
        release();
        aem.close().catch(() => {});
        chunks.return().catch(() => {});
      },
    });
  }

  // An alert list: SubscribeAlerts replayed up to its marker, each alert once in its latest state
  // at the place it first appeared (latestStates), in a slot of the operator's large answers. The
  // whole replay is read before the answer starts (a live change during it can still change an
  // alert written earlier), kept as each alert's JSON text (a third of the object's memory), then
  // written ALERT_PAGE alerts at a time as the socket drains, never as one string.
  async function alertList(ctx, spacecraftId) {
    const since = timeParam(ctx.query, 'since') || EPOCH;
    const release = await largeSlot(ctx, 'alerts');
    const latest = new Map();
    try {
      await esgd.replayEach('SubscribeAlerts', { spacecraft_id: spacecraftId, since },
        ctx.authorization, ctx.owner,
        (alert) => latest.set(`${alert.spacecraft_id}\u0000${alert.sequence}`, JSON.stringify(alert)));
    } catch (err) {
      release();
      throw err;
    }
    async function* pages() {
      let page = [];
      for (const text of latest.values()) {
        page.push(text);
        if (page.length === ALERT_PAGE) {
          yield page;
          page = [];
        }
      }
      yield page;
    }
    return new StreamedJson('alerts', pages(), { raw: true, done: () => { latest.clear(); release(); } });
  }

  // Newest per-step estimate's last star-tracker time over the day before the session's last
  // frame; null when there is none. The last hour is asked first: it holds the newest record
  // whenever the filter ran in it, and is 24 times less to page through than the day.
  // Throws UNIMPLEMENTED through for the caller to remember.
  async function lastStarTrackerTime(ctx, session) {
    if (!session.last_frame_time) return null;
    const toMs = Date.parse(session.last_frame_time);
    const at = (ms) => ({ seconds: Math.floor(ms / 1000), nanos: (((ms % 1000) + 1000) % 1000) * 1e6 });
    for (const spanS of [HOUR_S, DAY_S]) {
      const request = {
        spacecraft_id: session.spacecraft_id,
        from: at(toMs - spanS * 1000),
        // +1 ms: the ISO time dropped any sub-millisecond part of the last frame's time.
        to: at(toMs + 1),
        page_size: ESTIMATE_PAGE,
      };
      const estimates = await pages(ctx, 'GetEstimateHistory', request, 'estimates');
      if (estimates.length > 0) return estimates[estimates.length - 1].last_star_tracker_time || null;
    }
    return null;
  }

  return [
    ['GET', '/api/auth', async (ctx) => {
      // Without a token: does esgd want one? With one: is it a token esgd knows (401 if not)?
      const authRequired = await tokens.tokensRequired();
      if (!ctx.authorization) return { auth_required: authRequired };
      await tokens.check(ctx.authorization);
      // Whether the page offers its write actions (applying a diagnosis): esgd without tokens
      // lets every caller write; with tokens it is asked (TokenCheck.canWrite). esgd checks the
      // role of each write call all the same.
      const canWrite = authRequired ? await tokens.canWrite(ctx.authorization) : true;
      return { auth_required: authRequired, ok: true, can_write: canWrite };
    }, { public: true }],

    ['GET', '/api/sessions', async (ctx) => ({
      sessions: await pages(ctx, 'ListSessions', { page_size: SESSION_PAGE }, 'sessions'),
    })],

    ['GET', '/api/fleet', async (ctx) => {
      // Every alert's latest state at its first place (latestStates), kept only while it is open
      // (not cleared, not revised, of a known severity): the replay of every stored alert is
      // read, the closed ones, most of them, are not held.
      const latestOpen = new Map();
      const [sessions] = await Promise.all([
        pages(ctx, 'ListSessions', { page_size: SESSION_PAGE }, 'sessions'),
        esgd.replayEach('SubscribeAlerts', { spacecraft_id: '', since: EPOCH }, ctx.authorization,
          ctx.owner, (alert) => {
            const severity = alert.severity.replace(/^ALERT_SEVERITY_/, '');
            const isOpen = !alert.cleared && !alert.revised_time && SEVERITIES.includes(severity);
            latestOpen.set(`${alert.spacecraft_id}\u0000${alert.sequence}`, isOpen ? alert : null);
          }),
      ]);
      const open = new Map(sessions.map((s) => [s.spacecraft_id,
        Object.fromEntries(SEVERITIES.map((name) => [name, 0]))]));
      const worst = new Map();
      for (const alert of latestOpen.values()) {
        if (!alert) continue;
        const counts = open.get(alert.spacecraft_id);
        const severity = alert.severity.replace(/^ALERT_SEVERITY_/, '');
        if (!counts) continue;
        counts[severity]++;
        if (worseAlert(alert, worst.get(alert.spacecraft_id))) worst.set(alert.spacecraft_id, alert);
      }
      let estimatesAvailable = true;
      const times = await Promise.all(sessions.map(async (session) => {
        if (!estimatesAvailable) return null;
        try {
          return await lastStarTrackerTime(ctx, session);
        } catch (err) {
          if (!isUnimplemented(err)) throw err;
          estimatesAvailable = false;
          return null;
        }
      }));
      // The newest stored diagnosis of each spacecraft (ListDiagnoses lists oldest first).
      const diagnoses = await Promise.all(sessions.map(async (session) => {
        const list = await pages(ctx, 'ListDiagnoses',
          { spacecraft_id: session.spacecraft_id, page_size: DIAGNOSIS_PAGE }, 'diagnoses');
        return list.length ? list[list.length - 1] : null;
      }));
      return {
        fleet: sessions.map((session, i) => ({
          session,
          open_alerts: open.get(session.spacecraft_id),
          worst_alert: worst.get(session.spacecraft_id) || null,
          last_diagnosis: diagnoses[i],
          last_star_tracker_time: times[i],
        })),
      };
    }],

    // Streamed a page at a time (large.js): at most `limit` snapshots (default and most
    // MAX_HISTORY), then next_page_token when more remain; page_token goes on from there.
    ['GET', '/api/spacecraft/:id/history', async (ctx) => streamedPages(ctx, 'history',
      'GetCoefficientHistory', {
        spacecraft_id: ctx.params.id,
        gyro_id: intParam(ctx.query, 'gyro', 0, 4, 0),
        from: timeParam(ctx.query, 'from'),
        to: timeParam(ctx.query, 'to'),
        include_revised: boolParam(ctx.query, 'include_revised', false),
      }, 'snapshots', MAX_HISTORY, HISTORY_STREAM_PAGE)],

    // Streamed the same way: at most `limit` estimates (default and most MAX_ESTIMATES), then
    // next_page_token when more remain.
    ['GET', '/api/spacecraft/:id/estimates', async (ctx) => streamedPages(ctx, 'estimates',
      'GetEstimateHistory', {
        spacecraft_id: ctx.params.id,
        from: timeParam(ctx.query, 'from'),
        to: timeParam(ctx.query, 'to'),
      }, 'estimates', MAX_ESTIMATES, ESTIMATE_STREAM_PAGE)],

    // PredictAttitudeStream written as its chunks arrive (predictAnswer), the JSON of
    // PredictAttitude's answer.
    ['GET', '/api/spacecraft/:id/predict', async (ctx) => predictAnswer(ctx, {
      spacecraft_id: ctx.params.id,
      from: timeParam(ctx.query, 'from'),
      to: timeParam(ctx.query, 'to'),
      step_s: numberParam(ctx.query, 'step_s'),
      aem: boolParam(ctx.query, 'aem', false),
    })],

    ['POST', '/api/spacecraft/:id/predict', async (ctx) => {
      const body = await jsonBody(ctx.req, PREDICT_BODY_BYTES);
      let request;
      try {
        request = esgd.convert.fromJson('esg.v1.PredictRequest', body);
      } catch (err) {
        if (err instanceof ConvertError) throw badRequest(`body.${err.message}`);
        throw err;
      }
      if (request.spacecraft_id && request.spacecraft_id !== ctx.params.id) {
        throw badRequest(`body.spacecraft_id: '${request.spacecraft_id}' differs from the path's '${ctx.params.id}'`);
      }
      request.spacecraft_id = ctx.params.id;
      return predictAnswer(ctx, request);
    }, { body: PREDICT_BODY_BYTES }],

    ['GET', '/api/spacecraft/:id/alerts', async (ctx) => alertList(ctx, ctx.params.id)],
    ['GET', '/api/alerts', async (ctx) => alertList(ctx, '')],

    ['POST', '/api/spacecraft/:id/alerts/:sequence/acknowledge', async (ctx) => {
      const sequence = intValue('sequence', ctx.params.sequence, 1, Number.MAX_SAFE_INTEGER);
      const body = await jsonBody(ctx.req, ACKNOWLEDGE_BODY_BYTES);
      for (const key of Object.keys(body)) {
        if (key !== 'operator_name') {
          throw badRequest(`body.${key}: no such field (the body is {"operator_name": "..."}; spacecraft and sequence come from the path)`);
        }
      }
      const operatorName = body.operator_name === undefined ? '' : body.operator_name;
      if (typeof operatorName !== 'string') throw badRequest('body.operator_name: expected a string');
      return call(ctx, 'AcknowledgeAlert', {
        spacecraft_id: ctx.params.id, sequence, operator_name: operatorName,
      });
    }, { body: ACKNOWLEDGE_BODY_BYTES }],

    ['GET', '/api/spacecraft/:id/diagnoses', async (ctx) => ({
      diagnoses: await pages(ctx, 'ListDiagnoses',
        { spacecraft_id: ctx.params.id, page_size: DIAGNOSIS_PAGE }, 'diagnoses'),
    })],

    ['GET', '/api/spacecraft/:id/diagnoses/:diag_id', async (ctx) => {
      const id = intValue('diag_id', ctx.params.diag_id, 1, Number.MAX_SAFE_INTEGER);
      const { report_json: reportJson, ...result } = await call(ctx, 'GetDiagnosis',
        { spacecraft_id: ctx.params.id, id });
      try {
        result.report = JSON.parse(reportJson);
      } catch (err) {
        throw new ApiError(502, 'DATA_LOSS', `diagnosis ${id}: esgd's report_json is not JSON (${err.message})`);
      }
      return result;
    }],

    // ApplyDiagnosis (write role): the diagnosis's findings that map to configuration, applied
    // with replace=true (docs/service.md "Applying a diagnosis"). The body is {} (a JSON body: a form
    // of another site cannot post it, params.js).
    ['POST', '/api/spacecraft/:id/diagnoses/:diag_id/apply', async (ctx) => {
      const diagnosisId = intValue('diag_id', ctx.params.diag_id, 1, Number.MAX_SAFE_INTEGER);
      const body = await jsonBody(ctx.req, ACKNOWLEDGE_BODY_BYTES);
      const extra = Object.keys(body)[0];
      if (extra !== undefined) {
        throw badRequest(`body.${extra}: no such field (the body is {}; spacecraft and diagnosis come from the path)`);
      }
      return call(ctx, 'ApplyDiagnosis', { spacecraft_id: ctx.params.id, diagnosis_id: diagnosisId });
    }, { body: ACKNOWLEDGE_BODY_BYTES }],
  ];
}

module.exports = { makeRoutes, latestStates };
