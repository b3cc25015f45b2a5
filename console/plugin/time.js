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
