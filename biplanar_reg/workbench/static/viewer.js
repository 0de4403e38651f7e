// viewer.js — one radiograph view: a <canvas> that draws the image pyramid's tiles at the level
// that fits the zoom, plus overlays; wheel zooms about the cursor, drag pans, double-click fits.
//
// Coordinates: image pixels (u, v) = (column, row), 0-based, origin at the CENTRE of the top-left
// pixel (docs/annotation.md), so pixel i covers u in [i - 0.5, i + 0.5]. The view transform maps
// image pixels to canvas CSS pixels: x = u * zoom + offX, y = v * zoom + offY.
//
// The viewer knows nothing about landmarks or outlines: pointer input goes to a `handler`
// (the current tool, see tools.js) and overlays are drawn by a `drawOverlay` callback.

import { TileCache } from "./tiles.js";

const MAX_ZOOM = 40; // screen pixels per image pixel
const MIN_ZOOM_OF_FIT = 0.25; // how far out one may zoom, relative to "fit"
const CLICK_SLOP_PX = 4; // a press that moves less than this is a click, not a drag
const WHEEL_RATE = 0.0015; // zoom factor per wheel delta pixel: exp(-delta * rate)
const MULTI_CLICK_MS = 500; // clicks this close in time (and CLICK_SLOP_PX in space) count up

export class Viewer {
  /**
   * @param {HTMLCanvasElement} canvas
   * @param {object} info the view's entry of GET /api/case
   * @param {object} hooks {tileUrl(level, tx, ty, lo, hi), handler, drawOverlay(ctx, viewer),
   *   onCursor(viewer, uv|null)}
   */
  constructor(canvas, info, hooks) {
    this.canvas = canvas;
    this.ctx = canvas.getContext("2d");
    // A view without an image may not even know its size: a placeholder frame then.
    this.info = { ...info, width: info.width || 1000, height: info.height || 1000 };
    this.name = info.name;
    this.hooks = hooks;
    this.zoom = 1;
    this.offX = 0;
    this.offY = 0;
    this.fitted = false;
    this.userMoved = false; // until the user zooms or pans, a resize re-fits the image
    this.window = info.window ? [...info.window] : [0, 1];
    this.clahe = false; // CLAHE-equalised tiles (display only, window.js)
    this.previousDisplay = null; // {window, clahe}: its tiles stand in while new ones load
    this.windowDrag = null; // fn(dx, dy) of a right-drag (window.js); without it: pan
    this.override = null; // a handler that takes the pointer from the tool (e.g. a box)
    this.tiles = new TileCache(() => this.redraw());
    this.press = null; // the pointer press in progress: {x, y, mode: "click"|"pan"|"tool"}
    this.lastClick = null; // {time, x, y, count}: pointer events carry no click count
    this.frame = 0;
    this.listen();
    new ResizeObserver(() => this.resize()).observe(canvas);
    this.resize();
  }

  // ---- transform -------------------------------------------------------------------------

  /** Canvas CSS pixels -> image pixels. */
  toView(x, y) {
    return [(x - this.offX) / this.zoom, (y - this.offY) / this.zoom];
  }

  /** Image pixels -> canvas CSS pixels. */
  toCanvas(u, v) {
    return [u * this.zoom + this.offX, v * this.zoom + this.offY];
  }

  /** Image pixels -> page (client) coordinates, e.g. for scripted mouse clicks. */
  toClient(u, v) {
    const rect = this.canvas.getBoundingClientRect();
    const [x, y] = this.toCanvas(u, v);
    return [rect.left + x, rect.top + y];
  }

  /** Show the image rectangle [u0, u1] x [v0, v1] (image pixels) as large as fits. */
  fitRect(u0, v0, u1, v1) {
    const w = this.canvas.clientWidth;
    const h = this.canvas.clientHeight;
    if (!w || !h) return;
    const zoom = 0.98 * Math.min(w / (u1 - u0), h / (v1 - v0));
    this.zoom = Math.min(MAX_ZOOM, zoom);
    this.offX = w / 2 - ((u0 + u1) / 2) * this.zoom;
    this.offY = h / 2 - ((v0 + v1) / 2) * this.zoom;
    this.fitted = true;
    this.changed();
  }

  /** The whole image. */
  fit() {
    this.fitRect(-0.5, -0.5, this.info.width - 0.5, this.info.height - 0.5);
    this.userMoved = false;
  }

  /** Pan so that image point (u, v) is in the middle (the zoom stays). */
  centreOn(u, v) {
    this.offX = this.canvas.clientWidth / 2 - u * this.zoom;
    this.offY = this.canvas.clientHeight / 2 - v * this.zoom;
    this.userMoved = true;
    this.changed();
  }

  fitZoom() {
    const w = this.canvas.clientWidth || 1;
    const h = this.canvas.clientHeight || 1;
    return 0.98 * Math.min(w / this.info.width, h / this.info.height);
  }

  /** Multiply the zoom by `factor`, keeping the image point under canvas point (x, y) fixed. */
  zoomAbout(x, y, factor) {
    const [u, v] = this.toView(x, y);
    const lo = MIN_ZOOM_OF_FIT * this.fitZoom();
    this.zoom = Math.min(MAX_ZOOM, Math.max(lo, this.zoom * factor));
    this.offX = x - u * this.zoom;
    this.offY = y - v * this.zoom;
    this.userMoved = true;
    this.changed();
  }

  panBy(dx, dy) {
    this.offX += dx;
    this.offY += dy;
    this.userMoved = true;
    this.changed();
  }

  /** The view state moved: expose it for tests (data-zoom, data-level) and redraw. */
  changed() {
    this.canvas.dataset.zoom = this.zoom.toFixed(5);
    this.canvas.dataset.level = String(this.level());
    this.redraw();
  }

  // ---- window / level --------------------------------------------------------------------

  /** Display window in raw image units; tiles are re-requested for the new mapping. */
  setWindow(lo, hi) {
    if (!(hi > lo)) return;
    this.keepDisplay();
    this.window = [lo, hi];
    this.redraw();
  }

  /** CLAHE-equalised tiles on or off (the window stays). */
  setClahe(on) {
    if (on === this.clahe) return;
    this.keepDisplay();
    this.clahe = on;
    this.redraw();
  }

  /** Before the display changes: its tiles stand in while the new ones load, if it has at
   * least its backdrop (while dragging the window, an older display may be the last one). */
  keepDisplay() {
    if (!this.info.has_image) return;
    const [lo, hi] = this.window.map(roundWindow);
    const backdrop = this.hooks.tileUrl(this.info.levels - 1, 0, 0, lo, hi, this.clahe);
    if (!this.previousDisplay || this.tiles.peek(backdrop)) {
      this.previousDisplay = { window: this.window, clahe: this.clahe };
    }
  }

  /** Where pointer input goes: an override (e.g. window.js's box) or the current tool. */
  handler() {
    return this.override ?? this.hooks.handler();
  }

  // ---- drawing ---------------------------------------------------------------------------

  /** Pyramid level for the current zoom: the coarsest one that still has >= 1 image pixel per
   * device pixel (level k = 1/2^k of full resolution). */
  level() {
    const devicePerImage = this.zoom * (window.devicePixelRatio || 1);
    const k = Math.floor(Math.log2(1 / devicePerImage));
    return Math.max(0, Math.min(this.info.levels - 1, k));
  }

  /** Schedule one redraw on the next animation frame (many events -> one draw). */
  redraw() {
    if (this.frame) return;
    this.frame = requestAnimationFrame(() => {
      this.frame = 0;
      this.draw();
    });
  }

  resize() {
    const dpr = window.devicePixelRatio || 1;
    const w = this.canvas.clientWidth;
    const h = this.canvas.clientHeight;
    if (!w || !h) return;
    if (this.fitted && this.userMoved) {
      // keep the image point at the centre where it was
      const [cu, cv] = this.toView(this.canvas.width / dpr / 2, this.canvas.height / dpr / 2);
      this.offX = w / 2 - cu * this.zoom;
      this.offY = h / 2 - cv * this.zoom;
    }
    this.canvas.width = Math.round(w * dpr);
    this.canvas.height = Math.round(h * dpr);
    if (!this.userMoved) this.fit();
    else this.changed();
  }

  draw() {
    const ctx = this.ctx;
    const dpr = window.devicePixelRatio || 1;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.fillStyle = "#0b0d10";
    ctx.fillRect(0, 0, this.canvas.width, this.canvas.height);
    if (this.info.has_image) {
      // The coarsest level (one tile) first, as a backdrop while finer tiles load.
      const coarsest = this.info.levels - 1;
      this.drawLevel(ctx, coarsest);
      const k = this.level();
      if (k < coarsest) this.drawLevel(ctx, k);
    } else {
      this.drawNoImage(ctx);
    }
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    this.hooks.drawOverlay(ctx, this);
  }

  drawLevel(ctx, k) {
    const dpr = window.devicePixelRatio || 1;
    const { width, height, tile_size: ts } = this.info;
    const s = 2 ** k; // image pixels per level-k pixel
    const span = ts * s; // image pixels per tile
    const nx = Math.ceil(Math.ceil(width / s) / ts);
    const ny = Math.ceil(Math.ceil(height / s) / ts);
    const [u0, v0] = this.toView(0, 0);
    const [u1, v1] = this.toView(this.canvas.clientWidth, this.canvas.clientHeight);
    const tx0 = Math.max(0, Math.floor((u0 + 0.5) / span));
    const ty0 = Math.max(0, Math.floor((v0 + 0.5) / span));
    const tx1 = Math.min(nx - 1, Math.floor((u1 + 0.5) / span));
    const ty1 = Math.min(ny - 1, Math.floor((v1 + 0.5) / span));
    // Draw in image-pixel units; pixels stay crisp (no smoothing) once zoomed in past 2x, so
    // the annotator sees the real pixels rather than a blur.
    ctx.setTransform(dpr * this.zoom, 0, 0, dpr * this.zoom, dpr * this.offX, dpr * this.offY);
    ctx.imageSmoothingEnabled = this.zoom * s < 2;
    for (let ty = ty0; ty <= ty1; ty++) {
      for (let tx = tx0; tx <= tx1; tx++) {
        const img = this.tile(k, tx, ty);
        if (!img) continue;
        // A level-k pixel j covers image pixels [j s, (j + 1) s), i.e. u in [j s - 0.5, ...).
        ctx.drawImage(img, tx * span - 0.5, ty * span - 0.5, img.naturalWidth * s,
          img.naturalHeight * s);
      }
    }
  }

  /** The tile for the current window, else the previous window's while the new one loads. */
  tile(k, tx, ty) {
    const [lo, hi] = this.window.map(roundWindow);
    const img = this.tiles.get(this.hooks.tileUrl(k, tx, ty, lo, hi, this.clahe));
    const prev = this.previousDisplay;
    if (img || !prev) return img;
    const [plo, phi] = prev.window.map(roundWindow);
    return this.tiles.peek(this.hooks.tileUrl(k, tx, ty, plo, phi, prev.clahe));
  }

  drawNoImage(ctx) {
    const dpr = window.devicePixelRatio || 1;
    ctx.setTransform(dpr, 0, 0, dpr, 0, 0);
    const [x0, y0] = this.toCanvas(-0.5, -0.5);
    const [x1, y1] = this.toCanvas(this.info.width - 0.5, this.info.height - 0.5);
    ctx.strokeStyle = "#556";
    ctx.strokeRect(x0, y0, x1 - x0, y1 - y0);
    ctx.fillStyle = "#aab";
    ctx.font = "14px system-ui, sans-serif";
    ctx.fillText("no image for this view", x0 + 10, y0 + 24);
  }

  // ---- input -----------------------------------------------------------------------------

  /** Pointer position relative to the canvas, in CSS pixels. */
  local(ev) {
    const rect = this.canvas.getBoundingClientRect();
    return [ev.clientX - rect.left, ev.clientY - rect.top];
  }

  listen() {
    const c = this.canvas;
    c.addEventListener("wheel", (ev) => this.onWheel(ev), { passive: false });
    c.addEventListener("pointerdown", (ev) => this.onDown(ev));
    c.addEventListener("pointermove", (ev) => this.onMove(ev));
    c.addEventListener("pointerup", (ev) => this.onUp(ev));
    c.addEventListener("pointercancel", () => {
      this.press = null;
    });
    c.addEventListener("pointerleave", () => this.hooks.onCursor(this, null));
    c.addEventListener("dblclick", (ev) => this.onDoubleClick(ev));
    c.addEventListener("contextmenu", (ev) => ev.preventDefault());
  }

  onWheel(ev) {
    ev.preventDefault(); // the page must not scroll while zooming
    // Wheel events carry whole-pixel coordinates, pointer events fractional ones: zoom about
    // the last pointer position when it is the same place, so the point under it stays put.
    let [x, y] = this.local(ev);
    const p = this.lastPointer;
    if (p && Math.abs(p[0] - x) <= 1 && Math.abs(p[1] - y) <= 1) [x, y] = p;
    const delta = ev.deltaMode === 1 ? ev.deltaY * 16 : ev.deltaY; // lines -> pixels
    this.zoomAbout(x, y, Math.exp(-delta * WHEEL_RATE));
  }

  onDown(ev) {
    const [x, y] = this.local(ev);
    this.canvas.setPointerCapture(ev.pointerId);
    // Middle button: always pan; right: window/level (window.js), else pan. Left: the tool
    // may claim the press (e.g. to drag a landmark); otherwise a click, or a pan once it moves.
    let mode = ev.button === 0 ? "click" : "pan";
    if (ev.button === 2 && this.windowDrag) mode = "window";
    if (mode === "click" && this.handler().pointerDown?.(this, this.toView(x, y), ev)) {
      mode = "tool";
    }
    this.press = { x, y, lastX: x, lastY: y, mode };
  }

  onMove(ev) {
    const [x, y] = this.local(ev);
    this.lastPointer = [x, y];
    const uv = this.toView(x, y);
    this.hooks.onCursor(this, uv);
    const p = this.press;
    if (!p) {
      this.handler().hover?.(this, uv, ev);
      return;
    }
    if (p.mode === "click" && Math.hypot(x - p.x, y - p.y) > CLICK_SLOP_PX) p.mode = "pan";
    if (p.mode === "pan") this.panBy(x - p.lastX, y - p.lastY);
    if (p.mode === "window") this.windowDrag(x - p.lastX, y - p.lastY);
    if (p.mode === "tool") this.handler().drag?.(this, uv, ev);
    p.lastX = x;
    p.lastY = y;
  }

  onUp(ev) {
    const p = this.press;
    this.press = null;
    if (!p) return;
    const [x, y] = this.local(ev);
    const uv = this.toView(x, y);
    // Only a press that stayed put is a click (a pan or a drag resets the count).
    const still = Math.hypot(x - p.x, y - p.y) <= CLICK_SLOP_PX;
    const count = still ? this.clickCount(ev.timeStamp, x, y) : 0;
    if (!still) this.lastClick = null;
    if (p.mode === "click") this.handler().click?.(this, uv, ev, count);
    if (p.mode === "tool") this.handler().drop?.(this, uv, ev, count);
  }

  /** 1 for a single click, 2 for the second click of a double-click, ... (the `detail` of
   * pointer events is always 0, so the tools get the count from here). */
  clickCount(time, x, y) {
    const last = this.lastClick;
    const near = last && Math.hypot(x - last.x, y - last.y) < CLICK_SLOP_PX;
    const again = near && time - last.time < MULTI_CLICK_MS;
    const count = again ? last.count + 1 : 1;
    this.lastClick = { time, x, y, count };
    return count;
  }

  onDoubleClick(ev) {
    this.lastClick = null; // the next click starts a new count
    const uv = this.toView(...this.local(ev));
    if (!this.handler().doubleClick?.(this, uv, ev)) this.fit();
  }
}

/** Window bounds in tile URLs: rounded so that cache keys repeat. */
function roundWindow(x) {
  return Number(x.toPrecision(6));
}
