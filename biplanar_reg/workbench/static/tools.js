// tools.js — what a click in a view does: the landmark tool (place, drag, delete) and the
// outline tool (livewire anchors with a live preview, finish, select, delete).
//
// A tool receives pointer input from the viewer (viewer.js: pointerDown / drag / drop / click /
// hover / doubleClick) and edits through `wb` (app.js): wb.edit() runs edits one at a time, in
// order, so the server's answers (each the view's annotations) are applied in the order the
// edits were made.

import { api } from "./api.js";
import { distanceToPolyline } from "./overlay.js";

const HIT_PX = 8; // how near (CSS px) a press must be to grab a landmark
// How near (CSS px, on the screen: the same at any zoom) a click must be to select or erase a
// contour; the nearest contour within it wins.
export const CONTOUR_HIT_PX = 14;
const SAME_ANCHOR_PX = 4; // an anchor this near (CSS px) to the last one is the same anchor
const DRAG_SLOP_PX = 3; // a press on a landmark that moves less than this is a click
const PREVIEW_DELAY_MS = 100; // livewire preview debounce: the contract's ~100 ms

/** Image coordinates as saved: 0.01 px is far below any annotation's accuracy. */
function round2(uv) {
  return uv.map((x) => Math.round(x * 100) / 100);
}

const DOUBLE_CLICK_MS = 600; // a double-click this soon after a placement undoes it

export class LandmarkTool {
  constructor(wb) {
    this.wb = wb;
    this.dragging = null; // {view, name, start, moved}
    this.lastClick = null; // {view, name, before, time}: the last placement by a click
  }

  /** The placed landmark of `viewer` nearest to image point uv within HIT_PX, or null. */
  hit(viewer, uv) {
    const [x, y] = viewer.toCanvas(...uv);
    let best = null;
    let bestDist = HIT_PX;
    for (const [name, lm] of Object.entries(this.wb.viewAnnotations(viewer.name).landmarks)) {
      const [lx, ly] = viewer.toCanvas(...lm.uv);
      const d = Math.hypot(x - lx, y - ly);
      if (d <= bestDist) {
        best = name;
        bestDist = d;
      }
    }
    return best;
  }

  pointerDown(viewer, uv) {
    const name = this.hit(viewer, uv);
    if (!name) return false;
    // The press may become a drag of `name`, or stay a click (decided in drag / drop).
    this.dragging = { view: viewer.name, name, start: viewer.toCanvas(...uv), moved: false };
    return true; // the viewer hands us the drag instead of panning
  }

  drag(viewer, uv) {
    const d = this.dragging;
    if (!d) return;
    const [x, y] = viewer.toCanvas(...uv);
    if (!d.moved && Math.hypot(x - d.start[0], y - d.start[1]) < DRAG_SLOP_PX) return;
    if (!d.moved) this.wb.selectLandmark(d.name);
    d.moved = true;
    // Optimistic: move it on screen now; the PUT on drop makes it permanent.
    this.wb.viewAnnotations(viewer.name).landmarks[d.name].uv = uv;
    this.wb.redraw();
  }

  drop(viewer, uv, ev, count) {
    const d = this.dragging;
    this.dragging = null;
    if (!d) return;
    if (d.moved) {
      this.place(viewer.name, d.name, uv);
      return;
    }
    // A click on a placed landmark: place the selected landmark there if it is not yet in
    // this view (landmarks can be a few pixels apart), else select the one clicked.
    const sel = this.wb.selectedLandmark;
    if (sel && !this.wb.viewAnnotations(viewer.name).landmarks[sel]) {
      this.click(viewer, uv, ev, count);
    }
    else this.wb.selectLandmark(d.name);
  }

  click(viewer, uv, ev, count) {
    // The second click of a double-click (which fits the view) must not place anything.
    if (count > 1) return;
    const name = this.wb.selectedLandmark;
    if (!name) {
      this.wb.status("Select a landmark in the list first, then click in a view.");
      return;
    }
    const before = this.wb.viewAnnotations(viewer.name).landmarks[name];
    const time = ev.timeStamp;
    this.lastClick = { view: viewer.name, name, before: before && { ...before }, time };
    this.place(viewer.name, name, uv);
    this.wb.selectNextLandmark(viewer.name, name);
  }

  /** A double-click fits the view; its first click placed a landmark, which is undone here
   * (restored where it was, or removed), so double-clicking never leaves a stray landmark. */
  doubleClick(viewer, uv, ev) {
    const last = this.lastClick;
    this.lastClick = null;
    if (last && last.view === viewer.name && ev.timeStamp - last.time < DOUBLE_CLICK_MS) {
      const { view, name, before } = last;
      this.wb.edit(async () => {
        const va = before
          ? await api.putLandmark(view, name, before.uv, before.sigma_px)
          : await api.deleteLandmark(view, name);
        this.wb.setViewAnnotations(view, va);
      });
      this.wb.selectLandmark(name);
    }
    return false; // the viewer fits
  }

  /** PUT the landmark (snapped first if the snap toggle is on); keeps a placed one's sigma. */
  place(view, name, uv) {
    this.wb.edit(async () => {
      let target = uv;
      if (this.wb.snap) {
        const snapped = await api.snap(view, round2(uv));
        target = snapped.uv;
      }
      const old = this.wb.viewAnnotations(view).landmarks[name];
      const sigma = old ? old.sigma_px : this.wb.sigma;
      const va = await api.putLandmark(view, name, round2(target), sigma);
      this.wb.setViewAnnotations(view, va);
      this.wb.status(`${view}: ${name} at (${round2(target).join(", ")})`);
    });
  }

  /** Delete key: the selected landmark in the active view. */
  deleteSelected() {
    const view = this.wb.activeView;
    const name = this.wb.selectedLandmark;
    if (!view || !name || !this.wb.viewAnnotations(view).landmarks[name]) return;
    this.wb.removeLandmark(view, name);
  }

  cancel() {}
}

export class OutlineTool {
  constructor(wb) {
    this.wb = wb;
    this.reset();
    this.timer = 0;
    this.inflight = null; // AbortController of the preview request in flight
    this.seq = 0; // answers to older previews are dropped
  }

  /** The outline being traced (drawn by overlay.drawTrace). */
  reset() {
    this.trace = { view: null, anchors: [], segments: [], preview: null, cursor: null };
    this.busy = false;
  }

  tracing() {
    return this.trace.anchors.length > 0;
  }

  click(viewer, uv, ev, count) {
    // The second click of a double-click finishes (doubleClick), it adds no anchor.
    if (count > 1 || this.busy) return;
    const t = this.trace;
    if (t.view && t.view !== viewer.name) {
      this.wb.status(`Finish (Enter) or cancel (Esc) the outline in ${t.view} first.`);
      return;
    }
    // Not tracing: a click on a contour selects it (Shift-click starts an outline anyway).
    if (!this.tracing() && !ev.shiftKey) {
      const index = this.hitContour(viewer, uv);
      this.wb.selectContour(index < 0 ? null : { view: viewer.name, index });
      if (index >= 0) return;
    }
    const refused = this.refuseAnchor(viewer, uv);
    if (refused) {
      this.wb.status(refused);
      return;
    }
    this.addAnchor(viewer.name, uv);
  }

  /** Why an anchor at uv would make the outline run over itself (null: it would not): the
   * same point as the last anchor, or a point on the outline traced so far (going back along
   * it). Near the first anchor is allowed (an outline may come round to where it began). */
  refuseAnchor(viewer, uv) {
    const t = this.trace;
    const n = t.anchors.length;
    if (!n) return null;
    const [x, y] = viewer.toCanvas(...uv);
    const [lx, ly] = viewer.toCanvas(...t.anchors[n - 1]);
    if (Math.hypot(x - lx, y - ly) < SAME_ANCHOR_PX) return "That anchor is placed already.";
    const [fx, fy] = viewer.toCanvas(...t.anchors[0]);
    if (n >= 3 && Math.hypot(x - fx, y - fy) <= CONTOUR_HIT_PX) return null;
    for (let i = 0; i < n - 1; i++) {
      const path = t.segments[i] ?? [t.anchors[i], t.anchors[i + 1]];
      if (distanceToPolyline(viewer, x, y, path, false) < SAME_ANCHOR_PX) {
        return "That point is on the outline traced already: click further along the edge " +
          "(Backspace drops the last anchor, Esc cancels the outline).";
      }
    }
    return null;
  }

  /** Index of the contour of `viewer` nearest to uv within CONTOUR_HIT_PX, or -1. */
  hitContour(viewer, uv) {
    const [x, y] = viewer.toCanvas(...uv);
    let best = -1;
    let bestDist = CONTOUR_HIT_PX;
    this.wb.viewAnnotations(viewer.name).contours.forEach((c, i) => {
      const d = distanceToPolyline(viewer, x, y, c.uv, c.closed);
      if (d <= bestDist) {
        best = i;
        bestDist = d;
      }
    });
    return best;
  }

  addAnchor(view, uv) {
    this.dropPreview(); // a preview from the previous anchor must not arrive after this one
    const t = this.trace;
    t.view = view;
    t.anchors.push(round2(uv));
    t.segments.push(null);
    t.preview = null;
    const n = t.anchors.length;
    if (n >= 2) this.traceSegment(t, n - 2);
    this.wb.redraw();
  }

  /** The livewire path from anchor i to anchor i + 1, drawn until the outline is finished. */
  async traceSegment(t, i) {
    const [a, b] = [t.anchors[i], t.anchors[i + 1]];
    try {
      const res = await api.livewire(t.view, [a, b], false);
      // still the same two anchors (not undone and placed again meanwhile)?
      if (t === this.trace && t.anchors[i] === a && t.anchors[i + 1] === b) {
        t.segments[i] = res.uv;
        this.wb.redraw();
      }
    } catch (err) {
      this.wb.error(err);
    }
  }

  hover(viewer, uv) {
    const t = this.trace;
    if (!this.tracing() || t.view !== viewer.name || this.busy) return;
    t.cursor = uv;
    this.wb.redraw();
    clearTimeout(this.timer);
    this.timer = setTimeout(() => this.requestPreview(), PREVIEW_DELAY_MS);
  }

  /** Forget the pending / in-flight preview (its answer, if any, is ignored). */
  dropPreview() {
    clearTimeout(this.timer);
    this.inflight?.abort();
    this.seq += 1;
  }

  /** Livewire from the last anchor to the cursor; a newer request aborts an older one. */
  async requestPreview() {
    const t = this.trace;
    if (!this.tracing() || !t.cursor) return;
    this.inflight?.abort();
    const controller = new AbortController();
    this.inflight = controller;
    const seq = ++this.seq;
    const last = t.anchors[t.anchors.length - 1];
    try {
      const res = await api.livewire(t.view, [last, round2(t.cursor)], false, controller.signal);
      if (seq !== this.seq || t !== this.trace) return;
      t.preview = res.uv;
      this.wb.noteLivewire(res.seconds);
      this.wb.redraw();
    } catch (err) {
      if (err.name !== "AbortError") this.wb.error(err);
    }
  }

  doubleClick(viewer) {
    if (!this.tracing() || this.trace.view !== viewer.name) return false;
    this.finish();
    return true; // consumed: no fit
  }

  /** Enter / double-click: the livewire through all anchors becomes a saved contour. */
  finish() {
    const t = this.trace;
    if (this.busy || !this.tracing()) return;
    if (t.anchors.length < 2) {
      this.wb.status("An outline needs at least two anchors.");
      return;
    }
    this.busy = true;
    this.dropPreview();
    const closed = this.wb.closedOutline;
    this.wb.edit(async () => {
      try {
        // traced again on the server and cut by the view's exclusion zones (outline_tools.py)
        const out = await api.traceOutline(t.view, t.anchors, closed);
        this.reset();
        this.wb.setViewAnnotations(t.view, out.view);
        const n = out.view.contours[out.index].uv.length;
        const pieces = out.pieces > 1 ? `, cut by exclusion zones into ${out.pieces} pieces` : "";
        this.wb.status(`${t.view}: contour #${out.index} saved (${n} points${pieces})`);
      } finally {
        this.busy = false; // on an error the anchors stay, so Enter can retry
        this.wb.redraw();
      }
    });
  }

  /** Backspace: drop the last anchor. */
  undo() {
    const t = this.trace;
    if (this.busy || !this.tracing()) return;
    this.dropPreview();
    t.anchors.pop();
    t.segments.pop();
    // segments[i] runs from anchor i to i + 1: the new last anchor has none.
    if (t.segments.length) t.segments[t.segments.length - 1] = null;
    if (!t.anchors.length) this.reset();
    t.preview = null;
    this.wb.redraw();
  }

  /** Esc: forget the outline being traced. */
  cancel() {
    this.dropPreview();
    this.reset();
    this.wb.redraw();
  }

  /** Delete key: the selected contour. */
  deleteSelected() {
    const sel = this.wb.selectedContour;
    if (sel) this.wb.removeContour(sel.view, sel.index);
  }
}
