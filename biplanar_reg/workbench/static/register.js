// register.js — the Register button, the streamed progress messages (EventSource on
// /api/register/events), and the result: metrics, quality flags with advice, the registered
// outline and landmarks (drawn over the views by app.js from wb.result).

import { api, ApiError } from "./api.js";
import { renderViewBadges, startText } from "./warnings.js";

/** What to do about each quality flag (the flags of registration/register.py), by prefix. */
const ADVICE = [
  [
    "relaxation not tight",
    "The convex relaxation's certificate is above 0.01: the pose may be a local optimum. " +
      "Check the landmarks for a blunder, or add one (3 per view fix the pose).",
  ],
  [
    "local refinement did not converge",
    "The final refinement stopped at its iteration limit: check the outlines for stretches " +
      "on the wrong edge.",
  ],
  [
    "large landmark reprojection error",
    "Landmark reprojection RMS above 5 px: compare the magenta X (registered) with the " +
      "green + (clicked) in each view and move the landmark that is off.",
  ],
  [
    "rejected observations",
    "The solver ignored these landmarks as blunders: check or delete them.",
  ],
  [
    "landmark disagrees with the outlines",
    "The landmark marked ! in the list and ringed in the view pulls against the traced " +
      "outlines: check where it was clicked (in the oblique view above all).",
  ],
  [
    "one-sided outline",
    "Only one border of the bone is traced in the view with the badge: trace the other " +
      "border too, or the fit may slide across the bone.",
  ],
];

function adviceFor(flag) {
  const hit = ADVICE.find(([prefix]) => flag.startsWith(prefix));
  return hit ? hit[1] : "";
}

/** One progress message as text: the stream's data lines may be plain text or JSON. */
function messageText(data) {
  try {
    const parsed = JSON.parse(data);
    if (typeof parsed === "string") return parsed;
    if (parsed && typeof parsed.message === "string") return parsed.message;
  } catch {
    // plain text
  }
  return data;
}

function formatNumber(x) {
  if (!Number.isFinite(x)) return String(x);
  if (Number.isInteger(x)) return String(x);
  return Math.abs(x) >= 1000 || Math.abs(x) < 0.001 ? x.toExponential(3) : x.toPrecision(4);
}

export class RegisterPanel {
  constructor(wb, elements) {
    this.wb = wb;
    this.el = elements; // {button, panel, progress, flags, metrics, error, start}
    this.source = null;
    this.el.button.addEventListener("click", () => this.run());
  }

  /** On page load: show the last result, and follow a registration still running. */
  async init() {
    // a case never registered has no result to ask for (GET /api/result would be a 404)
    if (this.wb.caseInfo.has_result) await this.loadResult();
    const status = await api.getRegister();
    if (status.state === "running") {
      this.follow();
      return;
    }
    for (const m of status.messages || []) this.addMessage(messageText(m));
    if (status.state === "failed") this.showError(status.error);
    this.setState(status.state);
  }

  showError(error) {
    this.el.error.textContent = `Registration failed: ${error || "unknown error"}`;
  }

  setState(state) {
    this.el.panel.dataset.state = state;
    this.el.button.disabled = state === "running";
    this.el.button.textContent = state === "running" ? "Registering…" : "Register";
  }

  async run() {
    try {
      await api.startRegister();
    } catch (err) {
      // 409: one is already running; follow it rather than fail.
      if (!(err instanceof ApiError && err.status === 409)) {
        this.wb.error(err);
        return;
      }
    }
    this.wb.noteRegisterStart();
    this.follow();
  }

  /** Stream the progress messages until `done` / `failed`. */
  follow() {
    this.setState("running");
    this.el.progress.replaceChildren();
    this.el.error.textContent = "";
    this.source?.close();
    const source = new EventSource(api.eventsUrl());
    this.source = source;
    source.onmessage = (ev) => this.addMessage(messageText(ev.data));
    // `idle`: nothing was started (e.g. the server restarted); the state says what there is.
    for (const end of ["done", "failed", "idle"]) {
      source.addEventListener(end, () => this.finish(source));
    }
    // A dropped stream (or a server without SSE) falls back to polling the state.
    source.onerror = () => {
      if (this.source === source) this.poll(source);
    };
  }

  addMessage(text) {
    const li = document.createElement("li");
    li.textContent = text;
    this.el.progress.append(li);
    // the list scrolls itself (never li.scrollIntoView: that scrolled the side panel away
    // from the landmark list)
    this.el.progress.scrollTop = this.el.progress.scrollHeight;
  }

  async poll(source) {
    source.close();
    for (;;) {
      const status = await api.getRegister().catch(() => null);
      if (status && status.state !== "running") break;
      await new Promise((r) => setTimeout(r, 500));
    }
    this.finish(source);
  }

  /** The job ended: the server's state is authoritative for the messages and the error. */
  async finish(source) {
    if (this.source !== source) return;
    source.close();
    this.source = null;
    try {
      const status = await api.getRegister();
      this.el.progress.replaceChildren();
      for (const m of status.messages || []) this.addMessage(messageText(m));
      if (status.state === "failed") {
        this.showError(status.error);
      } else {
        await this.loadResult();
      }
      this.setState(status.state);
      if (status.state === "done") this.wb.status(this.summary(status.result));
    } catch (err) {
      this.wb.error(err);
      this.setState("failed");
    }
  }

  /** GET /api/result (404 = none yet) -> wb.result, the metrics table and the flags. */
  async loadResult() {
    let result = null;
    try {
      result = await api.getResult();
    } catch (err) {
      if (!(err instanceof ApiError && err.status === 404)) throw err;
    }
    this.wb.setResult(result); // also re-renders the lists: the residuals appear in them
    this.showMetrics(result ? result.metrics : null);
    this.showFlags(result);
    renderViewBadges(result);
    this.el.start.textContent = startText(result);
    this.el.start.dataset.start = result?.start?.start ?? "";
  }

  /** The status line after a registration: its time and start (the side panel stays put). */
  summary(done) {
    const secs = typeof done?.seconds === "number" ? ` in ${done.seconds.toFixed(1)} s` : "";
    const start = done?.start?.text ? ` · ${done.start.text}` : "";
    const flags = (done?.flags || []).length;
    return `registered${secs}${start} · ${flags} flag${flags === 1 ? "" : "s"}`;
  }

  showMetrics(metrics) {
    const cells = [];
    for (const [key, value] of Object.entries(metrics || {})) {
      if (typeof value !== "number") continue; // method descriptions are in result.json
      const cell = document.createElement("div");
      cell.className = "metric";
      const k = document.createElement("span");
      const v = document.createElement("span");
      k.className = "key";
      k.textContent = key;
      v.className = "value";
      v.textContent = formatNumber(value);
      v.dataset.metric = key;
      cell.append(k, v);
      cell.title = `${key} = ${value}`;
      cells.push(cell);
    }
    this.el.metrics.replaceChildren(...cells);
  }

  showFlags(result) {
    const items = [];
    if (result) {
      const flags = result.flags || [];
      for (const flag of flags) {
        const li = document.createElement("li");
        li.className = "flag";
        const strong = document.createElement("strong");
        strong.textContent = flag;
        li.append(strong);
        const advice = adviceFor(flag);
        if (advice) {
          const p = document.createElement("p");
          p.textContent = advice;
          li.append(p);
        }
        items.push(li);
      }
      if (!flags.length) {
        const li = document.createElement("li");
        li.className = "ok";
        li.textContent = "no quality flags";
        items.push(li);
      }
    }
    this.el.flags.replaceChildren(...items);
    this.el.flags.dataset.count = result ? String((result.flags || []).length) : "";
  }
}
