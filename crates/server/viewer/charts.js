// Small charts on a 2D canvas: lines and bars against a shared x axis, an optional right-hand
// axis, a legend, and a vertical marker (the frame shown).

const AXIS = '#8a94a0';
const GRID = '#2c323a';
const TEXT = '#c8d0d8';

function niceMax(v) {
  if (!(v > 0)) return 1;
  const p = 10 ** Math.floor(Math.log10(v));
  for (const m of [1, 2, 2.5, 5, 10]) if (v <= m * p) return m * p;
  return 10 * p;
}

function fmt(v) {
  if (v === 0) return '0';
  const a = Math.abs(v);
  if (a >= 100) return v.toFixed(0);
  if (a >= 10) return v.toFixed(1);
  if (a >= 0.1) return v.toFixed(2);
  return v.toPrecision(2);
}

/**
 * Draws `series` on `canvas`. Each series: `{label, colour, points: [[x, y], ...], kind:
 * 'line' | 'bar', right: bool}`. Options: `xMax`, `xLabel`, `yLabel`, `y2Label`, `marker`
 * (an x to highlight), `bars` (labels of categorical bars: then points are [index, value]).
 */
export function drawChart(canvas, series, opts = {}) {
  const dpr = window.devicePixelRatio || 1;
  const w = canvas.clientWidth;
  const h = canvas.clientHeight;
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
    canvas.width = Math.round(w * dpr);
    canvas.height = Math.round(h * dpr);
  }
  const g = canvas.getContext('2d');
  g.setTransform(dpr, 0, 0, dpr, 0, 0);
  g.clearRect(0, 0, w, h);
  g.font = '11px system-ui, sans-serif';
  const hasRight = series.some((s) => s.right);
  const pad = { l: 44, r: hasRight ? 40 : 10, t: 18, b: 20 };
  const pw = w - pad.l - pad.r;
  const ph = h - pad.t - pad.b;
  if (pw <= 10 || ph <= 10) return;
  const ymax = (right) =>
    niceMax(Math.max(0, ...series.filter((s) => !!s.right === right).flatMap((s) => s.points.map((p) => p[1]))));
  const yl = ymax(false);
  const yr = ymax(true);
  const bars = opts.bars;
  const xMax = bars ? bars.length : Math.max(opts.xMax || 0, ...series.flatMap((s) => s.points.map((p) => p[0])), 1e-9);
  const X = (x) => pad.l + (bars ? (x + 0.5) / xMax : x / xMax) * pw;
  const Y = (y, right) => pad.t + ph - (y / (right ? yr : yl)) * ph;

  g.strokeStyle = GRID;
  g.fillStyle = TEXT;
  g.lineWidth = 1;
  for (let i = 0; i <= 4; i++) {
    const y = pad.t + (ph * i) / 4;
    g.beginPath();
    g.moveTo(pad.l, y);
    g.lineTo(pad.l + pw, y);
    g.stroke();
    g.textAlign = 'right';
    g.fillText(fmt((yl * (4 - i)) / 4), pad.l - 4, y + 4);
    if (hasRight) {
      g.textAlign = 'left';
      g.fillText(fmt((yr * (4 - i)) / 4), pad.l + pw + 4, y + 4);
    }
  }
  g.strokeStyle = AXIS;
  g.strokeRect(pad.l, pad.t, pw, ph);
  g.textAlign = 'center';
  if (bars) {
    const every = Math.ceil(bars.length / Math.max(1, Math.floor(pw / 34)));
    bars.forEach((b, i) => {
      if (i % every === 0) g.fillText(b, X(i), h - 6);
    });
  } else {
    for (let i = 0; i <= 4; i++) g.fillText(fmt((xMax * i) / 4), pad.l + (pw * i) / 4, h - 6);
  }
  if (opts.xLabel) {
    g.textAlign = 'right';
    g.fillText(opts.xLabel, pad.l + pw, pad.t - 5);
  }
  if (opts.yLabel) {
    g.textAlign = 'left';
    g.fillText(opts.yLabel, 4, 11);
  }

  const nBarSeries = series.filter((s) => s.kind === 'bar').length;
  let barIndex = 0;
  for (const s of series) {
    g.strokeStyle = s.colour;
    g.fillStyle = s.colour;
    if (s.kind === 'bar') {
      const slot = bars ? pw / xMax : Math.max(pw / Math.max(s.points.length, 1), 1);
      const bw = Math.max((slot * 0.8) / nBarSeries, 1);
      g.globalAlpha = 0.55;
      for (const [x, y] of s.points) {
        const x0 = X(x) - (slot * 0.8) / 2 + barIndex * bw;
        const y0 = Y(y, s.right);
        g.fillRect(x0, y0, bw, pad.t + ph - y0);
      }
      g.globalAlpha = 1;
      barIndex++;
    } else {
      g.lineWidth = 1.6;
      g.beginPath();
      s.points.forEach(([x, y], i) => (i ? g.lineTo(X(x), Y(y, s.right)) : g.moveTo(X(x), Y(y, s.right))));
      g.stroke();
    }
  }
  if (opts.marker !== undefined && opts.marker !== null) {
    g.strokeStyle = '#ffffff';
    g.globalAlpha = 0.5;
    g.beginPath();
    g.moveTo(X(opts.marker), pad.t);
    g.lineTo(X(opts.marker), pad.t + ph);
    g.stroke();
    g.globalAlpha = 1;
  }
  // legend
  let lx = pad.l + 4;
  g.textAlign = 'left';
  for (const s of series) {
    g.fillStyle = s.colour;
    g.fillRect(lx, 5, 10, 8);
    g.fillStyle = TEXT;
    const label = s.right && opts.y2Label ? `${s.label} (${opts.y2Label})` : s.label;
    g.fillText(label, lx + 13, 13);
    lx += g.measureText(label).width + 26;
  }
}
