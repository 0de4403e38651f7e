// app.js — the workbench page's entry point: loads the case, builds one viewer per radiograph
// and wires the controls to the shared state (workbench.js). Every edit goes straight to the
// server (which saves it in the case folder), so nothing is lost on reload.
//
// For the browser tests, `window.workbench` exposes the view transforms and a few waits.

import { api } from "./api.js";
import { EPIPOLAR_SHORTCUTS, installEpipolar } from "./epipolar.js";
import { fatal } from "./fatal.js";
import { installHistory } from "./history.js";
import { addShortcut, installKeys, SHORTCUTS } from "./keys.js";
import { ModelView } from "./model3d.js";
import { installMarkers, MARKER_SHORTCUTS } from "./markers.js";
import { installOutlineTools } from "./outlines.js";
import { PoseAid, PoseTool, ResultShading } from "./poseaid.js";
import { RegisterPanel } from "./register.js";
import { Viewer } from "./viewer.js";
import { WindowControls, WINDOW_SHORTCUTS } from "./window.js";
import { Workbench } from "./workbench.js";

const $ = (id) => document.getElementById(id);

// ---- page set-up -------------------------------------------------------------------------

/** One view's DOM: a title bar with the window/level controls and fit buttons, the canvas. */
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

  let windowing = null;
  const viewer = new Viewer(canvas, info, {
    tileUrl: (level, tx, ty, lo, hi, clahe) =>
      api.tileUrl(info.name, level, tx, ty, lo, hi) + (clahe ? "&clahe=1" : ""),
    handler: () => wb.tool(),
    drawOverlay: (ctx, v) => {
      wb.drawOverlay(ctx, v);
      windowing?.draw(ctx, v);
    },
    onCursor: (v, uv) => wb.cursor(v, uv),
  });
  if (info.has_image && info.range && info.window) {
    windowing = new WindowControls(wb, viewer, template.querySelector(".view-bar"), info);
  } else {
    template.querySelector(".window").hidden = true; // a view without an image: nothing to window
  }
  template.querySelector(".fit").addEventListener("click", () => viewer.fit());
  template.querySelector(".fit-bone").addEventListener("click", () => fitBone(wb, viewer));
  return viewer;
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
  $("delete-selected").addEventListener("click", () => wb.tools.outline.deleteSelected());
}

/** A module's shortcut ({key, help, run?}) as an entry of the page's table (keys.js): a
 * plain key when it runs something, else a line of the list only (e.g. "right-drag"). */
function moduleShortcut({ key, help, run }) {
  const match = (ev) =>
    Boolean(run) && !ev.ctrlKey && !ev.metaKey && !ev.altKey && ev.key.toLowerCase() === key.toLowerCase();
  return { keys: key, what: help, match, run: (wb) => (run ? run(wb) : false) };
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
    /** Resolves when the edits sent so far are answered (saved by the server). */
    idle: () => wb.queue.then(() => undefined),
    tilesPending: () => [...wb.viewers.values()].reduce((n, v) => n + v.tiles.pending(), 0),
    shortcuts: SHORTCUTS, // the table the key handler runs and "?" lists (keys.js)
  };
}

/** The 3D model view, the pose aid (Pose mode) and the result's shading. */
async function initModelAndPose(wb) {
  const fields = Object.fromEntries(["cx", "cy", "cz", "ax", "ay", "az"].map((k) => [k, $(`pose-${k}`)]));
  const aid = new PoseAid(wb, {
    panel: $("pose-panel"), status: $("pose-status"), reset: $("pose-reset"), undo: $("pose-undo"),
    save: $("pose-save"), propose: $("pose-propose"), accept: $("pose-accept"),
    discard: $("pose-discard"), show: $("pose-show"), time: $("pose-time"), fields,
  });
  const shading = new ResultShading(wb, $("show-shading"));
  wb.tools.pose = new PoseTool(wb, aid);
  wb.overlays.push((ctx, v) => shading.draw(ctx, v), (ctx, v) => aid.draw(ctx, v));
  $("mode-pose").addEventListener("click", () => wb.setMode("pose"));
  const model = new ModelView(wb, {
    box: $("model-box"), name: $("model-name"), list: $("model-landmarks"),
    status: $("model-status"), showResult: $("model-result"), legend: $("model-legend"),
    views: $("model-views"),
  });
  aid.listeners.push((doc) => model.setPose(doc)); // the 3D view oriented like a radiograph
  $("model-result").addEventListener("change", (ev) => model.setShowResult(ev.target.checked));
  $("model-enlarge").addEventListener("click", () => {
    const big = $("model-panel").classList.toggle("big");
    $("model-enlarge").setAttribute("aria-pressed", String(big));
    model.resize();
  });
  const onResult = async (result) => {
    if (!result) return;
    await Promise.all([shading.load(), model.loadResult()]);
  };
  wb.resultListeners.push((r) => onResult(r).catch((err) => wb.error(err)));
  window.workbench.poseAid = aid;
  window.workbench.model = model;
  await Promise.all([
    aid.init(),
    model
      .init()
      .then(() => model.setPose(aid.doc))
      .catch((err) => model.say(`3D view: ${err.message}`, true)),
    wb.result ? onResult(wb.result) : null,
  ]);
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
  installOutlineTools(wb); // outline editing, zones, GrabCut, quality (outlines.js)
  installMarkers(wb); // marker beads proposed as exclusion zones (markers.js)
  installEpipolar(wb); // epipolar curves of the cursor and the selected landmark (epipolar.js)
  installHistory(wb, { undo: $("undo"), redo: $("redo") }); // undo / redo (history.js)
  installKeys(wb); // the shortcuts and their "?" list; no control keeps the focus (keys.js)
  for (const s of [...EPIPOLAR_SHORTCUTS, ...WINDOW_SHORTCUTS, ...MARKER_SHORTCUTS]) {
    addShortcut(moduleShortcut(s));
  }
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
    start: $("register-start"),
  });
  try {
    await panel.init();
  } catch (err) {
    wb.error(err);
  }
  await initModelAndPose(wb);
  document.body.dataset.ready = "true";
}

main();
