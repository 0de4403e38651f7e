// outlines.js — outline editing beyond tracing (biplanar_reg/workbench/outline_tools.py does the
// numerics): edit a contour's anchors (drag, insert, delete: the server re-traces the livewire),
// erase a stretch, exclusion zones (circle, brush) that cut the contours, GrabCut from a box,
// the edge strength along each contour, and per-contour residuals after a registration.
//
// installOutlineTools(wb) puts an OutlineTools object in place of wb.tools.outline: in the
// "trace" sub-mode it hands every event to the tracing tool (tools.js), in the others it does
// the editing here. It also draws its overlay and decorates the contour list, by wrapping
// wb.drawOverlay / wb.refresh / wb.setViewAnnotations / wb.setResult.

import { contourPath, request } from "./api.js";
import { COLORS, distanceToPolyline, polyline } from "./overlay.js";
import { contourRow } from "./panels.js";
import { el } from "./dom.js";

const ANCHOR_HIT_PX = 8; // how near (CSS px) a press must be to grab an anchor (drawn 8 px)
const SAME_POINT_PX = 4; // an erase's second click this near (CSS px) the first is the same point
const DRAG_SLOP_PX = 3;
const enc = encodeURIComponent;
const $ = (id) => document.getElementById(id);

export const outlineApi = {
  trace: (view, anchors, closed) =>
    request("POST", `api/views/${enc(view)}/outlines`, { anchors, closed }),
  // `contour` as the server last sent it: its id and version (a stale edit gets 409)
  retrace: (view, contour, anchors, closed) =>
    request("PUT", contourPath(view, contour, "anchors"), { anchors, closed }),
  erase: (view, contour, from, to) =>
    request("POST", contourPath(view, contour, "erase"), { from, to }),
  grabcut: (view, box) => request("POST", `api/views/${enc(view)}/grabcut`, { box }),
  zones: (view) => request("GET", `api/views/${enc(view)}/exclusions`),
  addZone: (view, body) => request("POST", `api/views/${enc(view)}/exclusions`, body),
  deleteZone: (view, k) => request("DELETE", `api/views/${enc(view)}/exclusions/${k}`),
  quality: (view) => request("GET", `api/views/${enc(view)}/quality`),
  residuals: () => request("GET", "api/result/contours"),
};

const SUBMODES = [
  ["trace", "Trace", "click livewire anchors; Enter or double-click finishes"],
  ["edit", "Edit", "drag an anchor of the selected contour; click the contour to insert one, an anchor to delete it"],
  ["erase", "Erase", "click two points of a contour: the stretch between them goes"],
  ["circle", "Circle", "exclusion circle: press at the centre and drag to the radius (a click: the radius field)"],
  ["brush", "Brush", "paint an exclusion zone (the radius field is the brush's)"],
  ["grabcut", "GrabCut", "drag a box round the bone: its GrabCut outline becomes a contour"],
];
const ZONE_FILL = "rgba(255, 80, 80, 0.22)";
const ZONE_LINE = "#ff6b6b";
const STRENGTH_COLORS = { weak: "#ff5c5c", mid: COLORS.contour, strong: "#6ea8ff" };

function round2(uv) {
  return uv.map((x) => Math.round(x * 100) / 100);
}

function residualClass(px) {
  if (px < 3) return "good";
  if (px < 8) return "fair";
  return "bad";
}


export class OutlineTools {
  constructor(wb, tracer) {
    this.wb = wb;
    this.tracer = tracer; // tools.js OutlineTool
    this.submode = "trace";
    this.zones = {}; // view -> [polygon]
    this.quality = {}; // view -> [{index, strength, median, verdict, ...}]
    this.thresholds = {}; // view -> {weak, strong}: the server's, in the strength's units
    this.residuals = null; // {views: {view: [{index, mean_px, worst_mean_px, worst_uv}]}}
    this.showQuality = true;
    this.press = null; // the gesture in progress: {kind, view, start, points, moved, ...}
    this.eraseFrom = null; // {view, index, uv}
  }

  get trace() {
    return this.tracer.trace;
  }

  // ---- delegation to the tracing tool (keyboard shortcuts of app.js use these) ----------

  tracing() {
    return this.tracer.tracing();
  }
  finish() {
    return this.tracer.finish();
  }
  undo() {
    return this.tracer.undo();
  }
  /** Esc: forget the gesture or the outline being traced; with neither, drop the selection. */
  cancel() {
    const idle = !this.press && !this.eraseFrom && !this.tracer.tracing();
    this.press = null;
    this.eraseFrom = null;
    this.tracer.cancel();
    if (idle && this.wb.selectedContour) this.wb.selectContour(null);
  }
  deleteSelected() {
    return this.tracer.deleteSelected();
  }
  hover(viewer, uv, ev) {
    if (this.submode === "trace") this.tracer.hover(viewer, uv, ev);
  }
  doubleClick(viewer, uv, ev) {
    return this.submode === "trace" ? this.tracer.doubleClick(viewer, uv, ev) : true;
  }

  setSubmode(mode) {
    // the selection stays (select a contour, then pick Edit or Erase)
    this.press = null;
    this.eraseFrom = null;
    this.tracer.cancel();
    this.submode = mode;
    for (const b of document.querySelectorAll("#outline-submodes button")) {
      b.setAttribute("aria-pressed", String(b.dataset.submode === mode));
    }
    const help = SUBMODES.find(([m]) => m === mode)[2];
    this.wb.status(`Outline · ${mode}: ${help}`);
    this.wb.redraw();
  }

  radius() {
    const r = Number($("zone-radius")?.value);
    return r > 0 ? r : 10;
  }

  // ---- pointer input ---------------------------------------------------------------------

  selected(viewer) {
    const sel = this.wb.selectedContour;
    if (!sel || sel.view !== viewer.name) return null;
    const c = this.wb.viewAnnotations(viewer.name).contours[sel.index];
    return c ? { index: sel.index, contour: c } : null;
  }

  anchorHit(viewer, uv) {
    const s = this.selected(viewer);
    if (!s || !s.contour.anchors) return -1;
    const [x, y] = viewer.toCanvas(...uv);
    let best = -1;
    let bestD = ANCHOR_HIT_PX;
    s.contour.anchors.forEach((a, i) => {
      const [ax, ay] = viewer.toCanvas(...a);
      const d = Math.hypot(ax - x, ay - y);
      if (d <= bestD) {
        best = i;
        bestD = d;
      }
    });
    return best;
  }

  pointerDown(viewer, uv, ev) {
    const m = this.submode;
    if (m === "trace") return this.tracer.pointerDown?.(viewer, uv, ev) ?? false;
    const start = viewer.toCanvas(...uv);
    if (m === "edit") {
      const k = this.anchorHit(viewer, uv);
      if (k < 0) return false;
      this.press = { kind: "anchor", view: viewer.name, k, start, uv, moved: false };
      return true;
    }
    if (m === "circle" || m === "brush" || m === "grabcut") {
      this.press = { kind: m, view: viewer.name, start, uv0: uv, uv, points: [uv], moved: false };
      return true;
    }
    return false;
  }

  drag(viewer, uv) {
    const p = this.press;
    if (!p || p.view !== viewer.name) return;
    const [x, y] = viewer.toCanvas(...uv);
    if (!p.moved && Math.hypot(x - p.start[0], y - p.start[1]) < DRAG_SLOP_PX) return;
    p.moved = true;
    p.uv = uv;
    if (p.kind === "brush") p.points.push(uv);
    this.wb.redraw();
  }

  drop(viewer, uv, ev, count) {
    const p = this.press;
    this.press = null;
    if (!p) return;
    if (p.kind === "anchor") this.anchorDrop(viewer, p, uv);
    else if (p.kind === "circle") {
      const r = p.moved ? Math.hypot(uv[0] - p.uv0[0], uv[1] - p.uv0[1]) : this.radius();
      this.addZone(p.view, { circle: { center: round2(p.uv0), radius_px: Math.max(r, 1) } });
    } else if (p.kind === "brush") {
      this.addZone(p.view, {
        brush: { points: thin(p.points, this.radius() / 2).map(round2), radius_px: this.radius() },
      });
    } else if (p.kind === "grabcut") {
      if (!p.moved) {
        this.wb.status("GrabCut: drag a box round the bone.");
        return;
      }
      this.grabcut(p.view, [...round2(p.uv0), ...round2(uv)]);
    }
    this.wb.redraw();
  }

  click(viewer, uv, ev, count) {
    const m = this.submode;
    if (m === "trace") return this.tracer.click(viewer, uv, ev, count);
    if (count > 1) return;
    const hit = this.tracer.hitContour(viewer, uv);
    if (m === "edit") {
      const s = this.selected(viewer);
      if (s && hit === s.index && s.contour.anchors) {
        this.insertAnchor(viewer.name, s, uv);
        return;
      }
      this.wb.selectContour(hit < 0 ? null : { view: viewer.name, index: hit });
      const c = hit >= 0 ? this.wb.viewAnnotations(viewer.name).contours[hit] : null;
      if (c && !c.anchors) {
        this.wb.status(`contour #${hit} has no anchors (made outside the workbench or by GrabCut): erase a stretch or trace it again`);
      }
      return;
    }
    if (m === "erase") {
      if (hit < 0) {
        this.wb.status("Erase: click on a contour.");
        return;
      }
      const f = this.eraseFrom;
      if (f && f.view === viewer.name && f.index === hit && this.samePoint(viewer, f.uv, uv)) {
        // a stretch of no length: nothing to erase (and the contour must not be split)
        this.wb.status(`Erase: that is where the stretch starts; click its other end on contour #${hit}`);
        return;
      }
      if (!f || f.view !== viewer.name || f.index !== hit) {
        this.eraseFrom = { view: viewer.name, index: hit, uv: round2(uv) };
        this.wb.selectContour({ view: viewer.name, index: hit });
        this.wb.status(`Erase: now click the other end of the stretch on contour #${hit}`);
        return;
      }
      this.eraseFrom = null;
      const contour = this.wb.contourAt(viewer.name, hit);
      this.run(viewer.name, () => outlineApi.erase(viewer.name, contour, f.uv, round2(uv)),
        (res) => `contour #${hit}: stretch erased (${res.pieces} piece(s) left)`);
    }
  }

  samePoint(viewer, a, b) {
    const [ax, ay] = viewer.toCanvas(...a);
    const [bx, by] = viewer.toCanvas(...b);
    return Math.hypot(ax - bx, ay - by) < SAME_POINT_PX;
  }

  anchorDrop(viewer, p, uv) {
    const s = this.selected(viewer);
    if (!s) return;
    const anchors = s.contour.anchors.map((a) => [...a]);
    const need = s.contour.closed ? 3 : 2;
    if (p.moved) anchors[p.k] = round2(uv);
    else if (anchors.length > need) anchors.splice(p.k, 1);
    else {
      this.wb.status(`contour #${s.index}: needs at least ${need} anchors`);
      return;
    }
    this.retrace(viewer.name, s, anchors, p.moved ? "anchor moved" : "anchor deleted");
  }

  insertAnchor(view, s, uv) {
    // the new anchor goes between the anchors whose nearest contour points bracket the click
    const at = nearestIndex(s.contour.uv, uv);
    const idx = s.contour.anchors.map((a) => nearestIndex(s.contour.uv, a));
    let pos = idx.findIndex((i) => i > at);
    if (pos < 0) pos = idx.length;
    if (pos === 0 && !s.contour.closed) pos = 1;
    const anchors = s.contour.anchors.map((a) => [...a]);
    anchors.splice(pos, 0, round2(uv));
    this.retrace(view, s, anchors, "anchor inserted");
  }

  retrace(view, s, anchors, what) {
    const closed = s.contour.closed;
    const ref = { id: s.contour.id, version: s.contour.version };
    s.contour.anchors = anchors; // optimistic: drawn at once, replaced by the answer
    this.run(view, () => outlineApi.retrace(view, ref, anchors, closed),
      (res) => `contour #${s.index}: ${what}, re-traced (${res.pieces} piece(s))`,
      (res) => this.wb.selectContour({ view, index: res.index }));
  }

  addZone(view, body) {
    this.wb.edit(async () => {
      const res = await outlineApi.addZone(view, body);
      this.zones[view] = res.zones;
      this.wb.setViewAnnotations(view, res.view);
      const cut = res.cut.length ? `, cut contour(s) #${res.cut.join(", #")}` : "";
      this.wb.status(`${view}: exclusion zone added${cut}`);
    });
  }

  removeZone(view, k) {
    this.wb.edit(async () => {
      const res = await outlineApi.deleteZone(view, k);
      this.zones[view] = res.zones;
      this.wb.setViewAnnotations(view, res.view); // what the zone cut is back
      const kept = res.not_restored
        ? `; ${res.not_restored} edited since stay as they are` : "";
      this.wb.status(`${view}: exclusion zone ${k} removed, ${res.restored} contour(s) restored${kept}`);
    });
  }

  grabcut(view, box) {
    this.wb.status(`${view}: GrabCut running…`);
    this.run(view, () => outlineApi.grabcut(view, box),
      (res) => `${view}: GrabCut contour #${res.index} saved (${res.seconds.toFixed(1)} s)`);
  }

  /** One edit: call(), then the view's annotations from the answer and a status line. */
  run(view, call, message, after) {
    this.wb.edit(async () => {
      const res = await call();
      this.wb.setViewAnnotations(view, res.view);
      after?.(res);
      this.wb.status(message(res));
    });
  }

  // ---- data from the server --------------------------------------------------------------

  async loadZones() {
    for (const { name, has_image: hasImage } of this.wb.caseInfo.views) {
      if (!hasImage) continue;
      try {
        this.zones[name] = (await outlineApi.zones(name)).zones;
        this.loadQuality(name);
      } catch (err) {
        this.wb.error(err);
      }
    }
    this.wb.refresh();
  }

  async loadQuality(view) {
    try {
      const q = await outlineApi.quality(view);
      this.quality[view] = q.contours;
      this.thresholds[view] = { weak: q.weak, strong: q.strong };
      this.decorateList();
      this.wb.redraw();
    } catch (err) {
      if (err.status !== 404) this.wb.error(err);
    }
  }

  async loadResiduals() {
    try {
      this.residuals = this.wb.result ? await outlineApi.residuals() : null;
    } catch (err) {
      this.residuals = null;
      if (err.status !== 404) this.wb.error(err);
    }
    this.decorateList();
    this.wb.redraw();
  }

  // ---- drawing ---------------------------------------------------------------------------

  draw(ctx, viewer) {
    for (const z of this.zones[viewer.name] ?? []) drawZone(ctx, viewer, z);
    const va = this.wb.viewAnnotations(viewer.name);
    const q = this.quality[viewer.name];
    if (this.showQuality && this.wb.mode === "outline" && q) {
      for (const item of q) {
        const c = va.contours[item.index];
        const th = this.thresholds[viewer.name];
        if (c && c.uv.length === item.strength.length) drawStrength(ctx, viewer, c, item.strength, th);
      }
    }
    const s = this.selected(viewer);
    if (s?.contour.anchors && this.wb.mode === "outline" && this.submode !== "trace") {
      drawAnchors(ctx, viewer, s.contour.anchors);
    }
    if (this.wb.showResult && this.residuals) drawWorst(ctx, viewer, this.residuals.views[viewer.name]);
    this.drawGesture(ctx, viewer);
  }

  drawGesture(ctx, viewer) {
    const p = this.press;
    const f = this.eraseFrom;
    if (f && f.view === viewer.name) {
      const [x, y] = viewer.toCanvas(...f.uv);
      ctx.strokeStyle = ZONE_LINE;
      ctx.lineWidth = 2;
      ctx.strokeRect(x - 4, y - 4, 8, 8);
    }
    if (!p || p.view !== viewer.name || !p.moved) return;
    if (p.kind === "anchor") {
      // the dragged anchor, joined to its neighbours until the server's re-trace arrives
      const s = this.selected(viewer);
      const a = s?.contour.anchors ?? [];
      const near = [a[p.k - 1], p.uv, a[p.k + 1]].filter(Boolean);
      polyline(ctx, viewer, near, { color: COLORS.trace, width: 1, dash: [3, 3] });
      drawAnchors(ctx, viewer, [p.uv]);
      return;
    }
    ctx.setLineDash([4, 3]);
    ctx.strokeStyle = p.kind === "grabcut" ? COLORS.trace : ZONE_LINE;
    ctx.lineWidth = 1.5;
    const [x0, y0] = viewer.toCanvas(...p.uv0);
    const [x1, y1] = viewer.toCanvas(...p.uv);
    if (p.kind === "circle") {
      ctx.beginPath();
      ctx.arc(x0, y0, Math.hypot(x1 - x0, y1 - y0), 0, 2 * Math.PI);
      ctx.stroke();
    } else if (p.kind === "grabcut") {
      ctx.strokeRect(x0, y0, x1 - x0, y1 - y0);
    } else if (p.kind === "brush") {
      ctx.setLineDash([]);
      polyline(ctx, viewer, p.points, { color: ZONE_FILL, width: 2 * this.radius() * viewer.zoom });
    }
    ctx.setLineDash([]);
  }

  // ---- the contour list ------------------------------------------------------------------

  /** Add to each contour's row its edge strength and, after a registration, its residual
   * (click: the view centred on the worst stretch); and the zone list. */
  decorateList() {
    for (const { name: view } of this.wb.caseInfo.views) {
      for (const q of this.quality[view] ?? []) {
        const row = contourRow(view, q.index);
        const c = this.wb.viewAnnotations(view).contours[q.index];
        // an answer for an older state of the view (its contours since changed) waits
        if (!row || !c || c.uv.length !== q.strength.length || row.querySelector(".quality")) continue;
        const cls = q.verdict === "faint" ? "quality faint" : "quality";
        const badge = el("span", { class: cls, "data-testid": `quality-${view}-${q.index}` },
          `edge ${q.median.toFixed(2)}${q.verdict === "faint" ? " faint" : ""}`);
        badge.title =
          `edge strength along the contour: median ${q.median} × a typical edge of this image; ` +
          `${Math.round(100 * q.weak_fraction)}% weak, ${Math.round(100 * q.strong_fraction)}% ` +
          "on the image's strongest edges (a bead or metal?)";
        row.querySelector(".meta").after(badge);
      }
      for (const r of this.residuals?.views?.[view] ?? []) {
        const row = contourRow(view, r.index);
        if (!row || row.querySelector(".residual") || r.worst_mean_px === null) continue;
        const chip = el("span", {
          class: `residual jump ${residualClass(r.worst_mean_px)}`,
          "data-testid": `contour-residual-${view}-${r.index}`,
          title: `mean ${r.mean_px} px, worst 20 px stretch ${r.worst_mean_px} px from the ` +
            "registered outline: click to centre the view on the worst stretch",
          onclick: (ev) => {
            ev.stopPropagation();
            this.wb.selectContour({ view, index: r.index });
            this.wb.viewers.get(view)?.centreOn(...r.worst_uv);
          },
        }, `${r.mean_px.toFixed(1)}/${r.worst_mean_px.toFixed(1)}`);
        row.querySelector(".remove").before(chip);
      }
    }
    this.renderZones();
  }

  renderZones() {
    const list = $("zone-list");
    if (!list) return;
    const items = [];
    for (const [view, zones] of Object.entries(this.zones)) {
      zones.forEach((z, k) => {
        const c = centroid(z);
        items.push(el("li", { class: "contour", "data-testid": `zone-${view}-${k}`,
          onclick: () => this.wb.viewers.get(view)?.centreOn(...c) },
        el("span", { class: "name" }, `${view} zone ${k}`),
        el("span", { class: "meta" }, `(${c[0].toFixed(0)}, ${c[1].toFixed(0)})`),
        el("button", { class: "remove", title: "remove the zone", onclick: (ev) => {
          ev.stopPropagation();
          this.removeZone(view, k);
        } }, "×")));
      });
    }
    list.replaceChildren(...items);
  }
}

// ---- drawing helpers -----------------------------------------------------------------------

function drawZone(ctx, viewer, zone) {
  ctx.beginPath();
  zone.forEach(([u, v], i) => {
    const [x, y] = viewer.toCanvas(u, v);
    if (i === 0) ctx.moveTo(x, y);
    else ctx.lineTo(x, y);
  });
  ctx.closePath();
  ctx.fillStyle = ZONE_FILL;
  ctx.fill();
  ctx.strokeStyle = ZONE_LINE;
  ctx.lineWidth = 1;
  ctx.stroke();
}

/** The contour in the colour of the edge under it: red weak, amber ordinary, blue among the
 * image's strongest edges (the thresholds the server sends with the quality). */
function drawStrength(ctx, viewer, c, strength, { weak, strong }) {
  const cls = (s) => (s < weak ? "weak" : s >= strong ? "strong" : "mid");
  let start = 0;
  for (let i = 1; i <= c.uv.length; i++) {
    if (i < c.uv.length && cls(strength[i]) === cls(strength[start])) continue;
    const k = cls(strength[start]);
    if (k !== "mid") {
      polyline(ctx, viewer, c.uv.slice(Math.max(start - 1, 0), i + 1),
        { color: STRENGTH_COLORS[k], width: 2.5 });
    }
    start = i;
  }
}

function drawAnchors(ctx, viewer, anchors) {
  ctx.fillStyle = COLORS.anchor;
  ctx.strokeStyle = "#000";
  ctx.lineWidth = 1;
  for (const [u, v] of anchors) {
    const [x, y] = viewer.toCanvas(u, v);
    ctx.fillRect(x - 4, y - 4, 8, 8);
    ctx.strokeRect(x - 4, y - 4, 8, 8);
  }
}

/** A ring round each contour's worst stretch, in its residual colour. */
function drawWorst(ctx, viewer, items) {
  const colors = { good: "#3ddc84", fair: "#ffc94d", bad: "#ff5c5c" };
  for (const r of items ?? []) {
    if (r.worst_mean_px === null) continue;
    const [x, y] = viewer.toCanvas(...r.worst_uv);
    ctx.strokeStyle = colors[residualClass(r.worst_mean_px)];
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.arc(x, y, 9, 0, 2 * Math.PI);
    ctx.stroke();
  }
}

function nearestIndex(uv, p) {
  let best = 0;
  let bestD = Infinity;
  uv.forEach(([u, v], i) => {
    const d = (u - p[0]) ** 2 + (v - p[1]) ** 2;
    if (d < bestD) {
      best = i;
      bestD = d;
    }
  });
  return best;
}

function thin(points, spacing) {
  const out = [points[0]];
  for (const p of points.slice(1)) {
    const q = out[out.length - 1];
    if (Math.hypot(p[0] - q[0], p[1] - q[1]) >= spacing) out.push(p);
  }
  const last = points[points.length - 1];
  if (out[out.length - 1] !== last) out.push(last);
  return out;
}

function centroid(poly) {
  const n = poly.length;
  return [poly.reduce((s, p) => s + p[0], 0) / n, poly.reduce((s, p) => s + p[1], 0) / n];
}

// ---- installation ----------------------------------------------------------------------------

function buildControls(tools) {
  const body = document.querySelector("#outline-panel .panel-body");
  if (!body) return;
  const bar = el("div", { class: "modes row submodes", id: "outline-submodes", role: "group",
    "aria-label": "outline tool" });
  for (const [mode, label, help] of SUBMODES) {
    bar.append(el("button", { "data-submode": mode, "data-testid": `outline-${mode}`,
      "aria-pressed": String(mode === "trace"), title: help,
      onclick: () => tools.setSubmode(mode) }, label));
  }
  const radius = el("input", { type: "number", id: "zone-radius", "data-testid": "zone-radius",
    value: "12", min: "1", step: "1" });
  const quality = el("input", { type: "checkbox", id: "show-quality", "data-testid": "show-quality",
    checked: "" });
  quality.addEventListener("change", () => {
    tools.showQuality = quality.checked;
    tools.wb.redraw();
  });
  const row = el("div", { class: "row" },
    el("label", { class: "field" }, "radius ", radius, " px"),
    el("label", { class: "toggle", title: "colour the contours by the edge under them: red weak, blue among the strongest" },
      quality, " edge strength"));
  const zones = el("ul", { id: "zone-list", "data-testid": "zone-list", class: "zones" });
  body.prepend(bar, row);
  body.append(el("h3", { class: "sub" }, "Exclusion zones"), zones);
}

/** Put the outline tools in place (call once, after the Workbench is made). */
export function installOutlineTools(wb) {
  const tools = new OutlineTools(wb, wb.tools.outline);
  wb.tools.outline = tools;
  wb.outlineTools = tools;
  buildControls(tools);

  const drawOverlay = wb.drawOverlay.bind(wb);
  wb.drawOverlay = (ctx, viewer) => {
    drawOverlay(ctx, viewer);
    tools.draw(ctx, viewer);
  };
  const refresh = wb.refresh.bind(wb);
  wb.refresh = () => {
    refresh();
    tools.decorateList();
  };
  const setViewAnnotations = wb.setViewAnnotations.bind(wb);
  wb.setViewAnnotations = (view, va) => {
    setViewAnnotations(view, va);
    tools.loadQuality(view);
    if (tools.residuals) tools.loadResiduals(); // residuals of the edited contours
  };
  const setResult = wb.setResult.bind(wb);
  wb.setResult = (result) => {
    setResult(result);
    tools.loadResiduals();
  };
  tools.loadZones();
  return tools;
}
