// Calls to the server's HTTP API with relative URLs (the page may sit behind a gateway under a
// path prefix), and a reader of the Server-Sent Events a streamed rollout or generation
// answers.

const TOKEN_KEY = 'dynaserve-token';

/** Request headers, with the bearer token the user gave if the server asked for one. */
export function headers(extra = {}) {
  const h = { ...extra };
  const token = sessionStorage.getItem(TOKEN_KEY);
  if (token) h.authorization = `Bearer ${token}`;
  return h;
}

/** Remembers a bearer token for this tab (the server answers 401 without one). */
export function setToken(token) {
  if (token) sessionStorage.setItem(TOKEN_KEY, token);
  else sessionStorage.removeItem(TOKEN_KEY);
}

/** The message of a failed response: the server's error document when there is one. */
async function failure(resp) {
  const text = await resp.text();
  try {
    const doc = JSON.parse(text);
    if (doc.error) return new ApiFailure(resp.status, doc.error.message || doc.error.code);
  } catch (_) {
    // not JSON: fall through
  }
  return new ApiFailure(resp.status, text.trim() || resp.statusText);
}

/** An HTTP error answer, with its status. */
export class ApiFailure extends Error {
  constructor(status, message) {
    super(`HTTP ${status}: ${message}`);
    this.status = status;
  }
}

/** GETs a JSON document at a relative path. */
export async function getJson(path) {
  const resp = await fetch(path, { headers: headers({ accept: 'application/json' }) });
  if (!resp.ok) throw await failure(resp);
  return resp.json();
}

/**
 * POSTs `request` to a streaming route (`v1/rollout`: `frame` events; `v1/generate`:
 * `progress` and `sample` events; both end with `done` or `error`) asking for Server-Sent
 * Events, and calls `onEvent(name, data)` for each event, with `data` parsed from JSON.
 * Resolves when the stream ends; rejects on a failed request. `signal` (an AbortSignal)
 * stops it.
 */
export async function streamPost(path, request, onEvent, signal) {
  const resp = await fetch(path, {
    method: 'POST',
    headers: headers({ 'content-type': 'application/json', accept: 'text/event-stream' }),
    body: JSON.stringify(request),
    signal,
  });
  if (!resp.ok) throw await failure(resp);
  const reader = resp.body.pipeThrough(new TextDecoderStream()).getReader();
  let buffer = '';
  for (;;) {
    const { value, done } = await reader.read();
    if (done) break;
    buffer += value.replace(/\r\n?/g, '\n');
    let end;
    while ((end = buffer.indexOf('\n\n')) >= 0) {
      const block = buffer.slice(0, end);
      buffer = buffer.slice(end + 2);
      let name = 'message';
      const data = [];
      for (const line of block.split('\n')) {
        if (line.startsWith(':')) continue; // keep-alive comment
        const colon = line.indexOf(':');
        const field = colon < 0 ? line : line.slice(0, colon);
        const val = colon < 0 ? '' : line.slice(colon + 1).replace(/^ /, '');
        if (field === 'event') name = val;
        else if (field === 'data') data.push(val);
      }
      if (data.length) onEvent(name, JSON.parse(data.join('\n')));
    }
  }
}
