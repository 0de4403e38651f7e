// keys.js — the page's keyboard: one table of shortcuts (SHORTCUTS) that the key handler runs
// and the "?" list shows, so the list cannot go stale; and the focus rule: no control keeps
// the keyboard after it was used (a slider, a button, a checkbox give it back at once), so the
// shortcuts always work. Text fields (a number being typed, a name) keep it while typing;
// Enter or Esc in one gives it back.
//
// Other modules add their shortcuts with addShortcut({keys, what, match, run}).

const $ = (id) => document.getElementById(id);

/** A plain key (no Ctrl / Cmd / Alt), any of `names` (KeyboardEvent.key values). */
const plain = (...names) => (ev) => !ev.ctrlKey && !ev.metaKey && !ev.altKey && names.includes(ev.key);

/** Ctrl (Cmd on a Mac) + `letter`, with or without Shift. */
const ctrl = (letter, shift) => (ev) =>
  (ev.ctrlKey || ev.metaKey) && !ev.altKey && ev.shiftKey === shift && ev.key.toLowerCase() === letter;

/**
 * The shortcuts, in the order the list shows them. `run(wb, ev)` returns false when the key
 * does nothing in the current state (the browser's default then happens), anything else when
 * it was handled.
 */
export const SHORTCUTS = [
  { keys: "L", what: "Landmarks mode", match: plain("l", "L"), run: (wb) => wb.setMode("landmark") },
  { keys: "O", what: "Outline mode", match: plain("o", "O"), run: (wb) => wb.setMode("outline") },
  {
    keys: "P", what: "Pose mode (the pose aid)", match: plain("p", "P"),
    run: (wb) => (wb.tools.pose ? wb.setMode("pose") : false),
  },
  {
    keys: "U", what: "Pose mode: undo the last pose-aid step (nudge or typed pose)",
    match: plain("u", "U"), run: (wb) => (wb.mode === "pose" ? wb.tools.pose.aid.undo() : false),
  },
  {
    keys: "F", what: "fit the view under the mouse to the whole image", match: plain("f", "F"),
    run: (wb) => wb.viewers.get(wb.activeView)?.fit(),
  },
  {
    keys: "Enter", what: "Outline: save the outline being traced (once)", match: plain("Enter"),
    run: (wb) => (wb.mode === "outline" ? wb.tools.outline.finish() : false),
  },
  {
    keys: "Esc", what: "cancel the outline being traced or the gesture; else drop the selection",
    match: plain("Escape"), run: (wb) => wb.tool().cancel(),
  },
  {
    keys: "Backspace", what: "Outline: drop the last anchor (not tracing: as Delete)",
    match: plain("Backspace"),
    run: (wb) => {
      const outline = wb.tools.outline;
      if (wb.mode === "outline" && outline.tracing()) outline.undo();
      else wb.tool().deleteSelected();
    },
  },
  {
    keys: "Delete", what: "remove the selected landmark (in the view under the mouse) or contour",
    match: plain("Delete"), run: (wb) => wb.tool().deleteSelected(),
  },
  {
    keys: "Ctrl+Z", what: "undo the last edit (while tracing: the last anchor)",
    match: ctrl("z", false), run: (wb) => wb.history?.undo(),
  },
  {
    keys: "Ctrl+Shift+Z, Ctrl+Y", what: "redo the last undone edit",
    match: (ev) => ctrl("z", true)(ev) || ctrl("y", false)(ev), run: (wb) => wb.history?.redo(),
  },
  { keys: "?", what: "this list of shortcuts", match: plain("?"), run: () => toggleShortcutList() },
];

/** Add a shortcut (shown in the list, run by the handler). */
export function addShortcut(entry) {
  SHORTCUTS.push(entry);
  if (!$("shortcut-list")?.hidden) renderShortcutList();
}

/** Whether `el` is a field that takes typed text (it keeps the focus while typing). */
export function isTextField(el) {
  if (!(el instanceof Element)) return false;
  if (el.isContentEditable || el.tagName === "TEXTAREA" || el.tagName === "SELECT") return true;
  if (el.tagName !== "INPUT") return false;
  const notText = ["range", "checkbox", "radio", "button", "submit", "reset", "color", "file", "image"];
  return !notText.includes(el.type);
}

/** The keyboard: shortcuts from SHORTCUTS; Esc closes the list first. */
function onKey(wb, ev) {
  const target = ev.target;
  if (isTextField(target)) {
    // typing: the field keeps the keys; Enter (its value is taken) or Esc gives the focus back
    if (ev.key === "Enter" || ev.key === "Escape") setTimeout(() => target.blur(), 0);
    return;
  }
  // a button reached with Tab: Enter / Space press it (after a click it has no focus)
  if ((ev.key === "Enter" || ev.key === " ") && target.closest?.("button, a[href], summary")) return;
  if (ev.key === "Escape" && !$("shortcut-list").hidden) {
    toggleShortcutList(false);
    ev.preventDefault();
    return;
  }
  for (const s of SHORTCUTS) {
    if (!s.match(ev)) continue;
    if (s.run(wb, ev) === false) return;
    ev.preventDefault(); // e.g. Enter on a button must not also press it
    return;
  }
}

/** Give the focus back after a control was used: a button, a slider, a checkbox, a chosen
 * option. A text field keeps it (it is being typed in). */
function releaseFocus() {
  const a = document.activeElement;
  if (!a || a === document.body || isTextField(a)) return;
  if (a.matches("button, input, select, summary, [tabindex]")) a.blur();
}

/** Install the key handler, the focus rule and the "?" list (call once). */
export function installKeys(wb) {
  document.addEventListener("keydown", (ev) => onKey(wb, ev));
  for (const type of ["click", "pointerup", "change"]) {
    // after the control's own handlers (a timeout: they run first, whatever their order)
    document.addEventListener(type, () => setTimeout(releaseFocus, 0), true);
  }
  document.addEventListener("change", (ev) => {
    if (ev.target instanceof HTMLSelectElement) setTimeout(() => ev.target.blur(), 0);
  }, true);
  // a press in a view takes the keyboard from any field (the canvas itself takes no focus)
  $("views").addEventListener("pointerdown", () => document.activeElement?.blur?.());
  $("shortcuts-button")?.addEventListener("click", () => toggleShortcutList());
  $("shortcut-list").addEventListener("click", (ev) => {
    if (ev.target === $("shortcut-list") || ev.target.closest(".close")) toggleShortcutList(false);
  });
}

/** Show (true), hide (false) or toggle the shortcut list. */
export function toggleShortcutList(show) {
  const box = $("shortcut-list");
  const open = show ?? box.hidden;
  if (open) renderShortcutList();
  box.hidden = !open;
  document.body.dataset.shortcuts = String(open);
}

function renderShortcutList() {
  const rows = SHORTCUTS.map((s) => {
    const tr = document.createElement("tr");
    const k = document.createElement("td");
    for (const [i, part] of s.keys.split(", ").entries()) {
      if (i) k.append(" or ");
      const kbd = document.createElement("kbd");
      kbd.textContent = part;
      k.append(kbd);
    }
    const w = document.createElement("td");
    w.textContent = s.what;
    tr.append(k, w);
    return tr;
  });
  $("shortcut-rows").replaceChildren(...rows);
}
