// The 3D view: floor (or the closed box of a mesh scene), lights, orbit camera, and one
// drawable per object. Objects are drawn from per-frame vertex arrays (world frame, metres,
// z up), so a rigid frame (poses applied to the body-frame geometry) and a deforming one
// (vertex positions given per frame) are drawn the same way. See docs/viewer.md for the frame
// format.

import {
  BufferAttribute,
  BufferGeometry,
  Color,
  DirectionalLight,
  GridHelper,
  Group,
  HemisphereLight,
  Mesh,
  MeshStandardMaterial,
  OrbitControls,
  PerspectiveCamera,
  PlaneGeometry,
  Points,
  PointsMaterial,
  Scene,
  Vector3,
  WebGLRenderer,
} from './vendor/three.min.js';

const PALETTE = [0xe4572e, 0x2e86ab, 0xf3a712, 0x3bb273, 0x7768ae, 0xd81e5b, 0x17bebb, 0x8c6d46];

/** Colour of object `j` (CSS hex), the same in the 3D view and the legends. */
export function objectColour(j) {
  return '#' + PALETTE[j % PALETTE.length].toString(16).padStart(6, '0');
}

/**
 * Body-frame geometry of every object of a rollout request: `{points: Float32Array(3n),
 * faces: Uint32Array | null}`; `points` are the mesh vertices when the object has a mesh.
 */
export function bodiesOf(request) {
  return request.scene.objects.map((o, j) => {
    if (o.mesh) {
      return {
        points: Float32Array.from(o.mesh.vertices.flat()),
        faces: Uint32Array.from(o.mesh.faces.flat()),
      };
    }
    if (o.points) {
      return { points: Float32Array.from(o.points.flat()), faces: null };
    }
    throw new Error(`scene.objects[${j}]: neither points nor mesh`);
  });
}

/**
 * Geometry of every object of a generate request (a mesh scene in the world frame at frame 0):
 * `{points: Float32Array(3n), faces: Uint32Array | null, material}`; `points` are the frame-0
 * vertices, `faces` null when the object has none (it is then drawn as points).
 */
export function meshBodiesOf(request) {
  return request.scene.objects.map((o, j) => {
    if (!Array.isArray(o.vertices) || !o.vertices.length) throw new Error(`scene.objects[${j}]: no vertices`);
    const faces = Array.isArray(o.faces) && o.faces.length ? Uint32Array.from(o.faces.flat()) : null;
    return { points: Float32Array.from(o.vertices.flat()), faces, material: o.material || 'rigid' };
  });
}

/**
 * The frames of one sampled trajectory (a generate `sample` event) as `{step, time,
 * positions, fits}`: `step` the frame index, `positions` one world-frame vertex array per
 * object, `fits` the RMS distance of each rigid object from its best rigid motion (null for
 * elastic ones). Throws when the sample does not match the scene.
 */
export function sampleFrames(sample, bodies) {
  return sample.frames.map((f) => {
    if (f.objects.length !== bodies.length) {
      throw new Error(`frame ${f.frame}: ${f.objects.length} objects, expected ${bodies.length}`);
    }
    const positions = f.objects.map((o, j) => {
      if (o.vertices.length * 3 !== bodies[j].points.length) {
        throw new Error(`frame ${f.frame}: object ${j} has ${o.vertices.length} vertices, expected ${bodies[j].points.length / 3}`);
      }
      return Float32Array.from(o.vertices.flat());
    });
    const fits = f.objects.map((o) => (typeof o.fit_rms === 'number' ? o.fit_rms : null));
    return { step: f.frame, time: f.time, positions, fits, timing: null };
  });
}

/** The eight corners of the box `[-e, e]^3` as one vertex array (for framing the camera). */
export function boxCorners(e) {
  const out = [];
  for (const x of [-e, e]) for (const y of [-e, e]) for (const z of [-e, e]) out.push(x, y, z);
  return [Float32Array.from(out)];
}

/** Applies a pose `{translation: [x,y,z], rotation: [x,y,z,w]}` to body-frame points. */
export function transform(points, pose) {
  const [tx, ty, tz] = pose.translation;
  const [qx, qy, qz, qw] = pose.rotation || [0, 0, 0, 1];
  const out = new Float32Array(points.length);
  for (let i = 0; i < points.length; i += 3) {
    const x = points[i], y = points[i + 1], z = points[i + 2];
    // v + 2 w (q x v) + 2 q x (q x v), q = (qx, qy, qz)
    const cx = qy * z - qz * y, cy = qz * x - qx * z, cz = qx * y - qy * x;
    const dx = qy * cz - qz * cy, dy = qz * cx - qx * cz, dz = qx * cy - qy * cx;
    out[i] = x + 2 * (qw * cx + dx) + tx;
    out[i + 1] = y + 2 * (qw * cy + dy) + ty;
    out[i + 2] = z + 2 * (qw * cz + dz) + tz;
  }
  return out;
}

/**
 * World-frame vertex arrays of one wire frame: `frame.vertices` (one flat `[x, y, z, ...]`
 * array per object, for deforming bodies) when present, else `frame.poses` applied to the
 * bodies. Throws when the frame does not match the scene.
 */
export function positionsOf(frame, bodies) {
  if (frame.vertices) {
    if (frame.vertices.length !== bodies.length) {
      throw new Error(`frame ${frame.step}: ${frame.vertices.length} vertex arrays for ${bodies.length} objects`);
    }
    return frame.vertices.map((v, j) => {
      if (v.length !== bodies[j].points.length) {
        throw new Error(`frame ${frame.step}: object ${j} has ${v.length / 3} vertices, expected ${bodies[j].points.length / 3}`);
      }
      return Float32Array.from(v);
    });
  }
  if (!frame.poses || frame.poses.length !== bodies.length) {
    throw new Error(`frame ${frame.step}: expected ${bodies.length} poses`);
  }
  return frame.poses.map((p, j) => transform(bodies[j].points, p));
}

/** Initial positions (step 0) of a request: its objects' poses applied to the bodies. */
export function initialPositions(request, bodies) {
  return request.scene.objects.map((o, j) => transform(bodies[j].points, o.pose));
}

/** Mean distance between corresponding vertices of two position sets, metres. */
export function meanDistance(a, b) {
  let sum = 0;
  let n = 0;
  for (let j = 0; j < a.length; j++) {
    const p = a[j], q = b[j];
    for (let i = 0; i < p.length; i += 3) {
      sum += Math.hypot(p[i] - q[i], p[i + 1] - q[i + 1], p[i + 2] - q[i + 2]);
      n++;
    }
  }
  return n ? sum / n : 0;
}

function drawable(body, colour, ghost) {
  const geometry = new BufferGeometry();
  geometry.setAttribute('position', new BufferAttribute(new Float32Array(body.points.length), 3));
  if (body.faces) {
    geometry.setIndex(new BufferAttribute(body.faces, 1));
    const material = new MeshStandardMaterial({
      color: ghost ? 0xbfc5cc : colour,
      flatShading: true,
      roughness: 0.65,
      metalness: 0.05,
      transparent: ghost,
      opacity: ghost ? 0.3 : 1,
      depthWrite: !ghost,
    });
    return new Mesh(geometry, material);
  }
  const material = new PointsMaterial({
    color: ghost ? 0xbfc5cc : colour,
    size: ghost ? 0.035 : 0.03,
    transparent: ghost,
    opacity: ghost ? 0.45 : 1,
    depthWrite: !ghost,
  });
  return new Points(geometry, material);
}

/** The WebGL view inside `container`. */
export class View {
  constructor(container) {
    this.container = container;
    this.renderer = new WebGLRenderer({ antialias: true });
    this.renderer.setPixelRatio(Math.min(window.devicePixelRatio || 1, 2));
    container.appendChild(this.renderer.domElement);
    this.scene = new Scene();
    this.scene.background = new Color(0x1d2127);
    this.camera = new PerspectiveCamera(45, 1, 0.05, 200);
    this.camera.up.set(0, 0, 1);
    this.camera.position.set(4, -5, 3);
    this.controls = new OrbitControls(this.camera, this.renderer.domElement);
    this.controls.addEventListener('change', () => this.render());
    this.scene.add(new HemisphereLight(0xdde6f0, 0x30343a, 1.4));
    const sun = new DirectionalLight(0xffffff, 1.6);
    sun.position.set(3, -4, 8);
    this.scene.add(sun);
    const floor = new Mesh(
      new PlaneGeometry(40, 40),
      new MeshStandardMaterial({ color: 0x3a4048, roughness: 1 }),
    );
    floor.position.z = -0.001;
    const grid = new GridHelper(40, 80, 0x6b7480, 0x4a515b);
    grid.rotation.x = Math.PI / 2; // the helper lies in x-z; the floor is the x-y plane
    this.ground = new Group();
    this.ground.add(floor, grid);
    this.scene.add(this.ground);
    this.box = new Group();
    this.box.visible = false;
    this.scene.add(this.box);
    this.model = new Group();
    this.truth = new Group();
    this.scene.add(this.truth, this.model);
    new ResizeObserver(() => this.resize()).observe(container);
    this.resize();
  }

  /** Replaces the objects: one drawable per body, plus ghosts when `withTruth`. */
  setBodies(bodies, withTruth) {
    for (const g of [this.model, this.truth]) {
      for (const c of [...g.children]) {
        c.geometry.dispose();
        c.material.dispose();
        g.remove(c);
      }
    }
    bodies.forEach((b, j) => this.model.add(drawable(b, PALETTE[j % PALETTE.length], false)));
    if (withTruth) bodies.forEach((b) => this.truth.add(drawable(b, 0, true)));
  }

  /**
   * Draws the closed box `[-e, e]^3` of a mesh scene as a wireframe (its floor with a grid of
   * quarter-size cells) in place of the open floor, or restores the floor when `e` is null.
   */
  setBox(e) {
    for (const c of [...this.box.children]) {
      c.geometry.dispose();
      c.material.dispose();
      this.box.remove(c);
    }
    this.box.visible = !!e;
    this.ground.visible = !e;
    if (e) {
      // A grid helper is a square of lines in its x-z plane; four of them outline the box.
      const face = (divisions, colour, place) => {
        const g = new GridHelper(2 * e, divisions, colour, colour);
        place(g);
        this.box.add(g);
      };
      face(4, 0x59616c, (g) => { g.rotation.x = Math.PI / 2; g.position.z = -e; });
      face(1, 0x9aa4b0, (g) => { g.rotation.x = Math.PI / 2; g.position.z = e; });
      face(1, 0x9aa4b0, (g) => { g.rotation.z = Math.PI / 2; g.position.x = -e; });
      face(1, 0x9aa4b0, (g) => { g.rotation.z = Math.PI / 2; g.position.x = e; });
    }
    this.render();
  }

  /** Shows world-frame vertex arrays (one per object) on the model or the ghost layer. */
  show(positions, layer = 'model') {
    const group = layer === 'truth' ? this.truth : this.model;
    group.visible = !!positions;
    if (positions) {
      group.children.forEach((c, j) => {
        const attr = c.geometry.getAttribute('position');
        attr.array.set(positions[j]);
        attr.needsUpdate = true;
        c.geometry.computeBoundingSphere();
      });
    }
    this.render();
  }

  /**
   * Points the camera at the objects' bounding box (positions: vertex arrays), from a distance
   * of `distance` times the box's diagonal.
   */
  frame(positions, distance = 1.25) {
    const min = new Vector3(Infinity, Infinity, 0);
    const max = new Vector3(-Infinity, -Infinity, -Infinity);
    for (const p of positions) {
      for (let i = 0; i < p.length; i += 3) {
        min.min(new Vector3(p[i], p[i + 1], p[i + 2]));
        max.max(new Vector3(p[i], p[i + 1], p[i + 2]));
      }
    }
    const centre = min.clone().add(max).multiplyScalar(0.5);
    const size = Math.max(max.distanceTo(min), 1.5);
    this.controls.target.copy(centre);
    const away = new Vector3(0.75, -1.1, 0.65).normalize().multiplyScalar(size * distance);
    this.camera.position.copy(centre).add(away);
    this.controls.update();
    this.render();
  }

  resize() {
    const w = Math.max(this.container.clientWidth, 1);
    const h = Math.max(this.container.clientHeight, 1);
    this.renderer.setSize(w, h, false);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() {
    this.renderer.render(this.scene, this.camera);
  }
}
