// overlay.js — drawing the annotations, the outline being traced and the registration result
// over a view. Everything is drawn in canvas CSS pixels (viewer.toCanvas), so line widths and
// labels keep their size at any zoom.

export const COLORS = {
  landmark: "#3ddc84", // placed landmarks (green, as in `annotate preview`)
  landmarkSelected: "#b8ffd6",
  contour: "#ffc94d", // annotated contours (amber)
  contourSelected: "#ffffff",
  trace: "#4fd1ff", // livewire segments between the anchors placed so far (cyan)
  preview: "#4fd1ff", // livewire preview to the cursor (cyan, dashed)
  anchor: "#ffffff",
  result: "#ff4fa3", // registered outline and landmarks (magenta)
};

const LABEL_FONT = "12px system-ui, sans-serif";

/** A polyline through image points, optionally closed. */
export function polyline(ctx, viewer, uv, { color, width = 1.5, closed = false, dash = [] }) {
  if (!uv || uv.length < 2) return;
  ctx.beginPath();
  uv.forEach(([u, v], i) => {
    const [x, y] = viewer.toCanvas(u, v);
    if (i === 0) ctx.moveTo(x, y);
    else ctx.lineTo(x, y);
  });
  if (closed) ctx.closePath();
  ctx.setLineDash(dash);
  ctx.lineWidth = width;
  ctx.strokeStyle = color;
  ctx.stroke();
  ctx.setLineDash([]);
}

/** Text with a dark halo, readable on bright and dark parts of a radiograph. */
export function label(ctx, text, x, y, color) {
  ctx.font = LABEL_FONT;
  ctx.lineWidth = 3;
  ctx.strokeStyle = "rgba(0, 0, 0, 0.85)";
  ctx.strokeText(text, x, y);
  ctx.fillStyle = color;
  ctx.fillText(text, x, y);
}

/** The annotated contours of one view; `selected` is the index of the selected one or -1;
 * `boxes` collects the label boxes drawn so far (labelPlace). */
export function drawContours(ctx, viewer, contours, selected, boxes = []) {
  contours.forEach((c, i) => {
    const isSel = i === selected;
    polyline(ctx, viewer, c.uv, {
      color: isSel ? COLORS.contourSelected : COLORS.contour,
      width: isSel ? 3 : 1.5,
      closed: c.closed,
    });
    const [x, y] = viewer.toCanvas(...c.uv[0]);
    const [lx, ly] = labelPlace(ctx, `#${i}`, x, y, boxes);
    label(ctx, `#${i}`, lx, ly, isSel ? COLORS.contourSelected : COLORS.contour);
  });
}

/** Placed landmarks: a cross, a 3-sigma circle (image scale) and the name, the names placed
 * so that they do not overlap each other (landmarks are often a few pixels apart). */
export function drawLandmarks(ctx, viewer, landmarks, selectedName, boxes = []) {
  for (const [name, lm] of Object.entries(landmarks)) {
    const [x, y] = viewer.toCanvas(...lm.uv);
    const isSel = name === selectedName;
    const color = isSel ? COLORS.landmarkSelected : COLORS.landmark;
    const r = 3 * (lm.sigma_px ?? 1) * viewer.zoom;
    ctx.lineWidth = isSel ? 2.5 : 1.5;
    ctx.strokeStyle = color;
    ctx.beginPath();
    ctx.moveTo(x - 7, y);
    ctx.lineTo(x + 7, y);
    ctx.moveTo(x, y - 7);
    ctx.lineTo(x, y + 7);
    ctx.stroke();
    if (r > 3) {
      ctx.beginPath();
      ctx.arc(x, y, r, 0, 2 * Math.PI);
      ctx.setLineDash([3, 3]);
      ctx.stroke();
      ctx.setLineDash([]);
    }
    const [lx, ly] = labelPlace(ctx, name, x, y, boxes);
    label(ctx, name, lx, ly, color);
  }
}

/** A label position near (x, y) whose box misses the boxes already used (greedy, 8 tries). */
export function labelPlace(ctx, text, x, y, boxes) {
  ctx.font = LABEL_FONT;
  const w = ctx.measureText(text).width;
  const h = 12;
  const tries = [
    [8, -8], [8, 16], [-8 - w, -8], [-8 - w, 16], [8, -22], [8, 30], [-8 - w, -22], [-8 - w, 30],
  ];
  for (const [dx, dy] of tries) {
    const box = [x + dx, y + dy - h, x + dx + w, y + dy + 2];
    if (!boxes.some((b) => box[0] < b[2] && b[0] < box[2] && box[1] < b[3] && b[1] < box[3])) {
      boxes.push(box);
      return [x + dx, y + dy];
    }
  }
  return [x + tries[0][0], y + tries[0][1]];
}

/** The registered model: its outline polylines and its landmark vertices projected (an X),
 * each joined to the clicked landmark of the same name by its residual (a thin line). */
export function drawResult(ctx, viewer, result, landmarks) {
  if (!result) return;
  (result.outline_px || []).forEach((line, i) => {
    const closed = Boolean(result.outline_closed?.[i]);
    polyline(ctx, viewer, line, { color: COLORS.result, width: 1.5, closed });
  });
  for (const [name, uv] of Object.entries(result.landmarks_px || {})) {
    const [x, y] = viewer.toCanvas(...uv);
    const clicked = landmarks[name];
    if (clicked) polyline(ctx, viewer, [clicked.uv, uv], { color: COLORS.result, width: 1 });
    ctx.strokeStyle = COLORS.result;
    ctx.lineWidth = 2;
    ctx.beginPath(); // an X, to tell it from the clicked landmark's +
    ctx.moveTo(x - 5, y - 5);
    ctx.lineTo(x + 5, y + 5);
    ctx.moveTo(x - 5, y + 5);
    ctx.lineTo(x + 5, y - 5);
    ctx.stroke();
  }
}

/** Names of the registered landmarks that were not clicked in this view (drawn last, so the
 * clicked landmarks' names keep their places). */
export function drawResultLabels(ctx, viewer, result, landmarks, boxes = []) {
  for (const [name, uv] of Object.entries(result?.landmarks_px || {})) {
    if (landmarks[name]) continue;
    const [x, y] = viewer.toCanvas(...uv);
    const [lx, ly] = labelPlace(ctx, name, x, y, boxes);
    label(ctx, name, lx, ly, COLORS.result);
  }
}

/** The outline being traced: committed segments, the preview to the cursor, the anchors. */
export function drawTrace(ctx, viewer, trace) {
  for (const seg of trace.segments) {
    if (seg) polyline(ctx, viewer, seg, { color: COLORS.trace, width: 2 });
  }
  const last = trace.anchors[trace.anchors.length - 1];
  if (last && trace.cursor) {
    if (trace.preview) {
      polyline(ctx, viewer, trace.preview, { color: COLORS.preview, width: 2, dash: [6, 3] });
    } else {
      // straight dashed line until the livewire preview arrives
      const straight = { color: COLORS.preview, width: 1, dash: [2, 4] };
      polyline(ctx, viewer, [last, trace.cursor], straight);
    }
  }
  ctx.fillStyle = COLORS.anchor;
  ctx.strokeStyle = "#000";
  ctx.lineWidth = 1;
  for (const [u, v] of trace.anchors) {
    const [x, y] = viewer.toCanvas(u, v);
    ctx.fillRect(x - 3, y - 3, 6, 6);
    ctx.strokeRect(x - 3, y - 3, 6, 6);
  }
}

/** Distance (canvas px) from canvas point (x, y) to a polyline through image points. */
export function distanceToPolyline(viewer, x, y, uv, closed) {
  let best = Infinity;
  const n = uv.length;
  const last = closed ? n : n - 1;
  for (let i = 0; i < last; i++) {
    const [ax, ay] = viewer.toCanvas(...uv[i]);
    const [bx, by] = viewer.toCanvas(...uv[(i + 1) % n]);
    best = Math.min(best, segmentDistance(x, y, ax, ay, bx, by));
  }
  return best;
}

function segmentDistance(px, py, ax, ay, bx, by) {
  const dx = bx - ax;
  const dy = by - ay;
  const len2 = dx * dx + dy * dy;
  const t = len2 ? Math.max(0, Math.min(1, ((px - ax) * dx + (py - ay) * dy) / len2)) : 0;
  return Math.hypot(px - ax - t * dx, py - ay - t * dy);
}
