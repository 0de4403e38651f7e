// model3d.js — the 3D view of the model (three.js, bundled in vendor/three.bundle.js): the
// mean shape with its named landmarks; rotate with the left button, zoom with the wheel, pan
// with the right button; a click on the surface defines (or moves) the landmark named in the
// panel's field at the nearest vertex (PUT /api/model/landmarks/{name}). After a registration,
// "result" shows the registered bone, coloured by its distance to the ground truth when the
// case has one. Once the pose aid has a pose, the view looks at the bone as a radiograph does
// (along that view's direction, with its up; one button per view, "free" after a drag).
// Landmark labels are placed around their ball where they overlap nothing, joined to it by a
// leader line when placed further out.

import * as THREE from "./vendor/three.bundle.js";
import { api } from "./api.js";

const CLICK_SLOP_PX = 4;
const BONE = 0xd8cbb0;
const LANDMARK = 0x3ddc84;
const LANDMARK_SELECTED = 0xffffff;

/** Error colour ramp: 0 -> blue, max/2 -> yellow-green, max -> red. */
function ramp(t) {
  const x = Math.max(0, Math.min(1, t));
  return [Math.min(1, 2 * x), Math.min(1, 2 - 2 * x) * (0.35 + 0.65 * Math.min(1, 2 * x)), Math.max(0, 1 - 2 * x)];
}

/** The principal axes of points [x0, y0, z0, ...] (unit THREE.Vector3, largest spread first):
 * Jacobi rotations of their 3 x 3 covariance. */
function principalAxes(p) {
  const n = p.length / 3;
  const mean = [0, 0, 0];
  for (let i = 0; i < n; i++) for (let k = 0; k < 3; k++) mean[k] += p[3 * i + k] / n;
  const C = [[0, 0, 0], [0, 0, 0], [0, 0, 0]];
  for (let i = 0; i < n; i++) {
    for (let a = 0; a < 3; a++) {
      for (let b = 0; b < 3; b++) C[a][b] += (p[3 * i + a] - mean[a]) * (p[3 * i + b] - mean[b]);
    }
  }
  const V = [[1, 0, 0], [0, 1, 0], [0, 0, 1]];
  for (let sweep = 0; sweep < 20; sweep++) {
    for (const [a, b] of [[0, 1], [0, 2], [1, 2]]) {
      if (Math.abs(C[a][b]) < 1e-12 * (Math.abs(C[a][a]) + Math.abs(C[b][b]) + 1e-300)) continue;
      const th = 0.5 * Math.atan2(2 * C[a][b], C[b][b] - C[a][a]);
      const [c, s] = [Math.cos(th), Math.sin(th)];
      for (const M of [C]) {
        for (let k = 0; k < 3; k++) { // rows a, b
          const [x, y] = [M[a][k], M[b][k]];
          M[a][k] = c * x - s * y;
          M[b][k] = s * x + c * y;
        }
      }
      for (const M of [C, V]) {
        for (let k = 0; k < 3; k++) { // columns a, b
          const [x, y] = [M[k][a], M[k][b]];
          M[k][a] = c * x - s * y;
          M[k][b] = s * x + c * y;
        }
      }
    }
  }
  const order = [0, 1, 2].sort((i, j) => C[j][j] - C[i][i]);
  return order.map((i) => new THREE.Vector3(V[0][i], V[1][i], V[2][i]).normalize());
}

export class ModelView {
  /**
   * @param {Workbench} wb the page state (its caseInfo landmark names are updated here)
   * @param {object} els {box, name, list, status, showResult, enlarge}
   */
  constructor(wb, els) {
    this.wb = wb;
    this.els = els;
    this.landmarks = { ...(wb.caseInfo.model_landmarks ?? {}) };
    this.model = null; // {geometry, positions (Float32Array), mesh}
    this.result = null; // the registered bone's mesh
    this.markers = new Map();
    this.selected = null;
    this.showResult = false;
    this.ready = false;
    this.cameras = null; // {view: {forward, up}} world frame, from the pose aid; R model -> world
    this.orientView = null; // the radiograph the camera follows, or null (free)
  }

  async init() {
    const box = this.els.box;
    let renderer;
    try {
      renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
    } catch (err) {
      this.say(`no 3D view: this browser has no WebGL (${err.message})`, true);
      return;
    }
    this.renderer = renderer;
    renderer.setPixelRatio(window.devicePixelRatio || 1);
    renderer.setClearColor(0x0b0d10);
    box.append(renderer.domElement);
    renderer.domElement.dataset.testid = "model-canvas";
    this.scene = new THREE.Scene();
    this.camera = new THREE.PerspectiveCamera(35, 1, 0.1, 10000);
    this.scene.add(new THREE.AmbientLight(0xffffff, 0.45));
    this.light = new THREE.DirectionalLight(0xffffff, 1.6);
    this.scene.add(this.light);
    this.controls = new THREE.OrbitControls(this.camera, renderer.domElement);
    this.controls.addEventListener("change", () => this.render());
    // a drag leaves the radiograph's orientation: the view buttons show "free"
    this.controls.addEventListener("start", () => {
      this.dragging = true;
    });
    this.controls.addEventListener("end", () => {
      this.dragging = false;
    });
    this.controls.addEventListener("change", () => {
      if (this.dragging && this.orientView) this.setOrientView(null, false);
    });
    this.leaders = document.createElementNS("http://www.w3.org/2000/svg", "svg");
    this.leaders.classList.add("model-leaders");
    box.append(this.leaders);
    this.listen(renderer.domElement);
    new ResizeObserver(() => this.resize()).observe(box);
    const mesh = await api.getModelMesh();
    this.model = this.buildMesh(mesh, BONE);
    this.scene.add(this.model.mesh);
    this.frame(this.model);
    this.renderMarkers();
    this.renderList();
    this.resize();
    this.ready = true;
    box.dataset.ready = "true";
  }

  /** A three.js mesh of a {vertices, faces} document, centred (the view's own frame). */
  buildMesh(doc, color) {
    const positions = new Float32Array(doc.vertices);
    const geometry = new THREE.BufferGeometry();
    geometry.setAttribute("position", new THREE.BufferAttribute(positions, 3));
    geometry.setIndex(doc.faces);
    geometry.computeVertexNormals();
    const material = new THREE.MeshPhongMaterial({
      color, shininess: 25, side: 2 /* DoubleSide: open meshes too */, vertexColors: false,
    });
    const mesh = new THREE.Mesh(geometry, material);
    geometry.computeBoundingBox();
    const centre = new THREE.Vector3();
    geometry.boundingBox.getCenter(centre);
    const size = new THREE.Vector3();
    geometry.boundingBox.getSize(size);
    return { geometry, positions, mesh, centre, radius: size.length() / 2, doc };
  }

  /** Camera looking at the mesh: like the radiograph `orientView` when there is one (its
   * direction and up at the bone, brought into the mesh's frame), else across its long axis
   * (drawn upright) from the side of its thinnest extent; the light from the camera. */
  frame(m) {
    let forward;
    let up;
    const cam = this.orientView ? this.cameras?.[this.orientView] : null;
    if (cam) {
      // the model's mean shape is in the model frame: world directions through R^T; the
      // registered bone is in the world frame already
      const R = m !== this.result ? this.R : null;
      const toMesh = (w) => {
        const v = R ? [0, 1, 2].map((i) => R[0][i] * w[0] + R[1][i] * w[1] + R[2][i] * w[2]) : w;
        return new THREE.Vector3(...v).normalize();
      };
      [forward, up] = [toMesh(cam.forward), toMesh(cam.up)];
    } else {
      const [long, , thin] = principalAxes(m.positions);
      [forward, up] = [thin, long];
    }
    const d = (m.radius / Math.tan((this.camera.fov * Math.PI) / 360)) * 1.15;
    this.controls.target.copy(m.centre);
    this.camera.position.copy(m.centre).addScaledVector(forward, -d);
    this.camera.up.copy(up);
    // OrbitControls orbits about its own "up": keep it the camera's
    this.controls._quat?.setFromUnitVectors(this.camera.up, new THREE.Vector3(0, 1, 0));
    this.controls._quatInverse?.copy(this.controls._quat).invert();
    this.camera.near = d / 100;
    this.camera.far = d * 10;
    this.camera.updateProjectionMatrix();
    this.controls.update();
  }

  /** The pose aid's document: each radiograph's direction for the view buttons. */
  setPose(doc) {
    const first = !this.cameras;
    if (!doc?.ready) {
      this.cameras = null;
      this.renderViewButtons();
      return;
    }
    this.cameras = Object.fromEntries(Object.entries(doc.views).map(([k, v]) => [k, v.camera]));
    this.R = doc.R; // model -> world: a world direction w is R^T w in the model frame
    if (first && this.orientView === null && !this.userMoved) {
      this.orientView = Object.keys(this.cameras)[0] ?? null; // like the first radiograph
    }
    this.renderViewButtons();
    if (this.orientView && this.ready) {
      this.frame(this.current());
      this.render();
    }
  }

  setOrientView(name, reframe = true) {
    this.orientView = name;
    if (!name) this.userMoved = true;
    this.renderViewButtons();
    if (reframe && this.ready) {
      this.frame(this.current());
      this.render();
    }
  }

  renderViewButtons() {
    const row = this.els.views;
    if (!row) return;
    row.replaceChildren();
    const names = this.cameras ? Object.keys(this.cameras) : [];
    for (const name of [...names, null]) {
      const b = document.createElement("button");
      b.className = "small";
      b.textContent = name ?? "free";
      b.dataset.testid = `model-view-${name ?? "free"}`;
      b.setAttribute("aria-pressed", String(this.orientView === name));
      b.title = name
        ? `Look at the bone as ${name} does (its direction and up, at the pose aid's pose)`
        : "Turn the view freely (drag)";
      b.addEventListener("click", () => this.setOrientView(name));
      row.append(b);
    }
    if (!names.length) {
      const note = document.createElement("span");
      note.className = "muted";
      note.textContent = "views: once the pose aid has a pose";
      row.append(note);
    }
  }

  resize() {
    const box = this.els.box;
    const w = box.clientWidth;
    const h = box.clientHeight;
    if (!w || !h || !this.renderer) return;
    this.renderer.setSize(w, h);
    this.camera.aspect = w / h;
    this.camera.updateProjectionMatrix();
    this.render();
  }

  render() {
    if (!this.renderer) return;
    this.light.position.copy(this.camera.position);
    this.renderer.render(this.scene, this.camera);
    this.placeLabels();
  }

  // ---- landmarks ---------------------------------------------------------------------------

  current() {
    return this.showResult && this.result ? this.result : this.model;
  }

  renderMarkers() {
    for (const m of this.markers.values()) m.sphere.removeFromParent();
    for (const m of this.markers.values()) m.label.remove();
    this.markers.clear();
    const target = this.current();
    if (!target) return;
    const r = target.radius * 0.03;
    for (const [name, i] of Object.entries(this.landmarks)) {
      const p = target.positions;
      if (3 * i + 2 >= p.length) continue;
      const color = name === this.selected ? LANDMARK_SELECTED : LANDMARK;
      const sphere = new THREE.Mesh(
        new THREE.SphereGeometry(r, 16, 12),
        new THREE.MeshBasicMaterial({ color, depthTest: false, transparent: true, opacity: 0.9 }),
      );
      sphere.renderOrder = 2;
      sphere.position.set(p[3 * i], p[3 * i + 1], p[3 * i + 2]);
      this.scene.add(sphere);
      const label = document.createElement("span");
      label.className = "model-label" + (name === this.selected ? " selected" : "");
      label.textContent = name;
      this.els.box.append(label);
      this.markers.set(name, { sphere, label });
    }
    this.render();
  }

  /** HTML labels around each landmark's ball: the first place, nearest first, that overlaps
   * no label placed before, no other ball and stays inside the view; a label placed away from
   * its ball gets a leader line to it. */
  placeLabels() {
    const w = this.els.box.clientWidth;
    const h = this.els.box.clientHeight;
    const items = [];
    const toPx = (v) => [((v.x + 1) / 2) * w, ((1 - v.y) / 2) * h];
    for (const [name, { sphere, label }] of this.markers) {
      const p = sphere.position.clone().project(this.camera);
      const [x, y] = toPx(p);
      // the ball's radius on the screen: a point of its rim, across the view
      const rim = sphere.position.clone().addScaledVector(this.camera.up, sphere.geometry.parameters.radius);
      const [rx, ry] = toPx(rim.project(this.camera));
      label.hidden = p.z > 1;
      items.push({ name, label, x, y, ball: Math.max(4, Math.hypot(rx - x, ry - y)), hidden: p.z > 1 });
    }
    const boxes = [];
    const balls = items
      .filter((it) => !it.hidden)
      .map((it) => [it.x - it.ball, it.y - it.ball, it.x + it.ball, it.y + it.ball]);
    const hits = (b, list) => list.some((o) => b[0] < o[2] && o[0] < b[2] && b[1] < o[3] && o[1] < b[3]);
    const lines = [];
    for (const it of items) {
      if (it.hidden) continue;
      const lw = it.label.offsetWidth || 7 * it.label.textContent.length;
      const lh = 13;
      let best = null;
      // rings of places around the ball: right, left, above, below, the diagonals, further out
      for (const r of [3, 16, 34, 56, 84].map((d) => it.ball + d)) {
        for (const a of [0, 180, -90, 90, -45, 45, -135, 135, -20, 20, -160, 160]) {
          const t = (a * Math.PI) / 180;
          const ax = it.x + r * Math.cos(t);
          const ay = it.y + r * Math.sin(t);
          // the label's side facing the ball at (ax, ay)
          const x0 = Math.cos(t) < -0.3 ? ax - lw : Math.cos(t) > 0.3 ? ax : ax - lw / 2;
          const y0 = Math.sin(t) < -0.3 ? ay - lh : Math.sin(t) > 0.3 ? ay : ay - lh / 2;
          const b = [x0, y0, x0 + lw, y0 + lh];
          const inside = b[0] >= 0 && b[1] >= 0 && b[2] <= w && b[3] <= h;
          const others = balls.filter((o) => Math.hypot((o[0] + o[2]) / 2 - it.x, (o[1] + o[3]) / 2 - it.y) > 1);
          if (inside && !hits(b, boxes) && !hits(b, others)) {
            best = { b, r, ax, ay };
            break;
          }
        }
        if (best) break;
      }
      const r0 = it.ball + 3;
      best ??= { b: [it.x + r0, it.y - 7, it.x + r0 + lw, it.y + 6], r: r0 };
      boxes.push(best.b);
      it.label.style.left = `${best.b[0]}px`;
      it.label.style.top = `${best.b[1]}px`;
      it.label.dataset.box = best.b.map((v) => v.toFixed(1)).join(",");
      if (best.r > it.ball + 3) lines.push([it.x, it.y, best.ax, best.ay]);
    }
    this.leaders.setAttribute("width", String(w));
    this.leaders.setAttribute("height", String(h));
    this.leaders.innerHTML = lines
      .map(([x1, y1, x2, y2]) => `<line x1="${x1}" y1="${y1}" x2="${x2}" y2="${y2}"></line>`)
      .join("");
  }

  renderList() {
    const list = this.els.list;
    list.replaceChildren();
    for (const [name, i] of Object.entries(this.landmarks)) {
      const li = document.createElement("li");
      li.className = "landmark" + (name === this.selected ? " selected" : "");
      li.dataset.testid = `model-landmark-${name}`;
      li.innerHTML = `<span class="name"></span><span class="muted">v${i}</span>`;
      li.querySelector(".name").textContent = name;
      li.addEventListener("click", () => this.select(name));
      list.append(li);
    }
  }

  select(name) {
    this.selected = name;
    this.els.name.value = name;
    this.renderList();
    this.renderMarkers();
  }

  listen(canvas) {
    let down = null;
    canvas.addEventListener("pointerdown", (ev) => {
      down = ev.button === 0 ? [ev.clientX, ev.clientY] : null;
    });
    canvas.addEventListener("pointerup", (ev) => {
      if (!down || Math.hypot(ev.clientX - down[0], ev.clientY - down[1]) > CLICK_SLOP_PX) return;
      down = null;
      this.pick(ev);
    });
  }

  /** The vertex nearest to the surface point under the pointer, or null. */
  vertexAt(clientX, clientY) {
    const rect = this.renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(
      ((clientX - rect.left) / rect.width) * 2 - 1,
      -((clientY - rect.top) / rect.height) * 2 + 1,
    );
    const ray = new THREE.Raycaster();
    ray.setFromCamera(ndc, this.camera);
    const target = this.current();
    const hit = ray.intersectObject(target.mesh, false)[0];
    if (!hit) return null;
    // the vertex nearest to the surface point (of all: a long triangle's corners may be far)
    const p = target.positions;
    const { x, y, z } = hit.point;
    let best = null;
    let bestDist = Infinity;
    for (let i = 0; i < p.length / 3; i++) {
      const d = (p[3 * i] - x) ** 2 + (p[3 * i + 1] - y) ** 2 + (p[3 * i + 2] - z) ** 2;
      if (d < bestDist) [best, bestDist] = [i, d];
    }
    return best;
  }

  async pick(ev) {
    const vertex = this.vertexAt(ev.clientX, ev.clientY);
    if (vertex === null) return;
    const name = this.els.name.value.trim();
    if (!name) {
      this.say(`vertex ${vertex}: type a landmark name first, then click the surface`, true);
      return;
    }
    try {
      const res = await api.putModelLandmark(name, vertex);
      this.landmarks = res.landmarks;
      this.selected = name;
      this.wb.setModelLandmarks?.(res.landmarks);
      this.renderList();
      this.renderMarkers();
      this.say(`${name}: vertex ${vertex} (saved in ${this.wb.caseInfo.landmarks_file})`);
    } catch (err) {
      this.say(err.message, true);
    }
  }

  // ---- the registered bone -----------------------------------------------------------------

  /** Load (or reload) the registered bone; `show` switches the view to it. */
  async loadResult(show = this.showResult) {
    let doc;
    try {
      doc = await api.getResultMesh();
    } catch (err) {
      if (err.status === 404) return;
      throw err;
    }
    if (this.result) this.result.mesh.removeFromParent();
    this.result = this.buildMesh(doc, BONE);
    if (doc.error_mm) this.colourByError(this.result, doc.error_mm, doc.error_max_mm);
    this.els.showResult.disabled = false;
    this.setShowResult(show);
  }

  colourByError(m, errors, max) {
    const colours = new Float32Array(3 * errors.length);
    errors.forEach((e, i) => colours.set(ramp(e / (max || 1)), 3 * i));
    m.geometry.setAttribute("color", new THREE.BufferAttribute(colours, 3));
    m.mesh.material.vertexColors = true;
    m.mesh.material.color = new THREE.Color(0xffffff);
    m.mesh.material.needsUpdate = true;
    this.els.legend.textContent =
      `distance to the ground truth: blue 0 → red ${max.toFixed(2)} mm`;
  }

  setShowResult(show) {
    this.showResult = Boolean(show && this.result);
    this.els.showResult.checked = this.showResult;
    this.els.legend.hidden = !(this.showResult && this.result?.doc.error_mm);
    if (this.model) this.model.mesh.visible = !this.showResult;
    if (this.result) {
      if (!this.result.mesh.parent) this.scene.add(this.result.mesh);
      this.result.mesh.visible = this.showResult;
    }
    this.frame(this.current());
    this.renderMarkers();
  }

  say(text, isError = false) {
    this.els.status.textContent = text;
    this.els.status.classList.toggle("error", isError);
  }
}
