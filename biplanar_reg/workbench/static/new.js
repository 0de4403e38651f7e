// new.js — the "new case" form of `biplanar-reg workbench --new CASE_DIR`: choose the model,
// the calibrations and images among the folder's files (GET /api/new), then POST /api/new
// writes case.toml and the server opens the workbench on it (the page then loads it).

const TOKEN = document.querySelector('meta[name="workbench-token"]')?.content ?? "";
const $ = (id) => document.getElementById(id);

async function request(method, path, body) {
  const response = await fetch(path, {
    method,
    headers: { "Content-Type": "application/json", "X-Workbench-Token": TOKEN },
    body: body === undefined ? undefined : JSON.stringify(body),
  });
  const data = await response.json().catch(() => null);
  if (!response.ok) throw new Error(data?.error ?? `${response.status} ${response.statusText}`);
  return data;
}

function select(options, value, empty) {
  const s = document.createElement("select");
  if (empty) s.append(new Option(empty, ""));
  for (const o of options) s.append(new Option(o, o));
  if (value) s.value = value;
  return s;
}

/** The name a row's view gets: after its image file, else its calibration file (the server's
 * `view_names`), unique among the rows. */
function defaultName(names, row) {
  const file = row.querySelector(".view-image").value || row.querySelector(".view-calibration").value;
  const base = names[file] || `view${row.rowIndex}`;
  const taken = new Set([...$("view-rows").tBodies[0].rows]
    .filter((r) => r !== row).map((r) => r.querySelector(".view-name").value));
  let name = base;
  for (let k = 2; taken.has(name); k++) name = `${base}_${k}`;
  return name;
}

function addView(files, names, i) {
  const row = document.createElement("tr");
  const name = document.createElement("input");
  name.className = "view-name";
  name.dataset.testid = `new-view-name-${i}`;
  const calib = select(files.calibrations, files.calibrations[i]);
  calib.className = "view-calibration";
  const image = select(files.images, files.images[i], "(no image)");
  image.className = "view-image";
  for (const el of [name, calib, image]) {
    const td = document.createElement("td");
    td.append(el);
    row.append(td);
  }
  $("view-rows").tBodies[0].append(row);
  // the name follows the files chosen until it is typed in
  name.value = defaultName(names, row);
  name.addEventListener("input", () => {
    name.dataset.typed = "true";
  });
  for (const s of [calib, image]) {
    s.addEventListener("change", () => {
      if (!name.dataset.typed) name.value = defaultName(names, row);
    });
  }
}

async function main() {
  const { case_dir: dir, files, view_names: names } = await request("GET", "api/new");
  $("case-dir").textContent = dir;
  for (const m of files.models) $("model").append(new Option(m, m));
  if (files.landmarks.length) $("landmarks").value = files.landmarks[0];
  addView(files, names, 0);
  addView(files, names, 1);
  $("add-view").addEventListener("click",
    () => addView(files, names, $("view-rows").tBodies[0].rows.length));
  $("new-case").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const views = [...$("view-rows").tBodies[0].rows].map((r) => ({
      name: r.querySelector(".view-name").value.trim(),
      calibration: r.querySelector(".view-calibration").value,
      image: r.querySelector(".view-image").value || null,
    }));
    try {
      const res = await request("POST", "api/new", {
        model: $("model").value,
        landmarks: $("landmarks").value.trim() || null,
        poses: $("poses").value,
        views,
      });
      window.location.assign(res.url);
    } catch (err) {
      $("error").textContent = err.message;
    }
  });
  document.body.dataset.ready = "true";
}

main().catch((err) => {
  $("error").textContent = err.message;
});
