// window.js — window/level of each view: level and width fields, right-drag on the image
// (horizontal: width, vertical: level, as in 3D Slicer), an automatic window from a box drawn
// on the image (the 1st-99th percentile of its raw pixels, from the server), a reset, and a
// CLAHE toggle (contrast-limited adaptive histogram equalisation, display only: the livewire
// traces on the image itself). Each view has its own settings, kept in the browser's
// localStorage per case and view, so that a reload shows the views as they were.
//
// The controls never keep the keyboard: buttons blur after a click, the fields after Enter,
// Esc or a change (so the page's shortcuts work at once after using them).

import { request } from "./api.js";
import { el } from "./dom.js";

const enc = encodeURIComponent;
const DRAG_RATE = 0.004; // fraction of the raw range per screen pixel of a right-drag
const THROTTLE_MS = 100; // a right-drag asks for new tiles at most this often

/** Keyboard shortcuts of this module (merged into the page's shortcut list). */
export const WINDOW_SHORTCUTS = [
  { key: "right-drag", help: "window/level: horizontal width, vertical level" },
];


/** A window bound for display: whole numbers for 8/16-bit data, 4 digits otherwise. */
export function fmt(x) {
  return Math.abs(x) >= 100 || Number.isInteger(x) ? x.toFixed(0) : x.toPrecision(4);
}

/** The per-view window/level controls of one viewer. */
export class WindowControls {
  /**
   * @param {object} wb the page state (status, error)
   * @param {Viewer} viewer
   * @param {HTMLElement} bar the view's title bar (controls are put in its `.window`)
   * @param {object} info the view's entry of GET /api/case
   */
  constructor(wb, viewer, bar, info) {
    this.wb = wb;
    this.viewer = viewer;
    this.info = info;
    this.range = info.range;
    this.key = `biplanar-wb:${wb.caseInfo.id}:${info.name}:window`;
    this.box = null; // the box being drawn: {start, end}
    this.armed = false; // the next left drag on the image draws the box
    this.escape = null; // the Esc listener while armed
    this.pending = null; // the window a right-drag moved to, not yet applied
    this.timer = 0;
    this.build(bar.querySelector(".window"));
    this.restore();
    viewer.windowDrag = (dx, dy) => this.dragWindow(dx, dy);
  }

  build(root) {
    const name = this.info.name;
    const field = (cls, label, title) => {
      const input = el("input", { type: "number", class: `wl-${cls}`, "data-testid": `window-${cls}-${name}`,
        "aria-label": `${label} of ${name}`, title, step: "any" });
      input.addEventListener("keydown", (ev) => {
        ev.stopPropagation(); // typing a number is not a shortcut
        if (ev.key === "Enter") {
          this.fromFields();
          input.blur();
        } else if (ev.key === "Escape") {
          this.showFields();
          input.blur();
        }
      });
      input.addEventListener("change", () => {
        this.fromFields();
        input.blur();
      });
      return input;
    };
    this.level = field("level", "level", "Window level (centre), raw image units; Enter applies");
    this.width = field("width", "width", "Window width, raw image units; Enter applies");
    const button = (cls, text, title, fn) => {
      const b = el("button", { class: `wl wl-${cls}`, "data-testid": `window-${cls}-${name}`, title }, text);
      b.addEventListener("click", () => {
        fn();
        b.blur();
      });
      return b;
    };
    this.autoButton = button("auto", "Auto", "Draw a box on the image: the window of its pixels (1st-99th percentile)",
      () => this.arm(!this.armed));
    this.resetButton = button("reset", "Reset", "The view's default window", () => this.reset());
    this.claheButton = button("clahe", "CLAHE",
      "Contrast-limited adaptive equalisation, for tracing faint edges (display only)",
      () => this.setClahe(!this.viewer.clahe));
    this.claheButton.setAttribute("aria-pressed", "false");
    root.replaceChildren("L", this.level, "W", this.width, this.autoButton, this.claheButton,
      this.resetButton);
    root.title = "Display window (raw image values); right-drag on the image: horizontal width, vertical level";
  }

  // ---- state ---------------------------------------------------------------------------

  /** Apply a window [lo, hi] (raw units), show it in the fields and remember it. */
  set(lo, hi) {
    if (!(hi > lo) || !Number.isFinite(lo) || !Number.isFinite(hi)) return;
    clearTimeout(this.timer);
    this.timer = 0;
    this.pending = null;
    this.viewer.setWindow(lo, hi);
    this.showFields();
    this.save();
  }

  /** During a right-drag: the fields follow at once, the tiles at most every THROTTLE_MS
   * (each window is a new set of tiles). */
  setSoon(lo, hi) {
    this.pending = [lo, hi];
    this.showFields();
    if (!this.timer) {
      this.timer = setTimeout(() => {
        this.timer = 0;
        if (this.pending) this.set(...this.pending);
      }, THROTTLE_MS);
    }
  }

  /** The window shown: the one being dragged to, else the viewer's. */
  current() {
    return this.pending ?? this.viewer.window;
  }

  showFields() {
    const [lo, hi] = this.current();
    this.level.value = fmt((lo + hi) / 2);
    this.width.value = fmt(hi - lo);
    this.viewer.canvas.dataset.window = `${lo},${hi}`;
  }

  fromFields() {
    const level = Number(this.level.value);
    const width = Number(this.width.value);
    if (!(width > 0) || !Number.isFinite(level)) {
      this.wb.status(`${this.info.name}: the window width must be a number > 0`);
      this.showFields();
      return;
    }
    this.set(level - width / 2, level + width / 2);
  }

  reset() {
    this.setClahe(false);
    this.set(...this.info.window);
  }

  setClahe(on) {
    this.viewer.setClahe(on);
    this.claheButton.setAttribute("aria-pressed", String(on));
    this.save();
  }

  save() {
    const [lo, hi] = this.viewer.window;
    try {
      localStorage.setItem(this.key, JSON.stringify({ lo, hi, clahe: this.viewer.clahe }));
    } catch {
      // private mode or full storage: the settings just do not survive a reload
    }
  }

  restore() {
    let saved = null;
    try {
      saved = JSON.parse(localStorage.getItem(this.key) || "null");
    } catch {
      saved = null;
    }
    if (saved && saved.hi > saved.lo) this.viewer.setWindow(saved.lo, saved.hi);
    if (saved?.clahe) this.setClahe(true);
    this.showFields();
  }

  // ---- right-drag ------------------------------------------------------------------------

  /** A right-drag moved (dx, dy) screen px: right widens, down lowers the level (brighter
   * image for bone dark on bright, as in Slicer). */
  dragWindow(dx, dy) {
    const [lo, hi] = this.current();
    const span = (this.range[1] - this.range[0]) || 1;
    const width = Math.max(span / 1000, hi - lo + dx * DRAG_RATE * span);
    const level = (lo + hi) / 2 - dy * DRAG_RATE * span;
    this.setSoon(level - width / 2, level + width / 2);
  }

  // ---- automatic window from a box -------------------------------------------------------

  arm(on) {
    if (on && !this.escape) {
      // Esc gives the image back to the tool (before the page's own Esc handling)
      this.escape = (ev) => {
        if (ev.key !== "Escape") return;
        ev.stopPropagation();
        ev.preventDefault();
        this.cancel();
      };
      document.addEventListener("keydown", this.escape, true);
    } else if (!on && this.escape) {
      document.removeEventListener("keydown", this.escape, true);
      this.escape = null;
    }
    this.armed = on;
    this.autoButton.setAttribute("aria-pressed", String(on));
    this.viewer.override = on ? this : null; // the next press on the image draws the box
    if (on) this.wb.status(`${this.info.name}: drag a box over the region to window (Esc cancels)`);
  }

  cancel() {
    this.box = null;
    this.arm(false);
    this.viewer.redraw();
  }

  pointerDown(viewer, uv) {
    this.box = { start: uv, end: uv };
    return true;
  }

  drag(viewer, uv) {
    if (this.box) this.box.end = uv;
    this.viewer.redraw();
  }

  drop(viewer, uv) {
    const box = this.box;
    this.cancel();
    if (!box) return;
    const [u0, v0] = box.start;
    const coords = [u0, v0, uv[0], uv[1]].map((x) => x.toFixed(1)).join(",");
    request("GET", `api/views/${enc(this.info.name)}/window?box=${coords}`)
      .then((res) => {
        this.set(...res.window);
        this.wb.status(`${this.info.name}: window ${fmt(res.window[0])}–${fmt(res.window[1])} ` +
          `from ${res.pixels} pixels`);
      })
      .catch((err) => this.wb.error(err));
  }

  /** The box being drawn (over the view's overlay). */
  draw(ctx, viewer) {
    if (!this.box) return;
    const [x0, y0] = viewer.toCanvas(...this.box.start);
    const [x1, y1] = viewer.toCanvas(...this.box.end);
    ctx.setLineDash([5, 3]);
    ctx.strokeStyle = "#ffe066";
    ctx.lineWidth = 1.5;
    ctx.strokeRect(Math.min(x0, x1), Math.min(y0, y1), Math.abs(x1 - x0), Math.abs(y1 - y0));
    ctx.setLineDash([]);
  }
}
