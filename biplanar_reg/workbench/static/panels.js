// panels.js — the side panels' lists: landmarks (select, where placed, remove) and contours
// (select, remove). They are re-rendered from the state after every change (tens of items).

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === "dataset") Object.assign(node.dataset, v);
    else if (k.startsWith("on")) node.addEventListener(k.slice(2), v);
    else node.setAttribute(k, v);
  }
  node.append(...children);
  return node;
}

/** Landmark list: one item per name of the case's landmark_names; a chip per view shows where
 * it is placed (click the x to remove it there). */
export function renderLandmarkList(wb, list) {
  const views = wb.caseInfo.views.map((v) => v.name);
  const items = wb.caseInfo.landmark_names.map((name) => {
    const chips = views.map((view) => {
      const placed = Boolean(wb.viewAnnotations(view).landmarks[name]);
      const chip = el("span", { class: placed ? "chip placed" : "chip" }, view);
      if (placed) {
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
        dataset: { name, placed: views.filter((v) => wb.viewAnnotations(v).landmarks[name]).join(" ") },
        onclick: () => wb.selectLandmark(name),
      },
      el("span", { class: "name" }, name),
      el("span", { class: "chips" }, ...chips),
    );
  });
  list.replaceChildren(...items);
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
