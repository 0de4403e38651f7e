// workbench.js — the page's state and the operations the tools and panels share: the case, its
// annotations (as the server last answered them), the selections and modes, the result.
// Edits go through edit(), which runs them one at a time, in order.

import { api, ApiError } from "./api.js";
import * as overlay from "./overlay.js";
import { fatal } from "./fatal.js";
import { renderContourList, renderLandmarkList } from "./panels.js";
import { LandmarkTool, OutlineTool } from "./tools.js";
import { drawWarnings } from "./warnings.js";

const $ = (id) => document.getElementById(id);

export class Workbench {
  constructor(caseInfo, annotations) {
    this.caseInfo = caseInfo;
    this.annotations = annotations;
    this.viewers = new Map();
    this.mode = "landmark";
    this.selectedLandmark = caseInfo.landmark_names[0] ?? null;
    this.selectedContour = null; // {view, index}
    this.activeView = caseInfo.views[0]?.name ?? null;
    this.snap = false;
    this.sigma = 1;
    this.closedOutline = false;
    this.result = null;
    this.showResult = true;
    this.queue = Promise.resolve(); // edits run one at a time, in order
    this.timing = { loaded: performance.now(), registerStart: null, livewireSeconds: [] };
    this.tools = { landmark: new LandmarkTool(this), outline: new OutlineTool(this) };
    // hooks of the model view and the pose aid (model3d.js, poseaid.js)
    this.overlays = []; // fn(ctx, viewer), drawn first (under the result and the annotations)
    this.annotationListeners = []; // fn(view) after each saved edit of a view's annotations
    this.resultListeners = []; // fn(result) when a registration result arrives
  }

  tool() {
    return this.tools[this.mode];
  }

  // ---- annotations -----------------------------------------------------------------------

  /** The view's annotations ({landmarks, contours}), created empty if absent. */
  viewAnnotations(view) {
    const views = (this.annotations.views ??= {});
    const va = (views[view] ??= {});
    va.landmarks ??= {};
    va.contours ??= [];
    return va;
  }

  /** Apply the server's answer to an edit (the view's annotations). */
  setViewAnnotations(view, va) {
    (this.annotations.views ??= {})[view] = va;
    this.viewAnnotations(view); // fill missing keys
    const sel = this.selectedContour;
    if (sel && sel.view === view && sel.index >= va.contours.length) this.selectedContour = null;
    this.refresh();
    for (const fn of this.annotationListeners) fn(view);
  }

  /** The model's landmarks changed (defined or moved in the 3D view). */
  setModelLandmarks(landmarks) {
    this.caseInfo.model_landmarks = { ...landmarks };
    this.caseInfo.landmark_names = Object.keys(landmarks);
    this.selectedLandmark ??= this.caseInfo.landmark_names[0] ?? null;
    this.refresh();
    for (const fn of this.annotationListeners) fn(null);
  }

  /** Run an edit after the previous ones; a failure is shown and the annotations reloaded, so
   * the page never shows what the server did not save. A stale edit (409: the contour was
   * changed or removed since, in another tab or outside the workbench) reloads them too, and
   * says so: the edit can then be made again on what is there now. */
  edit(fn) {
    this.queue = this.queue.then(fn).catch(async (err) => {
      const stale = err instanceof ApiError && err.status === 409;
      this.error(err);
      try {
        this.annotations = await api.getAnnotations();
        if (stale) {
          this.selectedContour = null; // its index may now be another contour's
          this.error(new ApiError(409, `${err.message} (reloaded: the page shows the saved contours now)`));
          document.body.dataset.reloaded = String(Number(document.body.dataset.reloaded || 0) + 1);
        }
      } catch (reloadErr) {
        this.error(reloadErr);
      }
      this.refresh();
    });
    return this.queue;
  }

  /** The contour shown at `index` of `view` (with its id and version), or null. */
  contourAt(view, index) {
    return this.viewAnnotations(view).contours[index] ?? null;
  }

  removeLandmark(view, name) {
    this.edit(async () => {
      this.setViewAnnotations(view, await api.deleteLandmark(view, name));
      this.status(`${view}: ${name} removed`);
    });
  }

  removeContour(view, index) {
    const contour = this.contourAt(view, index); // as shown now: its id and version
    if (!contour) return;
    this.edit(async () => {
      this.selectedContour = null;
      this.setViewAnnotations(view, await api.deleteContour(view, contour));
      this.status(`${view}: contour #${index} removed`);
    });
  }

  // ---- selection and modes ---------------------------------------------------------------

  selectLandmark(name) {
    this.selectedLandmark = name;
    // The sigma field shows the selected landmark's sigma where it is placed.
    for (const { name: view } of this.caseInfo.views) {
      const lm = this.viewAnnotations(view).landmarks[name];
      if (lm) {
        this.sigma = lm.sigma_px ?? 1;
        $("sigma").value = String(this.sigma);
        break;
      }
    }
    this.refresh();
  }

  /** After placing `name` in `view`: select the next name not yet placed there (fast clicking
   * through the list), else keep the selection. */
  selectNextLandmark(view, name) {
    const names = this.caseInfo.landmark_names;
    const start = names.indexOf(name);
    for (let k = 1; k < names.length; k++) {
      const next = names[(start + k) % names.length];
      if (!this.viewAnnotations(view).landmarks[next]) {
        this.selectLandmark(next);
        return;
      }
    }
  }

  /** Per-landmark sigma: the field sets it for new placements and for the selected landmark
   * in every view where it is placed. */
  setSigma(value) {
    if (!(value > 0)) {
      this.status("sigma must be > 0");
      return;
    }
    this.sigma = value;
    const name = this.selectedLandmark;
    for (const { name: view } of this.caseInfo.views) {
      const lm = this.viewAnnotations(view).landmarks[name];
      if (!lm || lm.sigma_px === value) continue;
      this.edit(async () => {
        this.setViewAnnotations(view, await api.putLandmark(view, name, lm.uv, value));
      });
    }
  }

  selectContour(sel) {
    this.selectedContour = sel;
    this.refresh();
  }

  setMode(mode) {
    if (mode === this.mode) return;
    this.tool().cancel();
    this.mode = mode;
    for (const m of Object.keys(this.tools)) {
      $(`mode-${m}`)?.setAttribute("aria-pressed", String(m === mode));
    }
    $("pose-panel")?.classList.toggle("active", mode === "pose");
    document.body.dataset.mode = mode;
    $("landmarks-panel").classList.toggle("active", mode === "landmark");
    $("outline-panel").classList.toggle("active", mode === "outline");
    this.refresh();
  }

  setResult(result) {
    this.result = result;
    this.refresh();
    for (const fn of this.resultListeners) fn(result);
  }

  // ---- display ---------------------------------------------------------------------------

  redraw() {
    for (const v of this.viewers.values()) v.redraw();
  }

  /** Re-render the lists and redraw the views. */
  refresh() {
    renderLandmarkList(this, $("landmark-list"));
    renderContourList(this, $("contour-list"));
    const count = (v) => this.viewAnnotations(v.name).contours.length;
    const n = this.caseInfo.views.reduce((k, v) => k + count(v), 0);
    $("outline-summary").textContent =
      `${n} contour${n === 1 ? "" : "s"} · Outline mode (O) to trace or edit`;
    this.redraw();
  }

  /** The overlay of one view, drawn after its tiles (order: result under the annotations). */
  drawOverlay(ctx, viewer) {
    const va = this.viewAnnotations(viewer.name);
    const result = this.showResult ? this.result?.views?.[viewer.name] : null;
    for (const fn of this.overlays) fn(ctx, viewer);
    if (result) overlay.drawResult(ctx, viewer, result, va.landmarks);
    const sel = this.selectedContour;
    const boxes = []; // label boxes, so that no label hides another
    const selected = sel && sel.view === viewer.name ? sel.index : -1;
    overlay.drawContours(ctx, viewer, va.contours, selected, boxes);
    overlay.drawLandmarks(ctx, viewer, va.landmarks, this.selectedLandmark, boxes);
    if (result) overlay.drawResultLabels(ctx, viewer, result, va.landmarks, boxes);
    if (result) drawWarnings(ctx, viewer, this.result, va.landmarks);
    const trace = this.tools.outline.trace;
    if (trace.view === viewer.name) overlay.drawTrace(ctx, viewer, trace);
  }

  /** Status line: the cursor's pixel coordinates in the view under it. */
  cursor(viewer, uv) {
    if (!uv) return;
    this.activeView = viewer.name;
    const [u, v] = uv;
    $("cursor").textContent =
      `${viewer.name}  u ${u.toFixed(1)}  v ${v.toFixed(1)}  ` +
      `zoom ${viewer.zoom.toFixed(2)}×  level ${viewer.level()}`;
  }

  status(text) {
    const s = $("message");
    s.textContent = text;
    s.classList.remove("error");
  }

  error(err) {
    if (err instanceof ApiError && err.status === 403) {
      fatal(err);
      return;
    }
    const s = $("message");
    s.textContent = err instanceof Error ? err.message : String(err);
    s.classList.add("error");
    console.error(err);
  }

  noteLivewire(seconds) {
    if (typeof seconds === "number") this.timing.livewireSeconds.push(seconds);
    $("livewire-time").textContent =
      typeof seconds === "number" ? `livewire ${(seconds * 1000).toFixed(0)} ms` : "";
  }

  noteRegisterStart() {
    this.timing.registerStart = performance.now();
  }
}
