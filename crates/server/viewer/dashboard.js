// The operator dashboard: scrapes the server's own `metrics` once a second and shows
// throughput, active streams, queue depth, the batch-size histogram and latency quantiles
// (over the last minute and since start). <body data-scrapes> counts successful scrapes.

import { headers } from './sse.js';
import { drawChart } from './charts.js';
import { histogram, minus, parse, quantile, sum } from './prom.js';

const $ = (id) => document.getElementById(id);
const PERIOD_MS = 1000;
const HISTORY_S = 120;
const WINDOW_S = 60;

/** [{t: seconds, samples}] oldest first */
const history = [];
let scrapes = 0;

async function scrape() {
  const resp = await fetch('metrics', { headers: headers({ accept: 'text/plain' }) });
  if (!resp.ok) throw new Error(`metrics: HTTP ${resp.status}`);
  return parse(await resp.text());
}

function ago(seconds) {
  const now = history[history.length - 1].t;
  for (const h of history) if (now - h.t <= seconds) return h;
  return history[0];
}

function rate(name, seconds, filter = {}) {
  const a = ago(seconds);
  const b = history[history.length - 1];
  const dt = b.t - a.t;
  return dt > 0 ? (sum(b.samples, name, filter) - sum(a.samples, name, filter)) / dt : NaN;
}

function fmt(v, digits = 0) {
  return Number.isFinite(v) ? v.toFixed(digits) : '–';
}

function tiles(s) {
  const items = [
    ['ready', sum(s, 'dynaserve_ready') === 1 ? 'yes' : 'no', ''],
    ['scene-steps/s', fmt(rate('dynaserve_scene_steps_total', 5)), 'over the last 5 s'],
    ['object-steps/s', fmt(rate('dynaserve_object_steps_total', 5)), 'over the last 5 s'],
    ['active rollouts', fmt(sum(s, 'dynaserve_active_rollouts')), 'streams running'],
    ['predict variants', fmt(sum(s, 'dynaserve_active_predict_variants')), 'in flight'],
    ['queue depth', fmt(sum(s, 'dynaserve_queue_depth')), 'steps waiting'],
    ['requests/s', fmt(rate('dynaserve_requests_total', 5), 1), 'over the last 5 s'],
    ['failures', fmt(sum(s, 'dynaserve_request_failures_total')), 'since start'],
    ['models', fmt(sum(s, 'dynaserve_models_loaded')), 'resident'],
  ];
  $('tiles').replaceChildren(
    ...items.map(([name, value, note]) => {
      const d = document.createElement('div');
      d.className = 'tile';
      const b = document.createElement('b');
      b.textContent = value;
      const small = document.createElement('small');
      small.textContent = note ? `${name} · ${note}` : name;
      d.append(b, small);
      return d;
    }),
  );
}

function throughput() {
  const pts = [];
  const t0 = history[history.length - 1].t - HISTORY_S;
  for (let i = 1; i < history.length; i++) {
    const a = history[i - 1], b = history[i];
    const dt = b.t - a.t;
    if (dt <= 0) continue;
    const v = (sum(b.samples, 'dynaserve_scene_steps_total') - sum(a.samples, 'dynaserve_scene_steps_total')) / dt;
    pts.push([b.t - t0, v]);
  }
  drawChart($('throughput'), [{ label: 'scene-steps/s', colour: '#4aa3df', points: pts }], { xMax: HISTORY_S, xLabel: 'seconds' });
}

function batches(s) {
  const h = histogram(s, 'dynaserve_batch_scenes');
  const labels = [];
  const counts = [];
  h.bounds.forEach((b, i) => {
    const prev = i === 0 ? 0 : h.bounds[i - 1];
    labels.push(b === Infinity ? `>${prev}` : b === prev + 1 || i === 0 ? `${b}` : `${prev + 1}-${b}`);
    counts.push(h.cumulative[i] - (i === 0 ? 0 : h.cumulative[i - 1]));
  });
  // Trim empty buckets at the top so the chart shows the range in use.
  let last = counts.length - 1;
  while (last > 0 && counts[last] === 0) last--;
  drawChart(
    $('batches'),
    [{ label: 'passes', colour: '#3bb273', kind: 'bar', points: counts.slice(0, last + 1).map((c, i) => [i, c]) }],
    { bars: labels.slice(0, last + 1), yLabel: 'passes' },
  );
}

function latency(s) {
  const rows = [
    ['rollout (request)', 'dynaserve_request_duration_seconds', { method: 'rollout' }],
    ['predict (request)', 'dynaserve_request_duration_seconds', { method: 'predict' }],
    ['queue wait (step)', 'dynaserve_queue_wait_seconds', {}],
    ['forward pass', 'dynaserve_forward_duration_seconds', {}],
  ];
  const head = document.createElement('tr');
  for (const t of ['', 'p50 1 min', 'p90 1 min', 'p99 1 min', 'p50 all', 'p99 all', 'count']) {
    const th = document.createElement('th');
    th.textContent = t;
    head.append(th);
  }
  const body = rows.map(([label, name, filter]) => {
    const all = histogram(s, name, filter);
    const recent = minus(all, histogram(ago(WINDOW_S).samples, name, filter));
    const cells = [
      label,
      ...[0.5, 0.9, 0.99].map((q) => fmt(1000 * quantile(recent, q), 2)),
      ...[0.5, 0.99].map((q) => fmt(1000 * quantile(all, q), 2)),
      fmt(all.count),
    ];
    const tr = document.createElement('tr');
    for (const c of cells) {
      const td = document.createElement('td');
      td.textContent = c;
      tr.append(td);
    }
    return tr;
  });
  $('latency').replaceChildren(head, ...body);
}

async function poll() {
  try {
    const samples = await scrape();
    const t = performance.now() / 1000;
    history.push({ t, samples });
    while (history.length > 2 && t - history[0].t > HISTORY_S) history.shift();
    tiles(samples);
    throughput();
    batches(samples);
    latency(samples);
    $('error').textContent = '';
    $('updated').textContent = `updated ${new Date().toLocaleTimeString()}`;
    document.body.dataset.scrapes = String(++scrapes);
  } catch (e) {
    $('error').textContent = `cannot read the server's metrics: ${e.message}`;
  }
  setTimeout(poll, PERIOD_MS);
}

poll();
