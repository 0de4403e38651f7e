// epipolar.js — cross-view guides: the epipolar curve of the cursor, of the selected landmark
// and (fainter) of each landmark placed in another view but not yet in this one, in every
// other view (for pinhole views a line; for orthographic, slot-scanning
// and distorted views their analogue: the server projects the pixel's ray, view_aids.py).
//
// The cursor's curves follow the mouse with at most one request in flight: while one is
// answered the newest position waits, older ones are dropped. The selected landmark's curves
// are asked once per position and kept. `E` (or the "epipolar" box) turns them on and off.

import { request } from "./api.js";
import { label, polyline } from "./overlay.js";

const enc = encodeURIComponent;
const CURSOR_COLOR = "#ffe066"; // the cursor's curve: yellow, dashed
const LANDMARK_COLOR = "#3ddc84"; // the selected landmark's: the landmarks' green, solid
const PENDING_COLOR = "rgba(61, 220, 132, 0.55)"; // placed elsewhere, not yet here: fainter
const CACHE_SIZE = 64; // landmark curves kept

/** Keyboard shortcuts of this module (for the page's shortcut list): key, help, action. */
export const EPIPOLAR_SHORTCUTS = [
  { key: "E", help: "epipolar lines of the cursor and the selected landmark on/off",
    run: (wb) => wb.epipolar?.setOn(!wb.epipolar.on) },
];

export class EpipolarGuide {
  /** @param {object} wb the page state; @param {HTMLInputElement|null} box its checkbox */
  constructor(wb, box) {
    this.wb = wb;
    this.box = box;
    this.on = true;
    this.cursor = null; // {view, uv, curves: {view: [polyline, ...]}}
    this.pending = null; // the newest cursor position waiting for a request: {view, uv}
    this.inFlight = false;
    this.generation = 0; // bumped when the cursor leaves: late answers are dropped
    this.landmarks = new Map(); // "view|u|v" -> curves, or null while asked
    this.seconds = []; // the server's time of each cursor request (tests, the status line)
    box?.addEventListener("change", () => {
      this.setOn(box.checked);
      box.blur(); // the page's shortcuts work again at once
    });
  }

  setOn(on) {
    this.on = on;
    if (this.box) this.box.checked = on;
    document.body.dataset.epipolar = String(on);
    if (!on) {
      this.cursor = null;
      this.pending = null;
    }
    this.wb.redraw();
    this.wb.status(`epipolar lines ${on ? "on" : "off"} (E)`);
  }

  // ---- the cursor ------------------------------------------------------------------------

  /** The cursor moved to `uv` in `viewer` (null: it left the view). */
  onCursor(viewer, uv) {
    if (!this.on) return;
    if (!uv) {
      this.generation += 1;
      this.pending = null;
      if (this.cursor) {
        this.cursor = null;
        this.wb.redraw();
      }
      return;
    }
    const { width, height } = viewer.info;
    if (!viewer.info.has_image || uv[0] < -0.5 || uv[1] < -0.5 || uv[0] > width - 0.5 ||
        uv[1] > height - 0.5) {
      return; // off the image: the last curves stay
    }
    this.pending = { view: viewer.name, uv: [uv[0], uv[1]] };
    this.pump();
  }

  async pump() {
    if (this.inFlight || !this.pending) return;
    const want = this.pending;
    const generation = this.generation;
    this.pending = null;
    this.inFlight = true;
    try {
      const res = await fetchCurves(want.view, want.uv);
      this.seconds.push(res.seconds);
      if (generation === this.generation && this.on) {
        this.cursor = { view: want.view, uv: want.uv, curves: res.curves };
        this.wb.redraw();
      }
    } catch (err) {
      this.wb.error(err);
    } finally {
      this.inFlight = false;
      this.pump();
    }
  }

  // ---- the selected landmark -------------------------------------------------------------

  /** [{view, name, curves, selected}] to draw in `target`: the selected landmark's curves
   * from the views where it is placed, and those of the landmarks placed in another view but
   * not yet in `target` (the ones to find there). Asks for the curves not known yet. */
  landmarkCurves(target) {
    const sel = this.wb.selectedLandmark;
    const here = this.wb.viewAnnotations(target).landmarks;
    const out = [];
    for (const { name: view } of this.wb.caseInfo.views) {
      if (view === target) continue;
      for (const [name, lm] of Object.entries(this.wb.viewAnnotations(view).landmarks)) {
        if (name !== sel && here[name]) continue;
        const key = `${view}|${lm.uv[0]}|${lm.uv[1]}`;
        if (!this.landmarks.has(key)) this.ask(key, view, lm.uv);
        const curves = this.landmarks.get(key);
        if (curves) out.push({ view, name, curves, selected: name === sel });
      }
    }
    return out.sort((a, b) => Number(a.selected) - Number(b.selected)); // selected on top
  }

  ask(key, view, uv) {
    this.landmarks.set(key, null);
    while (this.landmarks.size > CACHE_SIZE) this.landmarks.delete(this.landmarks.keys().next().value);
    fetchCurves(view, uv)
      .then((res) => {
        this.landmarks.set(key, res.curves);
        this.wb.redraw();
      })
      .catch((err) => {
        this.landmarks.delete(key);
        this.wb.error(err);
      });
  }

  // ---- drawing ---------------------------------------------------------------------------

  draw(ctx, viewer) {
    if (!this.on) return;
    for (const { view, name, curves, selected } of this.landmarkCurves(viewer.name)) {
      const pieces = curves[viewer.name] ?? [];
      const color = selected ? LANDMARK_COLOR : PENDING_COLOR;
      for (const line of pieces) polyline(ctx, viewer, line, { color, width: selected ? 2 : 1.25 });
      const first = pieces[0]?.[0];
      if (first) {
        const [x, y] = viewer.toCanvas(...first);
        label(ctx, `${name} (${view})`, Math.max(4, Math.min(x + 6, viewer.canvas.clientWidth - 140)),
          Math.max(14, y + 14), color);
      }
    }
    const c = this.cursor;
    if (c && c.view !== viewer.name) {
      for (const line of c.curves[viewer.name] ?? []) {
        polyline(ctx, viewer, line, { color: CURSOR_COLOR, width: 1.25, dash: [7, 4] });
      }
    }
  }
}

function fetchCurves(view, uv) {
  const [u, v] = uv.map((x) => x.toFixed(2));
  return request("GET", `api/views/${enc(view)}/epipolar?u=${u}&v=${v}`);
}

/** Put the guide in place: its overlay, the cursor hook and the `E` key (call once). */
export function installEpipolar(wb) {
  const guide = new EpipolarGuide(wb, document.getElementById("epipolar"));
  wb.epipolar = guide;
  wb.overlays.push((ctx, v) => guide.draw(ctx, v));
  const cursor = wb.cursor.bind(wb);
  wb.cursor = (viewer, uv) => {
    cursor(viewer, uv);
    guide.onCursor(viewer, uv);
  };
  document.body.dataset.epipolar = "true";
  return guide;
}
