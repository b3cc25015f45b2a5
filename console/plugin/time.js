// Time conductor: UTC, fixed bounds by default over the fleet's latest flight (the 30 h before the
// newest last frame), because archived and replayed flights are seldom "now". Real-time mode
// follows the browser clock, for spacecraft in flight.
const HOUR = 3600 * 1000;
const DEFAULT_SPAN = 30 * HOUR;

export function conductorOptions(sessions) {
  const lasts = sessions.map((s) => Date.parse(s.last_frame_time)).filter(Number.isFinite);
  const end = lasts.length ? Math.max(...lasts) : Date.now();
  const start = end - DEFAULT_SPAN;
  return {
    menuOptions: [
      {
        name: 'Fixed',
        timeSystem: 'utc',
        bounds: { start, end },
        presets: [
          { label: 'Latest 30 h of the flight', bounds: { start, end } },
          { label: 'Latest 6 h of the flight', bounds: { start: end - 6 * HOUR, end } },
          { label: 'Gap: 6 h after the last frame', bounds: { start: end - HOUR, end: end + 6 * HOUR } }
        ],
        records: 10
      },
      {
        name: 'Realtime',
        timeSystem: 'utc',
        clock: 'local',
        clockOffsets: { start: -2 * HOUR, end: 5 * 60 * 1000 }
      }
    ]
  };
}

// An RFC 3339 time as the service and esg read it (docs/cli.md, "Time spans"): a date, 'T' or a
// blank, hh:mm:ss, an optional fraction, and 'Z' or an offset. Its milliseconds since 1970, or NaN
// for anything else: a date alone, a time without its zone (which Date.parse would read in the
// browser's own time zone), a day the month does not have (which Date.parse rolls over).
export function parseRfc3339(text) {
  const m = /^\s*(\d{4})-(\d{2})-(\d{2})[Tt ](\d{2}):(\d{2}):(\d{2})(\.\d+)?([Zz]|[+-]\d{2}:\d{2})\s*$/
    .exec(String(text));
  if (!m) return NaN;
  const [y, mo, d, h, mi, s] = m.slice(1, 7).map(Number);
  if (mo < 1 || mo > 12 || h > 23 || mi > 59 || s > 59) return NaN;
  const day = new Date(Date.UTC(y, mo - 1, d));
  if (day.getUTCFullYear() !== y || day.getUTCMonth() !== mo - 1 || day.getUTCDate() !== d) return NaN;
  const fraction = m[7] ? m[7].slice(0, 4) : '';  // milliseconds: Date's resolution
  return Date.parse(`${m[1]}-${m[2]}-${m[3]}T${m[4]}:${m[5]}:${m[6]}${fraction}${m[8].toUpperCase()}`);
}
