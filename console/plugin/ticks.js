// Time ticks at round times on Open MCT's plots (docs/console.md "Time ticks", D113).
//
// Open MCT 4.2's plot puts its time-axis ticks at multiples of 1, 2 or 5 times a power of ten of
// milliseconds (00:26:40, 11:33:20) and has no option, format or hook that chooses them: the
// plot's MctTicks component computes them from the axis's display range, and the axis's list of
// tick values it would honour is filled only for an enumerated range axis. So the page draws the
// time axis's labels and vertical grid lines itself, over each plot Open MCT draws:
//   - the plot's displayed time range is read back from Open MCT's own time ticks (each label's
//     full UTC time and its position in percent of the width; two give the range), so zooming,
//     panning and the time conductor are followed as Open MCT follows them;
//   - the ticks are the multiples of a round step (ROUND_STEPS) within that range, the smallest
//     step that puts at most 8 ticks on the plot with their labels apart (fewer on a narrow plot);
//   - Open MCT's labels and vertical grid lines stay in the page, hidden (visibility, so its
//     layout is unchanged); ours carry its CSS classes, so they look the same, but a label is as
//     wide as its text (Open MCT's are a fifth of the plot's width, which cuts a date on a plot
//     of the summary layout).
// Nothing inside node_modules is changed. The page watches the DOM (one MutationObserver) and
// redraws a plot's ticks on the next animation frame after Open MCT redraws its own.

const SECOND = 1000;
const MINUTE = 60 * SECOND;
const HOUR = 60 * MINUTE;
const DAY = 24 * HOUR;

// The round steps. Below a second and beyond two weeks: 1, 2 or 5 times a power of ten of
// milliseconds or of days.
export const ROUND_STEPS = [
  1 * SECOND, 2 * SECOND, 5 * SECOND, 10 * SECOND, 15 * SECOND, 30 * SECOND,
  1 * MINUTE, 2 * MINUTE, 5 * MINUTE, 10 * MINUTE, 15 * MINUTE, 30 * MINUTE,
  1 * HOUR, 2 * HOUR, 3 * HOUR, 6 * HOUR, 12 * HOUR,
  1 * DAY, 2 * DAY, 7 * DAY, 14 * DAY,
];

// Multiples of a week start on Mondays: 1970-01-05 (UTC) was one.
const MONDAY = 4 * DAY;
const MAX_TICKS = 8;
const LABEL_GAP_PX = 12;

function oneTwoFive(target, unit, fromExponent) {
  for (let k = fromExponent; ; k++) {
    for (const m of [1, 2, 5]) {
      const step = m * 10 ** k * unit;
      if (step >= target) return step;
    }
  }
}

// The smallest round step that puts at most `count` steps in `span` [ms].
export function roundStep(span, count) {
  const target = span / Math.max(1, count);
  if (target < SECOND) return Math.max(1, oneTwoFive(target, 1, 0));
  const step = ROUND_STEPS.find((s) => s >= target);
  return step !== undefined ? step : oneTwoFive(target, DAY, 1);
}

// The multiples of a round step within [min, max] (UTC ms); weeks from Mondays. The range is read
// back from the page to about a millionth of its length: a multiple within a hundred-thousandth
// of it outside is an end of the range, kept.
export function ticksOfStep(min, max, step) {
  const origin = step % (7 * DAY) === 0 ? MONDAY : 0;
  const slack = (max - min) * 1e-5;
  const ticks = [];
  for (let t = origin + Math.ceil((min - slack - origin) / step) * step; t <= max + slack; t += step) ticks.push(t);
  return ticks;
}

// Where a label of `width` px stands on an axis of `axisWidth` px, its tick at `x` px: centred on
// the tick, or written from the tick inwards where centring would cut it.
function labelBox(x, width, axisWidth) {
  if (x < width / 2) return { left: x, right: x + width };
  if (axisWidth - x < width / 2) return { left: x - width, right: x };
  return { left: x - width / 2, right: x + width / 2 };
}

// The ticks of a plot's time axis over [min, max] (UTC ms), `axisWidth` px wide: the smallest
// round step with at most MAX_TICKS - 1 steps in the range whose labels (textWidth(text) px wide)
// stand apart. Returns {step, ticks: [{t, text, full}]}.
export function chooseTicks(min, max, axisWidth, textWidth) {
  for (let step = roundStep(max - min, MAX_TICKS - 1); ; step = roundStep(step + 1, 1)) {
    const ticks = ticksOfStep(min, max, step).map((t) => ({ t, ...tickLabel(t, step) }));
    const boxes = ticks.map(({ t, text }) =>
      labelBox(((t - min) / (max - min)) * axisWidth, textWidth(text), axisWidth));
    if (ticks.length <= 1 || boxes.every((b, i) => i === 0 || boxes[i - 1].right + LABEL_GAP_PX <= b.left)) {
      return { step, ticks };
    }
  }
}

// "2026-11-26 08:00:00.000Z", Open MCT's utc format.
const fullTime = (t) => new Date(t).toISOString().replace('T', ' ');

// The label shown: the date at midnight (and for steps of a day or more), else the time of day
// to the step's precision; its full time in the tooltip.
export function tickLabel(t, step) {
  const full = fullTime(t);
  let text;
  if (step >= DAY || t % DAY === 0) text = full.slice(0, 10);
  else if (step >= MINUTE) text = full.slice(11, 16);
  else if (step >= SECOND) text = full.slice(11, 19);
  else text = full.slice(11, 23);
  return { text, full };
}

// Open MCT's time-axis labels of a plot as {t: UTC ms, left: percent}.
function openMctTicks(axis) {
  const labels = axis.querySelectorAll(':scope > .js-ticks .gl-plot-x-tick-label');
  return [...labels].map((el) => ({
    t: Date.parse((el.getAttribute('aria-label') || '').replace(' ', 'T')),
    left: parseFloat(el.style.left),
  })).filter((p) => Number.isFinite(p.t) && Number.isFinite(p.left));
}

// The displayed range of a plot's time axis, from two of Open MCT's ticks; null without two.
function displayedRange(axis) {
  const points = openMctTicks(axis);
  if (points.length < 2) return null;
  const a = points[0];
  const b = points[points.length - 1];
  if (!(b.left > a.left) || !(b.t > a.t)) return null;
  const interval = ((b.t - a.t) * 100) / (b.left - a.left);
  const min = a.t - (a.left * interval) / 100;
  return { min, max: min + interval };
}

function div(className, attrs = {}) {
  const el = document.createElement('div');
  el.className = className;
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, v);
  return el;
}

const OURS = 'data-esg-round-ticks';

function removeOurs(plot) {
  plot.querySelectorAll(`[${OURS}]`).forEach((el) => el.remove());
  delete plot.dataset.esgRoundTime;
}

let measure = null;

// The width in px of a label's text in the font of Open MCT's time-axis labels.
function textWidth(axis) {
  const theirs = axis.querySelector(':scope > .js-ticks .gl-plot-x-tick-label');
  measure = measure || document.createElement('canvas').getContext('2d');
  measure.font = theirs ? getComputedStyle(theirs).font : '11px sans-serif';
  const font = measure.font;
  return (text) => {
    measure.font = font;
    return measure.measureText(text).width;
  };
}

function updatePlot(plot) {
  const axis = plot.querySelector('.gl-plot-x');
  const area = plot.querySelector('.gl-plot-display-area');
  const range = axis && area ? displayedRange(axis) : null;
  if (!range) {
    removeOurs(plot);
    return;
  }
  const axisWidth = axis.clientWidth;
  // Open MCT's vertical grid lines: shown or not (its grid button, a compact plot) as ours.
  const theirGrid = [...area.querySelectorAll(':scope > .js-ticks')].find((el) => el.querySelector('.hash-v'));
  const gridShown = !theirGrid || theirGrid.style.display !== 'none';
  const key = `${range.min}|${range.max}|${axisWidth}`;
  let labels = axis.querySelector(`:scope > [${OURS}]`);
  let grid = area.querySelector(`:scope > [${OURS}]`);
  if (plot.dataset.esgRoundTime !== key || !labels || !grid) {
    removeOurs(plot);
    const { ticks } = chooseTicks(range.min, range.max, axisWidth, textWidth(axis));
    const percent = (t) => (100 * (t - range.min)) / (range.max - range.min);
    labels = div('gl-plot-tick-wrapper', { [OURS]: '' });
    grid = div('u-contents', { [OURS]: '' });
    for (const { t, text, full } of ticks) {
      const label = div('gl-plot-tick gl-plot-x-tick-label', { 'aria-label': full, title: full });
      label.style.left = `${percent(t)}%`;
      label.textContent = text;
      labels.appendChild(label);
      const line = div('gl-plot-hash hash-v');
      line.style.right = `${100 - percent(t)}%`;
      line.style.height = '100%';
      grid.appendChild(line);
    }
    axis.appendChild(labels);
    area.appendChild(grid);
    for (const label of labels.children) {
      const x = (parseFloat(label.style.left) / 100) * axisWidth;
      const box = labelBox(x, label.offsetWidth, axisWidth);
      label.style.transform = `translateX(${box.left - x}px)`;
    }
    plot.dataset.esgRoundTime = key;
  }
  grid.style.display = gridShown ? '' : 'none';
}

const STYLE = `
.gl-plot[data-esg-round-time] .gl-plot-x > .js-ticks,
.gl-plot[data-esg-round-time] .gl-plot-display-area > .js-ticks > .hash-v { visibility: hidden; }
.gl-plot-x > .gl-plot-tick-wrapper[data-esg-round-ticks] { position: absolute; inset: 0; }
.gl-plot-x > [data-esg-round-ticks] > .gl-plot-x-tick-label {
  width: auto; margin-left: 0; overflow: visible;
}
`;

// Whether a DOM change may move a plot's time ticks: Open MCT's ticks redrawn (their text, place
// or tooltip) or nodes added or removed, except the page's own tick nodes.
function relevant(record) {
  const target = record.target.nodeType === Node.ELEMENT_NODE ? record.target : record.target.parentElement;
  if (!target || target.closest(`[${OURS}]`)) return false;
  if (record.type === 'childList') {
    const nodes = [...record.addedNodes, ...record.removedNodes];
    return nodes.some((n) => !(n.nodeType === Node.ELEMENT_NODE && n.hasAttribute(OURS)));
  }
  return !!target.closest('.js-ticks');
}

export function installRoundTimeTicks(openmct) {
  const style = document.createElement('style');
  style.textContent = STYLE;
  document.head.appendChild(style);
  let scheduled = false;
  const update = () => {
    scheduled = false;
    const utc = openmct.time.getTimeSystem()?.key === 'utc';
    document.querySelectorAll('.gl-plot').forEach((plot) => (utc ? updatePlot(plot) : removeOurs(plot)));
  };
  const observer = new MutationObserver((records) => {
    if (scheduled || !records.some(relevant)) return;
    scheduled = true;
    requestAnimationFrame(update);
  });
  observer.observe(document.body, {
    subtree: true, childList: true, characterData: true, attributes: true,
    attributeFilter: ['style', 'aria-label'],
  });
  window.addEventListener('resize', () => {
    if (!scheduled) {
      scheduled = true;
      requestAnimationFrame(update);
    }
  });
}
