// markers.js — marker beads found on the radiographs (view_aids.py, annotation/markers.py),
// proposed as circular exclusion zones: drawn dashed over the views and listed in the outline
// panel, each accepted (✓: it becomes a zone that cuts the contours, as a Circle drawn by
// hand) or rejected (×), or all at once. Nothing is written until a proposal is accepted.

import { request } from "./api.js";
import { label } from "./overlay.js";
import { el } from "./dom.js";

const enc = encodeURIComponent;
const COLOR = "#ff9f43"; // proposals: orange, dashed

/** Keyboard shortcuts of this module (none: its buttons are in the outline panel). */
export const MARKER_SHORTCUTS = [];


/** A button that gives the keyboard back after a click. */
function button(attrs, text, fn) {
  return el("button", { ...attrs, onclick: (ev) => {
    ev.stopPropagation();
    ev.currentTarget.blur();
    fn();
  } }, text);
}

export class MarkerProposals {
  constructor(wb) {
    this.wb = wb;
    this.proposals = {}; // view -> [{uv, radius_px, contrast, zone_radius_px, id}]
    this.nextId = 0;
    this.kind = "beads";
  }

  /** Ask the server for the markers of every view with an image. */
  async find() {
    const views = this.wb.caseInfo.views.filter((v) => v.has_image).map((v) => v.name);
    this.wb.status(`looking for ${this.kind} in ${views.join(", ")}…`);
    document.body.dataset.markers = "finding";
    try {
      const answers = await Promise.all(views.map((view) =>
        request("GET", `api/views/${enc(view)}/markers?kind=${this.kind}`)));
      const counts = [];
      views.forEach((view, i) => {
        this.proposals[view] = answers[i].markers.map((m) => ({ ...m, id: this.nextId++ }));
        counts.push(`${view} ${answers[i].markers.length}`);
      });
      const secs = Math.max(...answers.map((a) => a.seconds));
      this.wb.status(`${this.kind} found: ${counts.join(", ")} (${secs.toFixed(1)} s); ` +
        "accept (✓) the ones to exclude from the outlines");
    } catch (err) {
      this.wb.error(err);
    } finally {
      document.body.dataset.markers = "done";
      this.render();
      this.wb.redraw();
    }
  }

  accept(view, id) {
    const list = this.proposals[view] ?? [];
    const m = list.find((p) => p.id === id);
    if (!m) return;
    this.proposals[view] = list.filter((p) => p.id !== id);
    this.wb.outlineTools.addZone(view, { circle: { center: m.uv, radius_px: m.zone_radius_px } });
    this.render();
  }

  reject(view, id) {
    this.proposals[view] = (this.proposals[view] ?? []).filter((p) => p.id !== id);
    this.render();
    this.wb.redraw();
  }

  acceptAll() {
    for (const [view, list] of Object.entries(this.proposals)) {
      for (const m of [...list]) this.accept(view, m.id);
    }
  }

  rejectAll() {
    this.proposals = {};
    this.render();
    this.wb.redraw();
  }

  count() {
    return Object.values(this.proposals).reduce((n, l) => n + l.length, 0);
  }

  // ---- the panel and the overlay ---------------------------------------------------------

  render() {
    const list = document.getElementById("marker-list");
    if (!list) return;
    const rows = [];
    for (const [view, items] of Object.entries(this.proposals)) {
      items.forEach((m, k) => {
        rows.push(el("li", { class: "contour", "data-testid": `marker-${view}-${k}`,
          title: "click: centre the view on it",
          onclick: () => this.wb.viewers.get(view)?.centreOn(...m.uv) },
        el("span", { class: "name" }, `${view} #${k}`),
        el("span", { class: "meta" },
          `(${m.uv[0].toFixed(0)}, ${m.uv[1].toFixed(0)}) r ${m.radius_px} · ${(m.contrast * 255).toFixed(0)}`),
        button({ class: "accept", title: "accept: an exclusion zone here", "data-testid": `marker-accept-${view}-${k}` },
          "✓", () => this.accept(view, m.id)),
        button({ class: "remove", title: "reject", "data-testid": `marker-reject-${view}-${k}` },
          "×", () => this.reject(view, m.id))));
      });
    }
    list.replaceChildren(...rows);
    const n = this.count();
    document.getElementById("markers-accept-all").disabled = n === 0;
    document.getElementById("markers-reject-all").disabled = n === 0;
    document.getElementById("markers-count").textContent = n ? `${n} proposed` : "";
  }

  draw(ctx, viewer) {
    (this.proposals[viewer.name] ?? []).forEach((m, k) => {
      const [x, y] = viewer.toCanvas(...m.uv);
      const r = Math.max(4, m.zone_radius_px * viewer.zoom);
      ctx.setLineDash([4, 3]);
      ctx.strokeStyle = COLOR;
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      ctx.arc(x, y, r, 0, 2 * Math.PI);
      ctx.stroke();
      ctx.setLineDash([]);
      if (viewer.zoom > 0.6) label(ctx, `#${k}`, x + r + 2, y - 2, COLOR);
    });
  }
}

function buildPanel(markers) {
  const body = document.querySelector("#outline-panel .panel-body");
  if (!body) return;
  const kind = el("select", { id: "markers-kind", "data-testid": "markers-kind",
    title: "beads: small metal beads (r 1.5-3.5 px); discs: larger skin markers (r 8-23 px)" },
  el("option", { value: "beads" }, "beads"), el("option", { value: "discs" }, "discs"));
  kind.addEventListener("change", () => {
    markers.kind = kind.value;
    kind.blur();
  });
  body.append(
    el("h3", { class: "sub" }, "Markers"),
    el("div", { class: "row" },
      button({ id: "markers-find", "data-testid": "markers-find",
        title: "Find marker beads on the radiographs and propose exclusion zones" },
      "Find markers", () => markers.find()),
      kind,
      button({ id: "markers-accept-all", "data-testid": "markers-accept-all", disabled: "" },
        "Accept all", () => markers.acceptAll()),
      button({ id: "markers-reject-all", "data-testid": "markers-reject-all", disabled: "" },
        "Reject all", () => markers.rejectAll())),
    el("p", { class: "note", id: "markers-count", "data-testid": "markers-count" }),
    el("ul", { id: "marker-list", "data-testid": "marker-list", class: "zones" }));
}

/** Put the marker proposals in place (after installOutlineTools). */
export function installMarkers(wb) {
  const markers = new MarkerProposals(wb);
  wb.markers = markers;
  buildPanel(markers);
  wb.overlays.push((ctx, v) => markers.draw(ctx, v));
  return markers;
}
