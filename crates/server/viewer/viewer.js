// The viewer page: pick a model and a scene (an example, or a dropped scene file). For a model
// that rolls scenes out (family `rollout`), stream its rollout from the server and draw each
// frame as it arrives; for a PhysiFormer model (family `generate`), show the denoising
// progress, then play the sampled trajectory back as deforming meshes in the model's box.
// Play, pause and scrub; chart the server's per-step timings and, when the scene has ground
// truth, the error against time. "Beside" rolls the same scene out on a second resident model
// (the rapier simulator shows what the learned model should have predicted) and draws it as
// the ghost in place of the example's ground truth. A model that estimates its uncertainty (an
// ensemble) sends each object's spread with every frame: charted per object against time, and
// given for the step on screen.
//
// The page reports its progress on <body> for people and for tests: data-state (loading, idle,
// running, done, stopped, error), data-family (rollout or generate), data-frames (rollout:
// steps received; generate: frames of the sampled trajectory, frame 0 included), data-requested
// (steps or frames asked for), data-denoised (denoising steps completed) and data-shown (the
// step or frame on screen).

import {
  View,
  bodiesOf,
  boxCorners,
  initialPositions,
  meanDistance,
  meshBodiesOf,
  objectColour,
  positionsOf,
  sampleFrames,
} from './scene.js';
import { ApiFailure, getJson, headers, setToken, streamPost } from './sse.js';
import { drawChart } from './charts.js';

const $ = (id) => document.getElementById(id);

const st = {
  view: null,
  models: [],
  /** example lists by family: rollout bodies and generate bodies */
  examples: { rollout: [], generate: [] },
  family: 'rollout',
  example: null,
  bodies: null,
  /** index 0: the initial state; index k: step k. Each {step, time, positions, timing}. */
  frames: [],
  /** ground truth in the same layout, or null */
  truth: null,
  requested: 0,
  running: false,
  abort: null,
  playing: false,
  cursor: 0,
  shown: 0,
  stepSeconds: 1 / 24,
  startedAt: 0,
  finishedAt: 0,
  /** generate: denoising steps asked for, completed, and each step's timing */
  denoiseSteps: 0,
  denoised: 0,
  progress: [],
  sampled: false,
};

function setState(s) {
  document.body.dataset.state = s;
}

function showError(message) {
  $('error').textContent = message || '';
}

function currentModel() {
  return st.models.find((m) => m.name === $('model').value) || st.models[0];
}

/** The calls a model answers: `generate` (PhysiFormer) or `rollout` (every other model). */
function familyOf(model) {
  return model && model.architecture === 'physiformer' ? 'generate' : 'rollout';
}

/** The example list of the selected model's family. */
function examples() {
  return st.examples[st.family];
}

// ----- scene selection -----

/** Switches the page to `family`: its inputs, its example list, its floor or box. */
function setFamily(family) {
  st.family = family;
  document.body.dataset.family = family;
  $('rollout-inputs').hidden = family !== 'rollout';
  $('generate-inputs').hidden = family !== 'generate';
  $('denoise-box').hidden = true;
}

function fillExamples(selectName) {
  const sel = $('example');
  sel.replaceChildren(
    ...examples().map((e, i) => {
      const o = document.createElement('option');
      o.value = String(i);
      o.textContent = e.ground_truth && e.ground_truth.length ? `${e.title} (with ground truth)` : e.title;
      return o;
    }),
  );
  const i = Math.max(0, examples().findIndex((e) => e.name === selectName));
  sel.value = String(i);
}

/** Shows a scene's initial state without running it (and points the camera at it unless
 * `keepCamera`). */
function selectExample(example, keepCamera = false) {
  st.example = example;
  if (st.family === 'generate') return selectMeshExample(example, keepCamera);
  const req = example.request;
  $('steps').value = String(req.steps || 48);
  $('dt-steps').value = String(req.dt_steps || 1);
  try {
    st.bodies = bodiesOf(req);
  } catch (e) {
    showError(`${example.name}: ${e.message}`);
    return false;
  }
  const initial = initialPositions(req, st.bodies);
  st.frames = [{ step: 0, time: 0, positions: initial, timing: null }];
  st.truth = null;
  st.requested = 0;
  st.view.setBox(null);
  st.view.setBodies(st.bodies, hasTruth(example));
  st.view.show(initial);
  st.view.show(null, 'truth');
  if (!keepCamera) st.view.frame(initial);
  legend();
  showFrame(0);
  charts();
  return true;
}

/** `selectExample` for a mesh scene (a generate body): its frame-0 vertices in the model's box. */
function selectMeshExample(example, keepCamera) {
  const req = example.request;
  const model = currentModel();
  $('gen-frames').value = String(req.frames || (model && model.max_frames) || 49);
  $('denoise-steps').value = String(req.denoise_steps || (model && model.default_denoise_steps) || 16);
  $('seed').value = String(req.seed || 0);
  try {
    st.bodies = meshBodiesOf(req);
  } catch (e) {
    showError(`${example.name}: ${e.message}`);
    return false;
  }
  const initial = st.bodies.map((b) => b.points);
  st.frames = [{ step: 0, time: 0, positions: initial, fits: null, timing: null }];
  st.truth = null;
  st.requested = 0;
  resetDenoise(0);
  $('denoise-box').hidden = true;
  const e = (model && model.box_half_extent) || 1;
  st.view.setBox(e);
  st.view.setBodies(st.bodies, false);
  st.view.show(initial);
  st.view.show(null, 'truth');
  if (!keepCamera) st.view.frame(boxCorners(e), 1.2);
  legend();
  showFrame(0);
  charts();
  return true;
}

function hasTruth(example) {
  return !!($('ghost').value || (example.ground_truth && example.ground_truth.length));
}

function legend() {
  const box = $('legend');
  const items = st.bodies.map((b, j) => {
    const row = document.createElement('div');
    const sw = document.createElement('span');
    sw.className = 'swatch';
    sw.style.background = objectColour(j);
    const n = b.points.length / 3;
    const what = b.material
      ? `${b.material} ${b.faces ? 'mesh' : 'points'}, ${n} vertices`
      : b.faces ? `mesh, ${n} vertices` : `${n} points`;
    const fit = document.createElement('span');
    fit.className = 'fit';
    row.append(sw, `object ${j}: ${what}`, fit);
    return row;
  });
  if (hasTruth(st.example)) {
    const row = document.createElement('div');
    const sw = document.createElement('span');
    sw.className = 'swatch';
    sw.style.background = '#bfc5cc';
    row.append(sw, `ghost: ${$('ghost').value || 'ground truth'}`);
    items.push(row);
  }
  box.replaceChildren(...items);
}

/** Reads a dropped or chosen file: a rollout request, a bare scene, or an example document. */
async function loadFile(file) {
  showError('');
  let doc;
  try {
    doc = JSON.parse(await file.text());
  } catch (e) {
    showError(`${file.name}: not JSON (${e.message})`);
    return;
  }
  let example;
  if (doc && doc.request && doc.request.scene) {
    example = { name: doc.name || file.name, title: doc.title || file.name, request: doc.request, ground_truth: doc.ground_truth || [] };
  } else if (doc && doc.scene && Array.isArray(doc.scene.objects)) {
    example = { name: file.name, title: `${file.name}: ${doc.scene.objects.length} objects`, request: doc, ground_truth: [] };
  } else if (doc && Array.isArray(doc.objects)) {
    const request = isMeshScene(doc) ? { scene: doc } : { scene: doc, steps: 48 };
    example = { name: file.name, title: `${file.name}: ${doc.objects.length} objects`, request, ground_truth: [] };
  } else {
    showError(
      `${file.name}: expected a rollout request ({"scene": {"objects": [...]}, "steps": n}), a generate request ` +
        `({"scene": {"objects": [{"vertices": [...], "material": "elastic"}]}, "frames": n}) or a scene ({"objects": [...]})`,
    );
    return;
  }
  // A mesh scene (objects given by world-frame vertices) is sampled by a PhysiFormer model,
  // anything else rolled out: switch to a model of that family if needed.
  const family = isMeshScene(example.request.scene) ? 'generate' : 'rollout';
  if (family !== st.family) {
    const model = st.models.find((m) => familyOf(m) === family);
    if (!model) {
      showError(`${file.name}: no resident model ${family === 'generate' ? 'samples mesh scenes (PhysiFormer)' : 'rolls scenes out'}`);
      return;
    }
    stop();
    $('model').value = model.name;
    setFamily(family);
  }
  st.examples[family].push(example);
  fillExamples(example.name);
  if (selectExample(example)) run();
}

/** Whether a scene is a generate scene: its objects are given by world-frame vertices. */
function isMeshScene(scene) {
  return Array.isArray(scene.objects) && scene.objects.length > 0 && scene.objects.every((o) => Array.isArray(o.vertices));
}

// ----- running -----

function positiveInt(id, name, max) {
  const v = Number($(id).value);
  if (!Number.isInteger(v) || v < 1) throw new Error(`${name} must be a whole number >= 1`);
  if (max && v > max) throw new Error(`${name} must be at most ${max} for this model`);
  return v;
}

async function run() {
  if (!st.example) return;
  stop();
  showError('');
  const model = currentModel();
  if (st.family === 'generate') return runGenerate(model);
  let steps, dtSteps;
  try {
    steps = positiveInt('steps', 'steps', model && model.max_steps);
    dtSteps = positiveInt('dt-steps', 'step size', model && model.max_dt_steps);
  } catch (e) {
    showError(e.message);
    return;
  }
  if (!selectExampleKeepInputs()) return;
  const req = { ...st.example.request, model: model ? model.name : '', steps, dt_steps: dtSteps, stream: true };
  delete req.timeout_ms;
  st.requested = steps;
  st.stepSeconds = dtSteps * (model ? model.dt_frame : 1 / 24);
  st.truth = $('ghost').value ? null : truthFrames(st.example, dtSteps);
  st.view.show(st.truth ? st.truth[0].positions : null, 'truth');
  st.running = true;
  st.playing = true;
  st.cursor = 0;
  st.startedAt = performance.now();
  const abort = new AbortController();
  st.abort = abort;
  if ($('ghost').value) ghostRollout($('ghost').value, { ...req, stream: false });
  setState('running');
  buttons();
  progress();
  try {
    await streamPost('v1/rollout', req, (name, data) => onEvent(name, data), abort.signal);
    if (st.abort !== abort || !st.running) return;
    if (document.body.dataset.state === 'error') finish('error');
    else if (received() < st.requested) {
      showError(`the stream ended after ${received()} of ${st.requested} steps`);
      finish('error');
    } else finish('done');
  } catch (e) {
    if (st.abort !== abort) return; // superseded by another run
    if (e.name === 'AbortError') {
      finish('stopped');
      return;
    }
    if (e instanceof ApiFailure && e.status === 401) $('token-box').hidden = false;
    showError(e.message);
    finish('error');
  }
}

/**
 * Samples the selected mesh scene with a PhysiFormer model (`POST v1/generate`, one sample,
 * streamed): the progress bar follows the denoising steps, then the trajectory plays.
 */
async function runGenerate(model) {
  let frames, denoiseSteps, seed;
  try {
    frames = positiveInt('gen-frames', 'frames', model && model.max_frames);
    if (frames < 2) throw new Error('frames must be at least 2 (frame 0 and one more)');
    denoiseSteps = positiveInt('denoise-steps', 'denoising steps', model && model.max_denoise_steps);
    seed = Number($('seed').value);
    if (!Number.isSafeInteger(seed) || seed < 0) throw new Error('seed must be a whole number >= 0');
  } catch (e) {
    showError(e.message);
    return;
  }
  if (!selectExampleKeepInputs()) return;
  const req = { ...st.example.request, model: model ? model.name : '', frames, denoise_steps: denoiseSteps, seed, samples: 1, stream: true };
  delete req.timeout_ms;
  st.requested = frames;
  st.stepSeconds = model ? model.dt_frame : 1 / 48;
  resetDenoise(denoiseSteps);
  $('denoise-box').hidden = false;
  st.running = true;
  st.playing = false;
  st.cursor = 0;
  st.startedAt = performance.now();
  const abort = new AbortController();
  st.abort = abort;
  setState('running');
  buttons();
  progress();
  try {
    await streamPost('v1/generate', req, (name, data) => onGenerateEvent(name, data), abort.signal);
    if (st.abort !== abort || !st.running) return;
    if (document.body.dataset.state === 'error') finish('error');
    else if (!st.sampled) {
      showError(`the stream ended after ${st.denoised} of ${st.denoiseSteps} denoising steps, before the trajectory`);
      finish('error');
    } else finish('done');
  } catch (e) {
    if (st.abort !== abort) return; // superseded by another run
    if (e.name === 'AbortError') {
      finish('stopped');
      return;
    }
    if (e instanceof ApiFailure && e.status === 401) $('token-box').hidden = false;
    showError(e.message);
    finish('error');
  }
}

/** Clears the denoising progress for a run of `steps` denoising steps. */
function resetDenoise(steps) {
  st.denoiseSteps = steps;
  st.denoised = 0;
  st.progress = [];
  st.sampled = false;
  denoiseProgress();
}

function denoiseProgress() {
  document.body.dataset.denoised = String(st.denoised);
  $('denoise').max = Math.max(st.denoiseSteps, 1);
  $('denoise').value = st.denoised;
  const last = st.progress[st.progress.length - 1];
  $('denoise-text').textContent = st.sampled
    ? `denoised in ${st.denoiseSteps} steps; trajectory of ${st.frames.length} frames received`
    : `denoising step ${st.denoised} of ${st.denoiseSteps}` + (last ? ` (flow time ${last.t.toFixed(2)})` : '');
}

function onGenerateEvent(name, data) {
  if (name === 'progress') {
    st.denoised = data.step;
    st.progress.push(data);
    denoiseProgress();
    progress();
    charts();
  } else if (name === 'sample') {
    if (data.sample !== 0 || st.sampled) return;
    let frames;
    try {
      frames = sampleFrames(data, st.bodies);
    } catch (e) {
      showError(e.message);
      setState('error');
      return;
    }
    st.frames = frames;
    st.sampled = true;
    st.cursor = 0;
    st.playing = true;
    denoiseProgress();
    progress();
    showFrame(0);
  } else if (name === 'error') {
    showError(`${data.error.code}: ${data.error.message}`);
    setState('error');
  } else if (name === 'done') {
    st.done = data;
  }
}

/** Re-selects the current example's bodies while keeping the inputs the user typed. */
function selectExampleKeepInputs() {
  const ids = ['steps', 'dt-steps', 'gen-frames', 'denoise-steps', 'seed'];
  const kept = ids.map((id) => $(id).value);
  const ok = selectExample(st.example, true);
  ids.forEach((id, i) => {
    $(id).value = kept[i];
  });
  return ok;
}

/** Rolls the request out on the model `name` and shows its frames as the ghost. */
async function ghostRollout(name, request) {
  const abort = st.abort;
  try {
    const resp = await fetch('v1/rollout', {
      method: 'POST',
      headers: headers({ 'content-type': 'application/json' }),
      body: JSON.stringify({ ...request, model: name }),
    });
    const doc = await resp.json();
    if (!resp.ok) throw new Error(`${name}: ${doc.message || resp.status}`);
    if (st.abort !== abort) return; // another run started meanwhile
    const frames = [st.frames[0]];
    for (const f of doc.frames) frames.push({ step: f.step, time: f.time, positions: positionsOf(f, st.bodies) });
    st.truth = frames;
    st.view.show(frames[0].positions, 'truth');
    charts();
  } catch (e) {
    showError(`beside: ${e.message}`);
  }
}

function truthFrames(example, dtSteps) {
  if (!hasTruth(example)) return null;
  if ((example.request.dt_steps || 1) !== dtSteps) {
    showError(`ground truth is for step size ${example.request.dt_steps || 1}; not shown at step size ${dtSteps}`);
    return null;
  }
  const frames = [st.frames[0]];
  for (const f of example.ground_truth) frames.push({ step: f.step, time: f.time, positions: positionsOf(f, st.bodies) });
  return frames;
}

function onEvent(name, data) {
  if (name === 'frame') {
    let positions;
    try {
      positions = positionsOf(data, st.bodies);
    } catch (e) {
      showError(e.message);
      return;
    }
    st.frames.push({ step: data.step, time: data.time, positions, timing: data.timing || null, spread: data.spread || null });
    if (st.frames.length === 2 && data.time > 0) st.stepSeconds = data.time / data.step;
    progress();
    charts();
  } else if (name === 'error') {
    showError(`${data.error.code}: ${data.error.message}`);
    setState('error');
  } else if (name === 'done') {
    st.done = data;
  }
}

function finish(state) {
  st.running = false;
  st.finishedAt = performance.now();
  setState(state);
  buttons();
  progress();
  charts();
}

function stop() {
  if (st.abort) st.abort.abort();
}

function buttons() {
  $('stop').disabled = !st.running;
}

// ----- playback -----

function received() {
  return st.frames.length - 1;
}

function progress() {
  const wall = ((st.running ? performance.now() : st.finishedAt) - st.startedAt) / 1000;
  const state = document.body.dataset.state;
  if (st.family === 'generate') {
    const n = st.sampled ? st.frames.length : 0;
    document.body.dataset.frames = String(n);
    document.body.dataset.requested = String(st.requested);
    $('frames').textContent = `${n} / ${st.requested} frames`;
    $('timeline').max = String(Math.max(st.requested - 1, received(), 0));
    $('status').textContent = !st.requested
      ? 'ready'
      : st.sampled
        ? `${state}: ${n} frames sampled in ${st.denoiseSteps} denoising steps, ${wall.toFixed(2)} s`
        : `${state}: denoising step ${st.denoised} of ${st.denoiseSteps} in ${wall.toFixed(2)} s`;
    return;
  }
  const n = received();
  document.body.dataset.frames = String(n);
  document.body.dataset.requested = String(st.requested);
  $('frames').textContent = `${n} / ${st.requested} frames`;
  $('timeline').max = String(Math.max(st.requested, n));
  const rate = n && wall > 0 ? ` · ${(n / wall).toFixed(0)} steps/s` : '';
  $('status').textContent = st.requested ? `${state}: ${n} of ${st.requested} steps in ${wall.toFixed(2)} s${rate}` : 'ready';
}

function showFrame(i) {
  i = Math.max(0, Math.min(i, received()));
  st.shown = i;
  const f = st.frames[i];
  st.view.show(f.positions);
  if (st.truth) {
    const t = st.truth[Math.min(i, st.truth.length - 1)];
    st.view.show(t.positions, 'truth');
  }
  document.body.dataset.shown = String(i);
  $('timeline').value = String(i);
  $('clock').textContent = `${st.family === 'generate' ? 'frame' : 'step'} ${f.step} · ${f.time.toFixed(3)} s`;
  // Rigid objects of a sampled trajectory: how far the vertices are from a rigid motion.
  $('legend').querySelectorAll('.fit').forEach((el, j) => {
    const fit = f.fits ? f.fits[j] : null;
    el.textContent = typeof fit === 'number' ? ` · ${(fit * 1000).toFixed(1)} mm off rigid` : '';
  });
  $('play').textContent = st.playing ? '❚❚' : '▶';
}

function tick(now) {
  const dt = (now - (tick.last || now)) / 1000;
  tick.last = now;
  if (st.playing) {
    st.cursor = Math.min(st.cursor + dt / st.stepSeconds, received());
    const i = Math.floor(st.cursor);
    if (i !== st.shown) showFrame(i);
    if (i >= received() && !st.running) {
      st.playing = false;
      showFrame(i);
    }
  }
  requestAnimationFrame(tick);
}

function togglePlay() {
  st.playing = !st.playing;
  if (st.playing && st.shown >= received() && !st.running) st.cursor = 0;
  else st.cursor = st.shown;
  showFrame(Math.floor(st.cursor));
  charts();
}

// ----- charts -----

function charts() {
  // Rollout: one point per step; generate: one per denoising step.
  const gen = st.family === 'generate';
  const steps = gen ? st.progress : st.frames.slice(1).filter((f) => f.timing);
  const unit = gen ? 'denoising step' : 'step';
  drawChart(
    $('timing-chart'),
    [
      { label: 'forward ms', colour: '#4aa3df', points: steps.map((f) => [f.step, f.timing.forward_ms]) },
      { label: 'queue ms', colour: '#f3a712', points: steps.map((f) => [f.step, f.timing.queue_ms]) },
      { label: 'batch', colour: '#3bb273', kind: 'bar', right: true, points: steps.map((f) => [f.step, f.timing.batch_scenes]) },
    ],
    {
      xMax: Math.max(gen ? st.denoiseSteps : st.requested, 1),
      xLabel: unit,
      yLabel: 'ms',
      y2Label: 'scenes',
      marker: gen ? null : st.shown,
    },
  );
  const last = steps[steps.length - 1];
  if (last) {
    const mean = (k) => steps.reduce((s, f) => s + f.timing[k], 0) / steps.length;
    $('timing-text').textContent =
      `${unit} ${last.step}: queue ${last.timing.queue_ms.toFixed(2)} ms, forward ${last.timing.forward_ms.toFixed(2)} ms, ` +
      `batch ${last.timing.batch_scenes} scenes · mean forward ${mean('forward_ms').toFixed(2)} ms, mean batch ${mean('batch_scenes').toFixed(1)}`;
  } else {
    $('timing-text').textContent = 'per-step server timing';
  }
  spreadChart();
  $('error-figure').hidden = !st.truth;
  if (st.truth) {
    const n = Math.min(st.frames.length, st.truth.length);
    const pts = [];
    for (let i = 0; i < n; i++) pts.push([st.frames[i].time, meanDistance(st.frames[i].positions, st.truth[i].positions)]);
    const end = st.truth[st.truth.length - 1].time;
    drawChart($('error-chart'), [{ label: 'mean point error, m', colour: '#e4572e', points: pts }], {
      xMax: Math.max(end, st.requested * st.stepSeconds),
      xLabel: 'time, s',
      yLabel: 'm',
      marker: st.frames[st.shown] ? st.frames[st.shown].time : null,
    });
    const lastErr = pts[pts.length - 1];
    $('error-text').textContent = lastErr
      ? `model (solid) against ${$('ghost').value || 'ground truth'} (ghost): ${(lastErr[1] * 100).toFixed(1)} cm mean point error at ${lastErr[0].toFixed(2)} s`
      : 'model against ground truth';
  }
}

/** Each object's position spread (m) against time, when the model sends one. */
function spreadChart() {
  const frames = st.family === 'generate' ? [] : st.frames.filter((f) => f.spread && f.spread.length);
  $('spread-figure').hidden = !frames.length;
  if (!frames.length) return;
  const objects = frames[0].spread.length;
  const series = [];
  for (let j = 0; j < objects; j++) {
    series.push({
      label: `object ${j}`,
      colour: objectColour(j),
      points: frames.map((f) => [f.time, f.spread[j] ? f.spread[j].position_m : 0]),
    });
  }
  drawChart($('spread-chart'), series, {
    xMax: Math.max(st.requested * st.stepSeconds, frames[frames.length - 1].time),
    xLabel: 'time, s',
    yLabel: 'm',
    marker: st.frames[st.shown] ? st.frames[st.shown].time : null,
  });
  const shown = st.frames[st.shown] && st.frames[st.shown].spread ? st.frames[st.shown] : frames[frames.length - 1];
  const widest = shown.spread.reduce((a, s, j) => (s.position_m > a.s.position_m ? { s, j } : a), { s: shown.spread[0], j: 0 });
  $('spread-text').textContent =
    `the model's spread at step ${shown.step}: largest object ${widest.j}, ` +
    `${(widest.s.position_m * 100).toFixed(2)} cm, ${widest.s.orientation_deg.toFixed(2)} deg`;
}

// ----- start-up -----

async function loadLists() {
  const [models, offered] = await Promise.all([getJson('v1/models'), getJson('v1/examples')]);
  st.models = models.models;
  st.examples = { rollout: offered.examples || [], generate: offered.generate_examples || [] };
  $('model').replaceChildren(
    ...st.models.map((m) => {
      const o = document.createElement('option');
      o.value = m.name;
      o.textContent = `${m.name} (${m.architecture}, ${familyOf(m)})`;
      return o;
    }),
  );
  // Start with the model of ?model=NAME, else one that rolls scenes out when there is one
  // (the first example is a rollout scene), else the first model; ?scene=NAME picks the scene.
  const params = new URLSearchParams(location.search);
  const first =
    st.models.find((m) => m.name === params.get('model')) ||
    st.models.find((m) => familyOf(m) === 'rollout' && st.examples.rollout.length) ||
    st.models[0];
  if (first) $('model').value = first.name;
  $('ghost').append(
    ...st.models
      .filter((m) => familyOf(m) === 'rollout')
      .map((m) => {
        const o = document.createElement('option');
        o.value = m.name;
        o.textContent = `${m.name} (${m.architecture})`;
        return o;
      }),
  );
  const beside = st.models.find((m) => m.name === params.get('beside'));
  if (beside) $('ghost').value = beside.name;
  setFamily(familyOf(first));
  fillExamples(params.get('scene') || (examples()[0] && examples()[0].name));
}

/** The example of ?scene=NAME among the current model's, else its first. */
function firstExample() {
  const want = new URLSearchParams(location.search).get('scene');
  return examples().find((e) => e.name === want) || examples()[0];
}

/** A model was chosen: switch to its family's scenes unless they are already shown. */
function selectModel() {
  const family = familyOf(currentModel());
  if (family === st.family) return;
  stop();
  showError('');
  setFamily(family);
  fillExamples(examples()[0] && examples()[0].name);
  const e = examples()[0];
  if (e && selectExample(e)) setState('idle');
  else if (!e) $('status').textContent = `no example scenes for this model; drop a scene JSON file`;
}

function wire() {
  $('run').addEventListener('click', () => run());
  $('stop').addEventListener('click', () => stop());
  $('play').addEventListener('click', () => togglePlay());
  $('model').addEventListener('change', () => selectModel());
  $('ghost').addEventListener('change', () => {
    legend();
    run();
  });
  $('example').addEventListener('change', () => {
    stop();
    const e = examples()[Number($('example').value)];
    if (e && selectExample(e)) setState('idle');
  });
  $('timeline').addEventListener('input', () => {
    st.playing = false;
    st.cursor = Number($('timeline').value);
    showFrame(st.cursor);
    charts();
  });
  $('file').addEventListener('change', () => {
    const f = $('file').files[0];
    if (f) loadFile(f);
  });
  $('token-save').addEventListener('click', async () => {
    setToken($('token').value.trim());
    $('token-box').hidden = true;
    await start();
  });
  document.addEventListener('keydown', (e) => {
    if (e.code === 'Space' && e.target === document.body) {
      e.preventDefault();
      togglePlay();
    }
  });
  document.addEventListener('dragover', (e) => {
    e.preventDefault();
    document.body.classList.add('dragging');
  });
  document.addEventListener('dragleave', (e) => {
    if (!e.relatedTarget) document.body.classList.remove('dragging');
  });
  document.addEventListener('drop', (e) => {
    e.preventDefault();
    document.body.classList.remove('dragging');
    const f = e.dataTransfer.files[0];
    if (f) loadFile(f);
  });
  new ResizeObserver(() => charts()).observe($('charts'));
}

async function start() {
  try {
    await loadLists();
  } catch (e) {
    if (e instanceof ApiFailure && e.status === 401) $('token-box').hidden = false;
    showError(`cannot list models and scenes: ${e.message}`);
    setState('error');
    return;
  }
  if (!examples().length) {
    setState('idle');
    $('status').textContent = 'no example scenes; drop a scene JSON file';
    return;
  }
  if (!selectExample(firstExample())) return;
  setState('idle');
  // Opening the page shows a scene rolling out (or sampled, for a PhysiFormer model);
  // ?autoplay=0 waits for Run.
  if (new URLSearchParams(location.search).get('autoplay') !== '0') run();
}

try {
  st.view = new View($('view'));
} catch (e) {
  showError(`cannot draw in 3D here (WebGL unavailable): ${e.message}`);
  setState('error');
}
if (st.view) {
  wire();
  requestAnimationFrame(tick);
  start();
}
