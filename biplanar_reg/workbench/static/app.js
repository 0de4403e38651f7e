// app.js — the workbench page: loads the case, builds one viewer per radiograph, and holds the
// state the tools and panels share (the `Workbench` below). Every edit goes straight to the
// server (which saves it in the case folder), so nothing is lost on reload.
//
// For the browser tests, `window.workbench` exposes the view transforms and a few waits.

import { api, ApiError } from "./api.js";
import * as overlay from "./overlay.js";
import { renderContourList, renderLandmarkList } from "./panels.js";
import { RegisterPanel } from "./register.js";
import { LandmarkTool, OutlineTool } from "./tools.js";
import { Viewer } from "./viewer.js";

const $ = (id) => document.getElementById(id);

class Workbench {
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
  }

  /** Run an edit after the previous ones; a failure is shown and the annotations reloaded, so
   * the page never shows what the server did not save. */
  edit(fn) {
    this.queue = this.queue.then(fn).catch(async (err) => {
      this.error(err);
      try {
        this.annotations = await api.getAnnotations();
      } catch (reloadErr) {
        this.error(reloadErr);
      }
      this.refresh();
    });
    return this.queue;
  }

  removeLandmark(view, name) {
    this.edit(async () => {
      this.setViewAnnotations(view, await api.deleteLandmark(view, name));
      this.status(`${view}: ${name} removed`);
    });
  }

  removeContour(view, index) {
    this.edit(async () => {
      this.selectedContour = null;
      this.setViewAnnotations(view, await api.deleteContour(view, index));
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
    for (const m of ["landmark", "outline"]) {
      $(`mode-${m}`).setAttribute("aria-pressed", String(m === mode));
    }
    document.body.dataset.mode = mode;
    $("landmarks-panel").classList.toggle("active", mode === "landmark");
    $("outline-panel").classList.toggle("active", mode === "outline");
    this.refresh();
  }

  setResult(result) {
    this.result = result;
    this.redraw();
  }

  // ---- display ---------------------------------------------------------------------------

  redraw() {
    for (const v of this.viewers.values()) v.redraw();
  }

  /** Re-render the lists and redraw the views. */
  refresh() {
    renderLandmarkList(this, $("landmark-list"));
    renderContourList(this, $("contour-list"));
    this.redraw();
  }

  /** The overlay of one view, drawn after its tiles (order: result under the annotations). */
  drawOverlay(ctx, viewer) {
    const va = this.viewAnnotations(viewer.name);
    const result = this.showResult ? this.result?.views?.[viewer.name] : null;
    if (result) overlay.drawResult(ctx, viewer, result, va.landmarks);
    const sel = this.selectedContour;
    const boxes = []; // label boxes, so that no label hides another
    const selected = sel && sel.view === viewer.name ? sel.index : -1;
    overlay.drawContours(ctx, viewer, va.contours, selected, boxes);
    overlay.drawLandmarks(ctx, viewer, va.landmarks, this.selectedLandmark, boxes);
    if (result) overlay.drawResultLabels(ctx, viewer, result, va.landmarks, boxes);
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

// ---- page set-up -------------------------------------------------------------------------

/** One view's DOM: a title bar with the window/level sliders and fit buttons, the canvas. */
function buildView(wb, info) {
  const template = $("view-template").content.firstElementChild.cloneNode(true);
  template.dataset.view = info.name;
  template.querySelector(".view-name").textContent = info.name;
  template.querySelector(".view-size").textContent = `${info.width} × ${info.height}`;
  const canvas = template.querySelector("canvas");
  canvas.id = `view-${info.name}`;
  canvas.dataset.testid = `view-${info.name}`;
  canvas.setAttribute("aria-label", `radiograph ${info.name}`);
  $("views").append(template);

  const viewer = new Viewer(canvas, info, {
    tileUrl: (level, tx, ty, lo, hi) => api.tileUrl(info.name, level, tx, ty, lo, hi),
    handler: () => wb.tool(),
    drawOverlay: (ctx, v) => wb.drawOverlay(ctx, v),
    onCursor: (v, uv) => wb.cursor(v, uv),
  });
  wireWindowSliders(template, info, viewer);
  template.querySelector(".fit").addEventListener("click", () => viewer.fit());
  template.querySelector(".fit-bone").addEventListener("click", () => fitBone(wb, viewer));
  return viewer;
}

/** Window/level: two sliders over the raw range; tiles are re-requested after a short pause
 * so that dragging a slider does not fetch every intermediate window. */
function wireWindowSliders(root, info, viewer) {
  const [min, max] = info.range;
  const lo = root.querySelector(".window-lo");
  const hi = root.querySelector(".window-hi");
  const readout = root.querySelector(".window-readout");
  lo.dataset.testid = `window-lo-${info.name}`;
  hi.dataset.testid = `window-hi-${info.name}`;
  // Whole steps for integer data (8/16-bit images), 1/1000 of the range otherwise.
  const integer = Number.isInteger(min) && Number.isInteger(max) && max - min >= 50;
  for (const s of [lo, hi]) {
    s.min = String(min);
    s.max = String(max);
    s.step = integer ? "1" : String((max - min) / 1000 || 1);
  }
  lo.value = String(info.window[0]);
  hi.value = String(info.window[1]);
  let timer = 0;
  const update = () => {
    const a = Number(lo.value);
    const b = Number(hi.value);
    readout.textContent = `${fmt(a)}–${fmt(b)}`;
    clearTimeout(timer);
    timer = setTimeout(() => viewer.setWindow(Math.min(a, b), Math.max(a, b)), 120);
  };
  lo.addEventListener("input", update);
  hi.addEventListener("input", update);
  readout.textContent = `${fmt(info.window[0])}–${fmt(info.window[1])}`;
}

/** A window bound for display: whole numbers for 8/16-bit data, 3 digits otherwise. */
function fmt(x) {
  return Math.abs(x) >= 100 || Number.isInteger(x) ? x.toFixed(0) : x.toPrecision(3);
}

/** Fit to the bone: the box around the view's annotations and registered outline. */
function fitBone(wb, viewer) {
  const pts = [];
  const va = wb.viewAnnotations(viewer.name);
  for (const lm of Object.values(va.landmarks)) pts.push(lm.uv);
  for (const c of va.contours) pts.push(...c.uv);
  for (const line of wb.result?.views?.[viewer.name]?.outline_px ?? []) pts.push(...line);
  if (!pts.length) {
    viewer.fit();
    wb.status(`${viewer.name}: nothing annotated yet, showing the whole image`);
    return;
  }
  const us = pts.map((p) => p[0]);
  const vs = pts.map((p) => p[1]);
  const [u0, u1, v0, v1] = [Math.min(...us), Math.max(...us), Math.min(...vs), Math.max(...vs)];
  const m = 0.15 * Math.max(u1 - u0, v1 - v0, 40);
  viewer.fitRect(u0 - m, v0 - m, u1 + m, v1 + m);
}

function wireControls(wb) {
  $("mode-landmark").addEventListener("click", () => wb.setMode("landmark"));
  $("mode-outline").addEventListener("click", () => wb.setMode("outline"));
  $("snap").addEventListener("change", (ev) => {
    wb.snap = ev.target.checked;
  });
  $("closed").addEventListener("change", (ev) => {
    wb.closedOutline = ev.target.checked;
  });
  $("sigma").addEventListener("change", (ev) => wb.setSigma(Number(ev.target.value)));
  $("show-result").addEventListener("change", (ev) => {
    wb.showResult = ev.target.checked;
    wb.redraw();
  });
  $("outline-finish").addEventListener("click", () => wb.tools.outline.finish());
  $("outline-cancel").addEventListener("click", () => wb.tools.outline.cancel());
  $("delete-selected").addEventListener("click", () => wb.tool().deleteSelected());
  document.addEventListener("keydown", (ev) => onKey(wb, ev));
}

/** Keyboard: L / O modes, F fit, Enter finish, Esc cancel, Backspace undo an anchor, Delete
 * removes the selected landmark (in the view under the mouse) or contour. */
function onKey(wb, ev) {
  if (ev.target instanceof HTMLInputElement || ev.ctrlKey || ev.metaKey || ev.altKey) return;
  const outline = wb.tools.outline;
  const key = ev.key;
  if (key === "l" || key === "L") wb.setMode("landmark");
  else if (key === "o" || key === "O") wb.setMode("outline");
  else if (key === "f" || key === "F") wb.viewers.get(wb.activeView)?.fit();
  else if (key === "Enter" && wb.mode === "outline") outline.finish();
  else if (key === "Escape") wb.tool().cancel();
  else if (key === "Backspace" && wb.mode === "outline" && outline.tracing()) outline.undo();
  else if (key === "Delete" || key === "Backspace") wb.tool().deleteSelected();
  else return;
  ev.preventDefault();
}

/** A page that cannot work (no token, server gone at start) says why instead of going blank. */
function fatal(err) {
  const box = $("fatal");
  const forbidden = err instanceof ApiError && err.status === 403;
  box.querySelector("h2").textContent = forbidden
    ? "Access denied (403)"
    : "The workbench could not start";
  box.querySelector(".detail").textContent = err.message || String(err);
  box.querySelector(".hint").textContent = forbidden
    ? "This page needs the workbench's token. Open the URL that `biplanar-reg workbench` " +
      "printed when it started (http://127.0.0.1:PORT/?token=…)."
    : "Is `biplanar-reg workbench` still running? Restart it and open the URL it prints.";
  box.hidden = false;
  document.body.dataset.ready = "error";
  $("app").hidden = true;
}

/** Test hooks (tests/workbench/test_e2e.py): transforms and waits; not used by the page. */
function exposeForTests(wb) {
  const viewer = (name) => {
    const v = wb.viewers.get(name);
    if (!v) throw new Error(`no view ${name}`);
    return v;
  };
  window.workbench = {
    state: wb,
    viewToClient: (name, u, v) => viewer(name).toClient(u, v),
    clientToView: (name, x, y) => {
      const rect = viewer(name).canvas.getBoundingClientRect();
      return viewer(name).toView(x - rect.left, y - rect.top);
    },
    viewState: (name) => {
      const v = viewer(name);
      return { zoom: v.zoom, offX: v.offX, offY: v.offY, level: v.level(), window: v.window };
    },
    fitRect: (name, u0, v0, u1, v1) => viewer(name).fitRect(u0, v0, u1, v1),
    /** Resolves when the edits sent so far are answered and no livewire call is pending. */
    idle: () => wb.queue.then(() => undefined),
    tilesPending: () => [...wb.viewers.values()].reduce((n, v) => n + v.tiles.pending(), 0),
  };
}

async function main() {
  let caseInfo;
  let annotations;
  try {
    [caseInfo, annotations] = await Promise.all([api.getCase(), api.getAnnotations()]);
  } catch (err) {
    fatal(err);
    return;
  }
  const wb = new Workbench(caseInfo, annotations);
  document.title = `${caseInfo.id} — biplanar-reg workbench`;
  $("case-id").textContent = caseInfo.id;
  $("case-info").textContent =
    `poses: ${caseInfo.poses ?? "?"} · silhouettes: ${caseInfo.silhouettes ? "on" : "off"}`;
  for (const info of caseInfo.views) wb.viewers.set(info.name, buildView(wb, info));
  wireControls(wb);
  document.body.dataset.mode = wb.mode;
  wb.refresh();
  exposeForTests(wb);
  const panel = new RegisterPanel(wb, {
    button: $("register"),
    panel: $("register-panel"),
    progress: $("progress"),
    flags: $("flags"),
    metrics: $("metrics"),
    error: $("register-error"),
  });
  try {
    await panel.init();
  } catch (err) {
    wb.error(err);
  }
  document.body.dataset.ready = "true";
}

main();
