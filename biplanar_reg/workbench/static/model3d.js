// model3d.js — the 3D view of the model (three.js, bundled in vendor/three.bundle.js): the
// mean shape with its named landmarks; rotate with the left button, zoom with the wheel, pan
// with the right button; a click on the surface defines (or moves) the landmark named in the
// panel's field at the nearest vertex (PUT /api/model/landmarks/{name}). After a registration,
// "result" shows the registered bone, coloured by its distance to the ground truth when the
// case has one.

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

  /** Camera looking at the mesh across its long axis (drawn upright) from the side of its
   * thinnest extent: the principal axes of its vertices; the light from the camera. */
  frame(m) {
    const [long, , thin] = principalAxes(m.positions);
    const d = (m.radius / Math.tan((this.camera.fov * Math.PI) / 360)) * 1.15;
    this.controls.target.copy(m.centre);
    this.camera.position.copy(m.centre).addScaledVector(thin, -d);
    this.camera.up.copy(long);
    this.camera.near = d / 100;
    this.camera.far = d * 10;
    this.camera.updateProjectionMatrix();
    this.controls.update();
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

  /** HTML labels next to each landmark's projection, moved down past the labels already
   * placed (landmarks are often close together). */
  placeLabels() {
    const w = this.els.box.clientWidth;
    const h = this.els.box.clientHeight;
    const boxes = [];
    for (const { sphere, label } of this.markers.values()) {
      const p = sphere.position.clone().project(this.camera);
      const [cx, cy] = [((p.x + 1) / 2) * w, ((1 - p.y) / 2) * h];
      const lw = label.offsetWidth || 7 * label.textContent.length;
      // right, left, then above/below the ball: the first place that misses the others
      const tries = [[8, -7], [-lw - 8, -7], [8, -20], [-lw - 8, -20], [8, 6], [-lw - 8, 6]];
      const free = ([dx, dy]) =>
        !boxes.some((b) => cx + dx < b[2] && b[0] < cx + dx + lw && cy + dy < b[3] && b[1] < cy + dy + 13);
      const [dx, dy] = tries.find(free) ?? tries[0];
      boxes.push([cx + dx, cy + dy, cx + dx + lw, cy + dy + 13]);
      label.style.left = `${cx + dx}px`;
      label.style.top = `${cy + dy}px`;
      label.hidden = p.z > 1;
    }
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
