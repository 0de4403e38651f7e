// poseaid.js — the pose aid: once the landmark clicks fix a pose, the model's mean shape posed
// by them is drawn over each radiograph (outline and landmark positions, orange), recomputed
// by the server after every landmark edit (GET /api/pose-aid). In Pose mode (P) a drag moves
// the posed bone in the view's plane, a Shift-drag turns it about its centre (POST
// /api/pose-aid/nudge); "Propose outline" snaps the posed outline to the image's edges
// (livewire) for the user to accept as a contour; "Save start pose" writes start.json.
//
// Also the registered bone's shading over each view (GET /api/result/shading/{view}).

import { api } from "./api.js";
import { label, polyline } from "./overlay.js";

export const POSE_COLOR = "#b794ff"; // lavender: apart from the amber contours, magenta result
const PROPOSAL_COLOR = "#c6ff4d";

/** Rotate image point p about c by `deg` degrees (clockwise on screen: v points down). */
function rotateAbout(p, c, deg) {
  const a = (deg * Math.PI) / 180;
  const [du, dv] = [p[0] - c[0], p[1] - c[1]];
  return [c[0] + du * Math.cos(a) - dv * Math.sin(a), c[1] + du * Math.sin(a) + dv * Math.cos(a)];
}

export class PoseAid {
  constructor(wb, els) {
    this.wb = wb;
    this.els = els; // {panel, status, reset, save, propose, accept, discard, show, time}
    this.doc = null;
    this.show = true;
    this.preview = null; // {view, du, dv, deg, centre} while dragging
    this.proposal = null; // {view, uv, anchors, closed}
    this.pending = null;
    this.again = false;
    this.seconds = [];
  }

  init() {
    const e = this.els;
    e.show.addEventListener("change", () => {
      this.show = e.show.checked;
      this.wb.redraw();
    });
    e.reset.addEventListener("click", () => this.act(() => api.poseAidAction("reset")));
    e.save.addEventListener("click", () => this.saveStart());
    e.propose.addEventListener("click", () => this.propose(this.wb.activeView));
    e.accept.addEventListener("click", () => this.accept());
    e.discard.addEventListener("click", () => this.setProposal(null));
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
    e.panel.dataset.ready = String(Boolean(doc?.ready));
    e.panel.dataset.source = doc?.source ?? "";
    const ready = Boolean(doc?.ready);
    for (const b of [e.reset, e.save, e.propose]) b.disabled = !ready;
    e.status.textContent = ready
      ? doc.source === "nudged"
        ? "pose: from the landmarks, nudged (Reset to drop the nudges)"
        : "pose: from the landmark clicks"
      : doc?.reason ?? "";
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

  async saveStart() {
    try {
      const res = await api.poseAidAction("start");
      this.wb.status(`start pose saved: ${res.file} ([registration] start in case.toml)`);
    } catch (err) {
      this.wb.error(err);
    }
  }

  async propose(view) {
    if (!view) return;
    try {
      this.wb.status(`${view}: proposing an outline…`);
      const res = await api.proposeOutline(view);
      this.setProposal({ view, ...res });
      this.wb.status(
        `${view}: proposed outline (${res.anchors.length} anchors, ` +
          `${(res.seconds * 1000).toFixed(0)} ms): Accept saves it as a contour`,
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
    this.wb.redraw();
  }

  accept() {
    const p = this.proposal;
    if (!p) return;
    this.wb.edit(async () => {
      const res = await api.addContour(p.view, p.uv, p.closed, p.anchors);
      this.setProposal(null);
      this.wb.setViewAnnotations(p.view, res.view);
      this.wb.status(`${p.view}: contour #${res.index} saved from the proposed outline`);
    });
  }

  // ---- drawing -----------------------------------------------------------------------------

  /** The posed outline and landmarks of one view (under the annotations). */
  draw(ctx, viewer) {
    const pr = this.proposal;
    if (pr && pr.view === viewer.name) {
      polyline(ctx, viewer, pr.uv, { color: PROPOSAL_COLOR, width: 2, closed: pr.closed, dash: [5, 3] });
    }
    const v = this.show && this.doc?.ready ? this.doc.views?.[viewer.name] : null;
    if (!v) return;
    const move = this.transform(viewer.name, v);
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
  }

  /** The drag preview's image transform (identity unless this view is being nudged). */
  transform(view, v) {
    const p = this.preview;
    if (!p || p.view !== view) return (uv) => uv;
    if (p.deg) return (uv) => rotateAbout(uv, v.centre_px, p.deg);
    return (uv) => [uv[0] + p.du, uv[1] + p.dv];
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
      const a0 = Math.atan2(d.uv[1] - d.centre[1], d.uv[0] - d.centre[0]);
      const a1 = Math.atan2(uv[1] - d.centre[1], uv[0] - d.centre[0]);
      let deg = ((a1 - a0) * 180) / Math.PI;
      if (deg > 180) deg -= 360;
      if (deg < -180) deg += 360;
      p.deg = deg || 1e-9;
    }
    this.aid.preview = p;
    this.wb.redraw();
  }

  drop(viewer) {
    const p = this.aid.preview;
    this.drag0 = null;
    if (!p) return;
    const body = p.deg ? { view: p.view, rotate_deg: p.deg } : { view: p.view, translate_px: [p.du, p.dv] };
    this.aid.act(async () => {
      const doc = await api.poseAidAction("nudge", body);
      this.aid.preview = null;
      return doc;
    });
  }

  click() {}
  cancel() {
    this.drag0 = null;
    this.aid.preview = null;
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
