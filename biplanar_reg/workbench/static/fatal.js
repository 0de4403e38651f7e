// fatal.js — a page that cannot work (no or a stale token, the server gone at start) says why
// and what to do, instead of going blank.

import { ApiError } from "./api.js";

const $ = (id) => document.getElementById(id);

/** A page that cannot work (no token, server gone at start) says why instead of going blank. */
export function fatal(err) {
  const box = $("fatal");
  const forbidden = err instanceof ApiError && err.status === 403;
  box.querySelector("h2").textContent = forbidden
    ? "Access denied (403)"
    : "The workbench could not start";
  box.querySelector(".detail").textContent = err.message || String(err);
  box.querySelector(".hint").textContent = forbidden
    ? "This page needs to be signed in to the workbench. Open the one-time URL that " +
      "`biplanar-reg workbench` printed (http://127.0.0.1:PORT/?launch=…); press Enter in " +
      "its terminal for a new one."
    : "Is `biplanar-reg workbench` still running? Restart it and open the URL it prints.";
  box.hidden = false;
  document.body.dataset.ready = "error";
  $("app").hidden = true;
}
