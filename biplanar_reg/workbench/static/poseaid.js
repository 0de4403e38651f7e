// poseaid.js — the pose aid: once the landmark clicks fix a pose, the model's mean shape posed
// by them is drawn over each radiograph (outline pieces and landmark positions, lavender),
// recomputed by the server after every landmark edit (GET /api/pose-aid) until the user moves
// it. In Pose mode (P) a drag moves the posed bone in the view's plane, a Shift-drag turns it
// about the view's axis through its centre (POST /api/pose-aid/nudge); while dragging, every
// view shows the pose the drag gives (the server's "preview" of the nudge). The nudge axes of
// each view are drawn in every view. Numeric fields set the centre and the angles; "Undo pose"
// (U) steps back; "Propose outline" snaps every piece of the posed outline to the image's
// edges (livewire) for the user to accept as contours; "Save start pose" writes start.json.
//
// Also the registered bone's shading over each view (GET /api/result/shading/{view}).

import { api } from "./api.js";
import { label, polyline } from "./overlay.js";

export const POSE_COLOR = "#b794ff"; // lavender: apart from the amber contours, magenta result
const PROPOSAL_COLOR = "#c6ff4d";
// the nudge axes: drag along u (red) or v (blue); k (grey) the view's axis, about which
// a Shift-drag turns the bone
const AXIS_COLORS = { u: "#ff6b6b", v: "#5aa9ff", k: "#d0d0d0" };
const FIELDS = ["cx", "cy", "cz", "ax", "ay", "az"];

/** Rotate image point p about c by `deg` degrees (clockwise on screen: v points down). */
function rotateAbout(p, c, deg) {
  const a = (deg * Math.PI) / 180;
  const [du, dv] = [p[0] - c[0], p[1] - c[1]];
  return [c[0] + du * Math.cos(a) - dv * Math.sin(a), c[1] + du * Math.sin(a) + dv * Math.cos(a)];
}

/** The words of the panel for a pose-aid document (the server's reason when there is no pose). */
function statusText(doc) {
  if (!doc?.ready) return doc?.reason ?? "";
  const from = {
    landmarks: "pose: from the landmark clicks",
    nudged: "pose: moved by hand",
    typed: "pose: typed in",
    start: "pose: the saved start pose (start.json)",
  }[doc.source] ?? `pose: ${doc.source}`;
  const changed = doc.landmarks_changed
    ? " · the clicks changed since: “From landmarks” solves them again"
    : "";
  return `${from}${changed} · ${doc.saved ? "saved as the start pose" : "not saved"}`;
}

/** An arrow from a to b in canvas pixels, with a label at its tip (`side`: beside its middle
 * instead, so that the labels of two arrows along one line stay apart). */
function arrow(ctx, a, b, color, text, dash = [], side = false) {
  const [dx, dy] = [b[0] - a[0], b[1] - a[1]];
  const n = Math.hypot(dx, dy);
  ctx.setLineDash(dash);
  ctx.strokeStyle = color;
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.moveTo(...a);
  ctx.lineTo(...b);
  ctx.stroke();
  ctx.setLineDash([]);
  if (n > 6) {
    const [ux, uy] = [dx / n, dy / n];
    ctx.beginPath();
    ctx.moveTo(...b);
    ctx.lineTo(b[0] - 9 * ux + 5 * uy, b[1] - 9 * uy - 5 * ux);
    ctx.lineTo(b[0] - 9 * ux - 5 * uy, b[1] - 9 * uy + 5 * ux);
    ctx.closePath();
    ctx.fillStyle = color;
    ctx.fill();
  }
  if (!text) return;
  if (side && n > 6) {
    const [ux, uy] = [dx / n, dy / n];
    label(ctx, text, a[0] + 0.55 * dx + 8 * uy + 4, a[1] + 0.55 * dy - 8 * ux + 4, color);
  } else label(ctx, text, b[0] + 5, b[1] - 5, color);
}

export class PoseAid {
  constructor(wb, els) {
    this.wb = wb;
    this.els = els; // {panel, status, reset, undo, save, propose, accept, discard, show, time, fields}
    this.doc = null;
    this.show = true;
    this.preview = null; // {view, du, dv, deg, centre} while dragging
    this.previewDoc = null; // {doc, du, dv, deg}: the server's pose for an earlier drag state
    this.previewBusy = false;
    this.proposal = null; // {view, pieces: [{uv, anchors, closed}]}
    this.pending = null;
    this.again = false;
    this.seconds = [];
    this.listeners = []; // called with each new document (the 3D view's orientation)
  }

  init() {
    const e = this.els;
    e.show.addEventListener("change", () => {
      this.show = e.show.checked;
      this.wb.redraw();
    });
    e.reset.addEventListener("click", () => this.act(() => api.poseAidAction("reset")));
    e.undo.addEventListener("click", () => this.undo());
    e.save.addEventListener("click", () => this.saveStart());
    e.propose.addEventListener("click", () => this.propose(this.wb.activeView));
    e.accept.addEventListener("click", () => this.accept());
    e.discard.addEventListener("click", () => this.setProposal(null));
    for (const k of FIELDS) {
      const input = e.fields[k];
      input.addEventListener("change", () => this.typed());
      // Enter sets the pose and gives the keyboard back to the views' shortcuts
      input.addEventListener("keydown", (ev) => {
        if (ev.key === "Enter" || ev.key === "Escape") input.blur();
      });
    }
    this.wb.annotationListeners.push(() => this.refresh());
    return this.refresh();
  }

  /** Ask the server for the pose (one request at a time; edits during one ask again). */
  refresh() {
    if (this.pending) {
      this.again = true;
      return this.pending;
    }
    this.pending = (async () => {
      try {
        do {
          this.again = false;
          const t0 = performance.now();
          this.setDoc(await api.getPoseAid());
          this.note(t0);
        } while (this.again);
      } catch (err) {
        // the panel says what went wrong now, never an earlier reason
        this.setDoc({ ready: false, reason: `pose aid: ${err.message}` });
        this.wb.error(err);
      } finally {
        this.pending = null;
      }
    })();
    return this.pending;
  }

  note(t0) {
    const s = this.doc?.seconds;
    if (typeof s === "number") this.seconds.push(s);
    const rtt = performance.now() - t0;
    this.els.time.textContent =
      typeof s === "number" ? `pose aid ${(s * 1000).toFixed(0)} ms (${rtt.toFixed(0)} ms)` : "";
  }

  setDoc(doc) {
    this.doc = doc;
    const e = this.els;
    const ready = Boolean(doc?.ready);
    e.panel.dataset.ready = String(ready);
    e.panel.dataset.source = doc?.source ?? "";
    for (const b of [e.reset, e.save, e.propose]) b.disabled = !ready;
    e.undo.disabled = !doc?.undo;
    e.status.textContent = statusText(doc);
    const values = ready ? [...doc.centre_mm, ...doc.angles_deg] : [];
    FIELDS.forEach((k, i) => {
      const input = e.fields[k];
      input.disabled = !ready;
      if (document.activeElement !== input) input.value = ready ? values[i].toFixed(i < 3 ? 2 : 1) : "";
    });
    for (const f of this.listeners) f(doc);
    this.wb.redraw();
  }

  async act(fn) {
    try {
      const t0 = performance.now();
      this.setDoc(await fn());
      this.note(t0);
    } catch (err) {
      this.wb.error(err);
    }
  }

  undo() {
    if (!this.doc?.undo) {
      this.wb.status("pose aid: nothing to undo");
      return;
    }
    this.act(() => api.poseAidAction("undo"));
  }

  /** The numeric fields: the bone centre (world mm) and the angles about the world axes. */
  typed() {
    const v = FIELDS.map((k) => Number(this.els.fields[k].value));
    if (v.some((x) => !Number.isFinite(x)) || this.els.fields.cx.value === "") return;
    this.act(() => api.poseAidAction("set", { centre_mm: v.slice(0, 3), angles_deg: v.slice(3) }));
  }

  async saveStart() {
    try {
      const res = await api.poseAidAction("start");
      this.wb.status(`start pose saved: ${res.file} ([registration] start in case.toml)`);
      await this.refresh();
    } catch (err) {
      this.wb.error(err);
    }
  }

  async propose(view) {
    if (!view) return;
    try {
      this.wb.status(`${view}: proposing an outline…`);
      const res = await api.proposeOutline(view);
      this.setProposal({ view, pieces: res.pieces });
      const n = res.pieces.reduce((k, p) => k + p.anchors.length, 0);
      this.wb.status(
        `${view}: ${res.pieces.length} proposed outline piece(s) (${n} anchors, ` +
          `${(res.seconds * 1000).toFixed(0)} ms): Accept saves them as contours`,
      );
    } catch (err) {
      this.wb.error(err);
    }
  }

  setProposal(p) {
    this.proposal = p;
    this.els.accept.disabled = !p;
    this.els.discard.disabled = !p;
    this.els.panel.dataset.proposal = p ? p.view : "";
    this.els.panel.dataset.pieces = p ? String(p.pieces.length) : "";
    this.wb.redraw();
  }

  accept() {
    const p = this.proposal;
    if (!p) return;
    this.wb.edit(async () => {
      let res = null;
      for (const piece of p.pieces) {
        res = await api.addContour(p.view, piece.uv, piece.closed, piece.anchors);
      }
      this.setProposal(null);
      if (res) this.wb.setViewAnnotations(p.view, res.view);
      this.wb.status(`${p.view}: ${p.pieces.length} contour(s) saved from the proposed outline`);
    });
  }

  // ---- a drag's preview in every view ------------------------------------------------------

  /** The drag state changed: redraw at once, and ask the server where it puts the bone (one
   * request at a time; the latest state is asked next). */
  setPreview(p) {
    this.preview = p;
    this.wb.redraw();
    if (!p || this.previewBusy) return;
    this.previewBusy = true;
    (async () => {
      try {
        let asked = null;
        while (this.preview && this.preview !== asked) {
          asked = this.preview;
          const q = asked;
          const body = q.deg
            ? { view: q.view, rotate_deg: q.deg, preview: true }
            : { view: q.view, translate_px: [q.du, q.dv], preview: true };
          const doc = await api.poseAidAction("nudge", body);
          if (this.preview) this.previewDoc = { doc, du: q.du, dv: q.dv, deg: q.deg };
          this.wb.redraw();
        }
      } catch (err) {
        this.wb.error(err);
      } finally {
        this.previewBusy = false;
      }
    })();
  }

  endPreview() {
    this.preview = null;
    this.previewDoc = null;
  }

  // ---- drawing -----------------------------------------------------------------------------

  /** The posed outline, landmarks and (Pose mode) nudge axes of one view. */
  draw(ctx, viewer) {
    const pr = this.proposal;
    if (pr && pr.view === viewer.name) {
      for (const piece of pr.pieces) {
        polyline(ctx, viewer, piece.uv, { color: PROPOSAL_COLOR, width: 2, closed: piece.closed, dash: [5, 3] });
      }
    }
    const pd = this.preview && this.previewDoc;
    const doc = pd ? pd.doc : this.doc;
    const v = this.show && doc?.ready ? doc.views?.[viewer.name] : null;
    if (!v) return;
    const move = this.transform(viewer.name, v, pd);
    (v.outline_px || []).forEach((line, i) => {
      const closed = Boolean(v.outline_closed?.[i]);
      polyline(ctx, viewer, line.map(move), { color: POSE_COLOR, width: 1.5, closed });
    });
    for (const [name, uv] of Object.entries(v.landmarks_px || {})) {
      const [x, y] = viewer.toCanvas(...move(uv));
      ctx.fillStyle = POSE_COLOR;
      ctx.beginPath(); // a diamond: neither the clicked + nor the registered x
      ctx.moveTo(x, y - 5);
      ctx.lineTo(x + 5, y);
      ctx.lineTo(x, y + 5);
      ctx.lineTo(x - 5, y);
      ctx.closePath();
      ctx.fill();
      if (!this.wb.viewAnnotations(viewer.name).landmarks[name]) {
        label(ctx, name, x + 7, y + 4, POSE_COLOR);
      }
    }
    if (this.wb.mode === "pose") this.drawAxes(ctx, viewer, v, move);
  }

  /** This view's nudge axes (solid: drag along u or v, Shift-drag turns clockwise as the arc
   * shows) and the other views' (dashed, named): where a nudge there moves the bone here. */
  drawAxes(ctx, viewer, v, move) {
    for (const [name, ax] of Object.entries(v.axes || {})) {
      const own = name === viewer.name;
      const c = viewer.toCanvas(...move(ax.centre));
      const dash = own ? [] : [6, 4];
      for (const k of own ? ["u", "v"] : ["u", "v", "k"]) {
        const text = own ? `drag ${k}` : `${name} ${k === "k" ? "axis" : k}`;
        arrow(ctx, c, viewer.toCanvas(...move(ax[k])), AXIS_COLORS[k], text, dash, !own);
      }
      if (own) {
        // the turn of a Shift-drag: a clockwise arc with its arrowhead
        const r = 0.6 * Math.hypot(...viewer.toCanvas(...move(ax.u)).map((x, i) => x - c[i]));
        ctx.strokeStyle = AXIS_COLORS.k;
        ctx.lineWidth = 1.5;
        ctx.beginPath();
        ctx.arc(c[0], c[1], r, -0.35 * Math.PI, 0.15 * Math.PI);
        ctx.stroke();
        const e = [c[0] + r * Math.cos(0.15 * Math.PI), c[1] + r * Math.sin(0.15 * Math.PI)];
        const t = [-Math.sin(0.15 * Math.PI), Math.cos(0.15 * Math.PI)];
        arrow(ctx, [e[0] - 8 * t[0], e[1] - 8 * t[1]], e, AXIS_COLORS.k, "Shift-drag");
      }
    }
  }

  /** The drag preview's image transform for one view: the drag itself in the dragged view
   * (minus the part the server's preview already holds); identity elsewhere. */
  transform(view, v, pd) {
    const p = this.preview;
    if (!p || p.view !== view) return (uv) => uv;
    const base = pd ?? { du: 0, dv: 0, deg: 0 };
    if (p.deg) return (uv) => rotateAbout(uv, v.centre_px, p.deg - (base.deg || 0));
    return (uv) => [uv[0] + p.du - (base.du || 0), uv[1] + p.dv - (base.dv || 0)];
  }
}

/** Pose mode: drag translates the posed bone in the view's plane, Shift- (or Alt-) drag turns
 * it about its centre; the nudge is sent on release. */
export class PoseTool {
  constructor(wb, aid) {
    this.wb = wb;
    this.aid = aid;
    this.drag0 = null;
  }

  pointerDown(viewer, uv, ev) {
    const v = this.aid.doc?.ready ? this.aid.doc.views?.[viewer.name] : null;
    if (!v) {
      this.wb.status(this.aid.doc?.reason ?? "pose aid: no pose yet");
      return false;
    }
    this.drag0 = { view: viewer.name, uv, rotate: ev.shiftKey || ev.altKey, centre: v.centre_px };
    return true;
  }

  drag(viewer, uv) {
    const d = this.drag0;
    if (!d) return;
    const p = { view: d.view, du: uv[0] - d.uv[0], dv: uv[1] - d.uv[1], deg: 0 };
    if (d.rotate) {
      // the angle swept around the centre, in image coordinates (v down): positive when the
      // mouse goes round clockwise on the screen, the server's positive (clockwise) turn
      const a0 = Math.atan2(d.uv[1] - d.centre[1], d.uv[0] - d.centre[0]);
      const a1 = Math.atan2(uv[1] - d.centre[1], uv[0] - d.centre[0]);
      let deg = ((a1 - a0) * 180) / Math.PI;
      if (deg > 180) deg -= 360;
      if (deg < -180) deg += 360;
      p.deg = deg || 1e-9;
    }
    this.aid.setPreview(p);
  }

  drop() {
    const p = this.aid.preview;
    this.drag0 = null;
    if (!p) return;
    const body = p.deg ? { view: p.view, rotate_deg: p.deg } : { view: p.view, translate_px: [p.du, p.dv] };
    this.aid.act(async () => {
      const doc = await api.poseAidAction("nudge", body);
      this.aid.endPreview();
      return doc;
    });
  }

  click() {}
  cancel() {
    this.drag0 = null;
    this.aid.endPreview();
    this.wb.redraw();
  }
  deleteSelected() {}
}

/** The registered bone shaded over each view (drawn under the outlines). */
export class ResultShading {
  constructor(wb, toggle) {
    this.wb = wb;
    this.toggle = toggle;
    this.views = {};
    this.show = toggle.checked;
    toggle.addEventListener("change", () => {
      this.show = toggle.checked;
      wb.redraw();
    });
  }

  async load() {
    const out = {};
    for (const { name } of this.wb.caseInfo.views) {
      try {
        out[name] = await api.getResultShading(name);
      } catch (err) {
        if (err.status !== 404 && err.status !== 409) this.wb.error(err);
      }
    }
    this.views = out;
    document.body.dataset.shading = String(Object.keys(out).length);
    this.wb.redraw();
  }

  draw(ctx, viewer) {
    const s = this.show && this.wb.showResult ? this.views[viewer.name] : null;
    if (!s) return;
    // Opaque triangles into a buffer, then the buffer at half opacity: overlapping triangles
    // would otherwise add up their opacity along every shared edge.
    const buf = (this.buffer ??= document.createElement("canvas"));
    buf.width = ctx.canvas.width;
    buf.height = ctx.canvas.height;
    const b = buf.getContext("2d");
    b.setTransform(ctx.getTransform());
    const t = s.triangles;
    for (let k = 0; k < s.shade.length; k++) {
      const g = Math.round(90 + 165 * s.shade[k]);
      b.fillStyle = `rgb(${g}, ${Math.round(g * 0.93)}, ${Math.round(g * 0.8)})`;
      b.strokeStyle = b.fillStyle;
      b.lineWidth = 0.5;
      b.beginPath();
      for (let j = 0; j < 3; j++) {
        const [x, y] = viewer.toCanvas(t[6 * k + 2 * j], t[6 * k + 2 * j + 1]);
        if (j === 0) b.moveTo(x, y);
        else b.lineTo(x, y);
      }
      b.closePath();
      b.fill();
      b.stroke();
    }
    ctx.save();
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.globalAlpha = 0.55;
    ctx.drawImage(buf, 0, 0);
    ctx.restore();
  }
}
