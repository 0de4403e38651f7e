// api.js — the workbench's JSON API (WORKBENCH.md, "JSON API"), one function per endpoint.
//
// The per-launch token comes from the page's URL (?token=...), else from the
// <meta name="workbench-token"> the server writes into the page. The server also sets an
// HttpOnly cookie when it serves the page, but we send the token explicitly as a header too, so
// a blocked or stale cookie does not break the page. URLs loaded by the browser itself (tiles
// as <img>, the EventSource) cannot carry headers, so they get the token as a query parameter.

const TOKEN =
  new URLSearchParams(window.location.search).get("token") ||
  document.querySelector('meta[name="workbench-token"]')?.content ||
  null;

/** An API failure: `status` is the HTTP status (0 for a network error), `message` the server's
 * one-line `{"error": ...}` text. */
export class ApiError extends Error {
  constructor(status, message) {
    super(message);
    this.name = "ApiError";
    this.status = status;
  }
}

/** Append the token to a same-origin URL (for <img> and EventSource). */
function withToken(url) {
  if (!TOKEN) return url;
  const sep = url.includes("?") ? "&" : "?";
  return `${url}${sep}token=${encodeURIComponent(TOKEN)}`;
}

/** One JSON request. Resolves to the parsed body, rejects with an ApiError. */
export async function request(method, path, body, { signal } = {}) {
  const headers = { Accept: "application/json" };
  if (TOKEN) headers["X-Workbench-Token"] = TOKEN;
  if (body !== undefined) headers["Content-Type"] = "application/json";
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
  /** Resolves to the view's annotations (the server answers {"index", "view"}). */
  deleteContour: async (view, index) => {
    const res = await request("DELETE", `api/views/${enc(view)}/contours/${index}`);
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
    withToken(`api/views/${enc(view)}/tiles/${level}/${tx}/${ty}.png?lo=${lo}&hi=${hi}`),
  eventsUrl: () => withToken("api/register/events"),
};
