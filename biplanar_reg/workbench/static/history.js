// history.js — undo / redo of every edit. The server keeps the history (one per launch:
// biplanar_reg/workbench/history.py), so a reloaded page can still undo; this module has the
// Undo / Redo buttons, what Ctrl+Z / Ctrl+Shift+Z run (keys.js), and brings the page to the
// state the server answers.

import { ApiError, request } from "./api.js";

const REFRESH_MS = 60; // edits in a burst ask for the history's state once

export class EditHistory {
  constructor(wb, { undo, redo }) {
    this.wb = wb;
    this.buttons = { undo, redo };
    this.status = null; // {undo, redo, undo_label, redo_label, limit, note}
    this.timer = 0;
    undo.addEventListener("click", () => this.undo());
    redo.addEventListener("click", () => this.redo());
  }

  /** Ctrl+Z: while an outline is being traced, its last anchor; else the last edit. */
  undo() {
    const outline = this.wb.tools.outline;
    if (this.wb.mode === "outline" && outline.tracing()) {
      outline.undo();
      return;
    }
    this.move("undo");
  }

  redo() {
    this.move("redo");
  }

  move(action) {
    this.wb.edit(async () => {
      const s = this.status;
      if (s && !s[action]) {
        const why = action === "undo" && s.note ? ` (${s.note})` : "";
        this.wb.status(`nothing to ${action}${why}`);
        return;
      }
      let res;
      try {
        res = await request("POST", `api/history/${action}`, {});
      } catch (err) {
        if (!(err instanceof ApiError && err.status === 409)) throw err;
        this.wb.error(err); // e.g. the history was cleared: a file was changed outside
        this.refresh();
        return;
      }
      this.apply(res);
      this.wb.status(`${action === "undo" ? "undone" : "redone"}: ${res.done}`);
    });
  }

  /** The page as the server's answer has it: annotations, model landmarks, zones. */
  apply(res) {
    const wb = this.wb;
    wb.tools.outline.cancel();
    wb.selectedContour = null;
    const names = Object.keys(res.model_landmarks);
    const known = wb.caseInfo.model_landmarks ?? {};
    const same = names.length === Object.keys(known).length &&
      names.every((n) => known[n] === res.model_landmarks[n]);
    if (!same) {
      if (!names.includes(wb.selectedLandmark)) wb.selectedLandmark = names[0] ?? null;
      wb.setModelLandmarks(res.model_landmarks);
      const model = window.workbench?.model; // the 3D view keeps its own copy (model3d.js)
      if (model) {
        model.landmarks = { ...res.model_landmarks };
        model.renderList();
        model.renderMarkers();
      }
    }
    for (const [view, va] of Object.entries(res.annotations.views)) wb.setViewAnnotations(view, va);
    wb.outlineTools?.loadZones();
    this.show(res.history);
  }

  /** Ask the server for the history's state soon (after an edit). */
  refreshSoon() {
    clearTimeout(this.timer);
    this.timer = setTimeout(() => this.refresh(), REFRESH_MS);
  }

  async refresh() {
    try {
      this.show((await request("GET", "api/history")).history);
    } catch (err) {
      this.wb.error(err);
    }
  }

  show(status) {
    this.status = status;
    const { undo, redo } = this.buttons;
    undo.disabled = !status.undo;
    redo.disabled = !status.redo;
    undo.title = status.undo ? `Undo: ${status.undo_label} (Ctrl+Z)` : "Nothing to undo (Ctrl+Z)";
    redo.title = status.redo
      ? `Redo: ${status.redo_label} (Ctrl+Shift+Z)` : "Nothing to redo (Ctrl+Shift+Z)";
    undo.dataset.steps = String(status.undo);
    redo.dataset.steps = String(status.redo);
  }
}

/** Install the history (call once, after the outline tools): every edit made through
 * wb.edit (and every model landmark edit) refreshes the buttons. */
export function installHistory(wb, buttons) {
  const history = new EditHistory(wb, buttons);
  wb.history = history;
  const edit = wb.edit.bind(wb);
  wb.edit = (fn) => edit(async () => {
    try {
      return await fn();
    } finally {
      history.refreshSoon();
    }
  });
  const setModelLandmarks = wb.setModelLandmarks.bind(wb);
  wb.setModelLandmarks = (landmarks) => {
    setModelLandmarks(landmarks);
    history.refreshSoon();
  };
  history.refresh();
  return history;
}
