// api.js — the workbench's JSON API (docs/workbench.md, "API"), one function per endpoint.
//
// The browser is signed in by the session cookie (set by the one-time URL the command
// printed); the per-launch token comes from the <meta name="workbench-token"> the server
// writes into the page and goes in the X-Workbench-Token header of every request: the server
// refuses a request that changes something without it (another page's form or <img> cannot
// set a header). URLs loaded by the browser itself (tiles as <img>, the EventSource) get
// through with the cookie; no URL carries the token.

const TOKEN = document.querySelector('meta[name="workbench-token"]')?.content || null;

// A URL with ?token= or ?launch= (e.g. opened by hand) leaves the address bar and the history.
{
  const url = new URL(window.location.href);
  if (url.searchParams.has("token") || url.searchParams.has("launch")) {
    url.searchParams.delete("token");
    url.searchParams.delete("launch");
    window.history.replaceState(window.history.state, "", url.pathname + url.search + url.hash);
  }
}

/** An API failure: `status` is the HTTP status (0 for a network error), `message` the server's
 * one-line `{"error": ...}` text. */
export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.name = "ApiError";
    this.status = status;
  }
}

/** One JSON request. Resolves to the parsed body, rejects with an ApiError. */
export async function request(method, path, body, { signal } = {}) {
  const headers = { Accept: "application/json" };
  if (TOKEN) headers["X-Workbench-Token"] = TOKEN;
  // every request that changes something is JSON (the server refuses other types)
  if (body !== undefined || method !== "GET") headers["Content-Type"] = "application/json";
  let response;
  try {
    response = await fetch(path, {
      method,
      headers,
      body: body === undefined ? undefined : JSON.stringify(body),
      signal,
      credentials: "same-origin",
    });
  } catch (err) {
    if (err.name === "AbortError") throw err;
    throw new ApiError(0, `the workbench server does not answer (${err.message})`);
  }
  let data = null;
  try {
    data = await response.json();
  } catch {
    data = null; // a non-JSON body: fall through to the status text below
  }
  if (!response.ok) {
    const message = data && data.error ? data.error : `${response.status} ${response.statusText}`;
    throw new ApiError(response.status, message);
  }
  return data;
}

const enc = encodeURIComponent;

export const api = {
  hasToken: () => Boolean(TOKEN),

  getCase: () => request("GET", "api/case"),
  getAnnotations: () => request("GET", "api/annotations"),

  putLandmark: (view, name, uv, sigmaPx) =>
    request("PUT", `api/views/${enc(view)}/landmarks/${enc(name)}`, {
      uv,
      ...(sigmaPx === undefined ? {} : { sigma_px: sigmaPx }),
    }),
  deleteLandmark: (view, name) =>
    request("DELETE", `api/views/${enc(view)}/landmarks/${enc(name)}`),
  snap: (view, uv) => request("POST", `api/views/${enc(view)}/snap`, { uv }),

  livewire: (view, anchors, closed, signal) =>
    request("POST", `api/views/${enc(view)}/livewire`, { anchors, closed }, { signal }),
  /** The livewire through the anchors, cut by the exclusion zones, saved: {index, pieces, view}. */
  traceOutline: (view, anchors, closed) =>
    request("POST", `api/views/${enc(view)}/outlines`, { anchors, closed }),
  addContour: (view, uv, closed, anchors) =>
    request("POST", `api/views/${enc(view)}/contours`, { uv, closed, anchors }),
  /** Resolves to the view's annotations (the server answers {"index", "view"}). `contour` is
   * the contour as the server last sent it: its id and version (a contour changed or removed
   * since, e.g. in another tab, is refused with 409). */
  deleteContour: async (view, contour) => {
    const res = await request("DELETE", contourPath(view, contour));
    return res && res.view ? res.view : res;
  },

  startRegister: () => request("POST", "api/register"),
  getRegister: () => request("GET", "api/register"),
  getResult: () => request("GET", "api/result"),

  // the 3D model view, the pose aid and the result's shading (model3d.js, poseaid.js)
  getModelMesh: () => request("GET", "api/model/mesh"),
  putModelLandmark: (name, vertex) =>
    request("PUT", `api/model/landmarks/${enc(name)}`, { vertex }),
  getResultMesh: () => request("GET", "api/result/mesh"),
  getResultShading: (view) => request("GET", `api/result/shading/${enc(view)}`),
  getPoseAid: () => request("GET", "api/pose-aid"),
  poseAidAction: (action, body) => request("POST", `api/pose-aid/${action}`, body ?? {}),
  proposeOutline: (view, spacingPx) =>
    request("POST", `api/views/${enc(view)}/propose-outline`,
      spacingPx === undefined ? {} : { spacing_px: spacingPx }),

  /** URL of one grey PNG tile, raw values mapped from [lo, hi] to [0, 255]. */
  tileUrl: (view, level, tx, ty, lo, hi) =>
    `api/views/${enc(view)}/tiles/${level}/${tx}/${ty}.png?lo=${lo}&hi=${hi}`,
  eventsUrl: () => "api/register/events",
};

/** The URL of one contour's edits: its id, with the version the page last saw. */
export function contourPath(view, contour, action = "") {
  const tail = action ? `/${action}` : "";
  return `api/views/${enc(view)}/contours/${enc(contour.id)}${tail}?version=${contour.version}`;
}
