// warnings.js — the registration's warnings placed where they belong: a badge in the bar of
// a view whose outline is one-sided (which border is untraced), a marker on a landmark's chip
// and a ring at its clicked position for a landmark that disagrees with the outlines or was
// rejected. The server sends them structured (GET /api/result: views[v].warnings, jobs.py).

const COLORS = { disagrees: "#ffb020", rejected: "#ff5252" };

/** The warnings of `view` in the result, or null. */
export function viewWarnings(result, view) {
  return result?.views?.[view]?.warnings ?? null;
}

/** The warnings of landmark `name` in `view` ([{kind, text, px?}], possibly empty). */
export function landmarkWarnings(result, view, name) {
  return viewWarnings(result, view)?.landmarks?.[name] ?? [];
}

/** A chip's marker: "!" coloured by the worst warning, its text as the title. */
export function chipMarker(result, view, name) {
  const items = landmarkWarnings(result, view, name);
  if (!items.length) return null;
  const kind = items.some((w) => w.kind === "rejected") ? "rejected" : "disagrees";
  const mark = document.createElement("span");
  mark.className = `lm-warn ${kind}`;
  mark.dataset.testid = `lm-warn-${name}-${view}`;
  mark.textContent = "!";
  mark.title = items.map((w) => `${name} in ${view}: ${w.text}`).join("\n");
  return mark;
}

/** The badge in each view's bar (one-sided outline), re-made for each result. */
export function renderViewBadges(result) {
  for (const box of document.querySelectorAll("#views .view")) {
    box.querySelector(".warn-badge")?.remove();
    const outline = viewWarnings(result, box.dataset.view)?.outline;
    if (!outline) continue;
    const badge = document.createElement("span");
    badge.className = "warn-badge";
    badge.dataset.testid = `warn-badge-${box.dataset.view}`;
    badge.dataset.untraced = outline.untraced ?? "";
    const arrow = { left: "◀", right: "▶", top: "▲", bottom: "▼" }[outline.untraced] ?? "!";
    badge.textContent = `${arrow} one-sided outline`;
    badge.title =
      `${outline.text}: trace the other border too (the fit slides along the bone ` +
      "where only one side is traced)";
    box.querySelector(".view-name").after(badge);
  }
}

/** Over the image: a ring and "!" at each warned landmark's clicked position, and an edge bar
 * on the side of the view where the outline is untraced. */
export function drawWarnings(ctx, viewer, result, landmarks) {
  const w = viewWarnings(result, viewer.name);
  if (!w) return;
  for (const [name, items] of Object.entries(w.landmarks || {})) {
    const clicked = landmarks[name];
    if (!clicked || !items.length) continue;
    const kind = items.some((i) => i.kind === "rejected") ? "rejected" : "disagrees";
    const [x, y] = viewer.toCanvas(...clicked.uv);
    ctx.strokeStyle = COLORS[kind];
    ctx.lineWidth = 2;
    ctx.setLineDash([4, 3]);
    ctx.beginPath();
    ctx.arc(x, y, 14, 0, 2 * Math.PI);
    ctx.stroke();
    ctx.setLineDash([]);
    ctx.fillStyle = COLORS[kind];
    ctx.font = "bold 13px system-ui, sans-serif";
    ctx.fillText("!", x + 11, y - 10);
  }
  if (w.outline) drawEdgeBar(ctx, w.outline.untraced);
}

function drawEdgeBar(ctx, side) {
  const { width, height } = ctx.canvas;
  const dpr = window.devicePixelRatio || 1;
  const t = 5 * dpr;
  const rect = {
    left: [0, 0, t, height], right: [width - t, 0, t, height],
    top: [0, 0, width, t], bottom: [0, height - t, width, t],
  }[side];
  if (!rect) return;
  ctx.save();
  ctx.setTransform(1, 0, 0, 1, 0, 0); // device pixels: the bar hugs the canvas edge
  ctx.fillStyle = "rgba(255, 176, 32, 0.55)";
  ctx.fillRect(...rect);
  ctx.restore();
}

/** The start the result was registered from, one line (or ""). */
export function startText(result) {
  return result?.start?.text ?? "";
}
