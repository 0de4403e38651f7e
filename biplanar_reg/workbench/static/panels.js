// panels.js — the side panels' lists: landmarks (select, where placed, remove) and contours
// (select, remove). They are re-rendered from the state after every change (tens of items).

import { chipMarker } from "./warnings.js";
import { el } from "./dom.js";


/** Residual classes: within the landmarks' typical sigma, near the 5 px flag, beyond. */
function residualClass(px) {
  if (px < 3) return "good";
  if (px < 8) return "fair";
  return "bad";
}

/** Landmark list: one item per name of the case's landmark_names; a chip per view shows where
 * it is placed (click it to centre that view on it, the x to remove it there) and, after a
 * registration, the residual in px. */
export function renderLandmarkList(wb, list) {
  const views = wb.caseInfo.views.map((v) => v.name);
  const items = wb.caseInfo.landmark_names.map((name) => {
    const placedIn = (view) => Boolean(wb.viewAnnotations(view).landmarks[name]);
    const chips = views.map((view) => {
      const lm = wb.viewAnnotations(view).landmarks[name];
      const placed = Boolean(lm);
      const chip = el("span", { class: placed ? "chip placed" : "chip" }, view);
      const residual = wb.result?.views?.[view]?.landmark_errors_px?.[name];
      if (placed && typeof residual === "number") {
        // The registration's residual here, colour-coded like its flag (5 px RMS).
        const cls = `residual ${residualClass(residual)}`;
        chip.append(el("span", { class: cls }, residual.toFixed(1)));
        chip.title = `${name} in ${view}: ${residual.toFixed(2)} px from the registered landmark`;
      }
      const mark = placed ? chipMarker(wb.result, view, name) : null;
      if (mark) {
        chip.append(mark); // the registration's warning about this landmark here
        chip.classList.add("warned");
        chip.title = `${chip.title}\n${mark.title}`.trim();
      }
      if (placed) {
        chip.classList.add("jump");
        chip.addEventListener("click", (ev) => {
          ev.stopPropagation(); // jumping is not selecting
          wb.selectLandmark(name);
          wb.viewers.get(view)?.centreOn(...lm.uv);
        });
        chip.append(
          el("button", {
            class: "remove",
            title: `remove ${name} from ${view}`,
            "aria-label": `remove ${name} from ${view}`,
            "data-testid": `remove-${name}-${view}`,
            onclick: (ev) => {
              ev.stopPropagation(); // removing is not selecting
              wb.removeLandmark(view, name);
            },
          }, "×"),
        );
      }
      return chip;
    });
    const selected = name === wb.selectedLandmark;
    return el(
      "li",
      {
        class: selected ? "landmark selected" : "landmark",
        "data-testid": `landmark-${name}`,
        "aria-selected": String(selected),
        dataset: { name, placed: views.filter((v) => placedIn(v)).join(" ") },
        onclick: () => wb.selectLandmark(name),
      },
      el("span", { class: "name" }, name),
      el("span", { class: "chips" }, ...chips),
    );
  });
  list.replaceChildren(...items);
}

/** The contour list's row of contour `index` of `view`, or null. Found through the rows' data
 * attributes, not a CSS selector: a view name may hold any character (a quote too). */
export function contourRow(view, index) {
  for (const row of document.querySelectorAll("#contour-list li.contour")) {
    if (row.dataset.view === view && row.dataset.index === String(index)) return row;
  }
  return null;
}

/** Contour list: per view, each contour with its point count; click selects, x removes. */
export function renderContourList(wb, list) {
  const items = [];
  for (const { name: view } of wb.caseInfo.views) {
    wb.viewAnnotations(view).contours.forEach((c, index) => {
      const sel = wb.selectedContour;
      const selected = Boolean(sel && sel.view === view && sel.index === index);
      items.push(
        el(
          "li",
          {
            class: selected ? "contour selected" : "contour",
            "data-testid": `contour-${view}-${index}`,
            dataset: { view, index: String(index), id: c.id ?? "" },
            onclick: () => wb.selectContour({ view, index }),
          },
          el("span", { class: "name" }, `${view} #${index}`),
          el("span", { class: "meta" }, `${c.uv.length} pts${c.closed ? ", closed" : ""}`),
          el("button", {
            class: "remove",
            title: `remove contour #${index} of ${view}`,
            onclick: (ev) => {
              ev.stopPropagation();
              wb.removeContour(view, index);
            },
          }, "×"),
        ),
      );
    });
  }
  if (!items.length) items.push(el("li", { class: "empty" }, "no contours yet"));
  list.replaceChildren(...items);
}
