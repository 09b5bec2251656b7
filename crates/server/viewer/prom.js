// Reading the server's own Prometheus text exposition (`GET metrics`): samples, sums over
// labels, histograms and their quantiles (linear inside a bucket, as Prometheus'
// histogram_quantile does).

/** Parses the text format into `[{name, labels: {k: v}, value}]` (comments skipped). */
export function parse(text) {
  const out = [];
  for (const line of text.split('\n')) {
    if (!line || line.startsWith('#')) continue;
    const m = /^([a-zA-Z_:][a-zA-Z0-9_:]*)(\{(.*)\})?\s+(\S+)/.exec(line);
    if (!m) continue;
    const labels = {};
    if (m[3]) {
      const re = /([a-zA-Z_][a-zA-Z0-9_]*)="((?:[^"\\]|\\.)*)"/g;
      let l;
      while ((l = re.exec(m[3]))) labels[l[1]] = l[2].replace(/\\(.)/g, (_, c) => (c === 'n' ? '\n' : c));
    }
    out.push({ name: m[1], labels, value: Number(m[4]) });
  }
  return out;
}

function matches(labels, filter) {
  return Object.entries(filter).every(([k, v]) => labels[k] === v);
}

/** Sum of every sample named `name` whose labels include `filter`. */
export function sum(samples, name, filter = {}) {
  return samples.filter((s) => s.name === name && matches(s.labels, filter)).reduce((a, s) => a + s.value, 0);
}

/**
 * The histogram `name` summed over the series matching `filter`: `{bounds: [le...], cumulative:
 * [count...], count, sum}` with bounds ascending and +Inf last.
 */
export function histogram(samples, name, filter = {}) {
  const byLe = new Map();
  for (const s of samples) {
    if (s.name !== `${name}_bucket` || !matches(s.labels, filter)) continue;
    const le = s.labels.le === '+Inf' ? Infinity : Number(s.labels.le);
    byLe.set(le, (byLe.get(le) || 0) + s.value);
  }
  const bounds = [...byLe.keys()].sort((a, b) => a - b);
  return {
    bounds,
    cumulative: bounds.map((b) => byLe.get(b)),
    count: sum(samples, `${name}_count`, filter),
    sum: sum(samples, `${name}_sum`, filter),
  };
}

/** `a - b` bucket by bucket (the observations between two scrapes); `b` may be null. */
export function minus(a, b) {
  if (!b || b.bounds.length !== a.bounds.length) return a;
  return {
    bounds: a.bounds,
    cumulative: a.cumulative.map((c, i) => c - b.cumulative[i]),
    count: a.count - b.count,
    sum: a.sum - b.sum,
  };
}

/** The q-quantile (0..1) of a histogram, or NaN when it holds no observation. */
export function quantile(h, q) {
  const total = h.cumulative[h.cumulative.length - 1] || 0;
  if (!(total > 0)) return NaN;
  const rank = q * total;
  for (let i = 0; i < h.bounds.length; i++) {
    if (h.cumulative[i] >= rank) {
      const upper = h.bounds[i];
      const lower = i === 0 ? 0 : h.bounds[i - 1];
      if (upper === Infinity) return lower;
      const below = i === 0 ? 0 : h.cumulative[i - 1];
      const inBucket = h.cumulative[i] - below;
      return inBucket > 0 ? lower + ((upper - lower) * (rank - below)) / inBucket : upper;
    }
  }
  return h.bounds[h.bounds.length - 2] || NaN;
}
