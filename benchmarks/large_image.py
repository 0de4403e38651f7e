"""Memory of a case with very large radiographs (two 8000 x 8000 16-bit radiographs by default).

Builds a synthetic two-view case whose radiographs are 16-bit TIFFs of ``--size`` x ``--size``
pixels (rendered at 1000 px by :func:`biplanar_reg.simulate.write_synthetic_case`, upsampled, with
calibrations and annotations of the same field of view at the large size), then measures in a
fresh process each of:

* ``load``: :func:`biplanar_reg.cases.load_case` alone;
* ``load + decode``: the case and both radiographs decoded (what the report and the workbench
  need);
* ``register``: ``biplanar-reg register CASE --out OUT`` (registration and report).

Reported per step: the peak resident memory of the process (MB, ``ru_maxrss``) and its CPU
seconds. With ``--base PATH`` (another checkout, e.g. ``git worktree add /tmp/base <an earlier
version>``) the same steps run on that code too, side by side, in the same run.

Usage::

    python benchmarks/large_image.py [--size 8000] [--base /tmp/base]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from _common import RESULTS, header, write_text

from biplanar_reg.calibration import save_calibration
from biplanar_reg.simulate import look_at_view, write_synthetic_case

SMALL = 1000  # px: the size the radiographs are rendered at before upsampling

STEPS = {
    "load": "from biplanar_reg.cases import load_case; load_case({case!r})",
    "load + decode": (
        "from biplanar_reg.cases import load_case; c = load_case({case!r}); "
        "[v.image.display.shape for v in c.views]"
    ),
    "register": (
        "import sys; from biplanar_reg.cli import main; "
        "sys.exit(main(['register', {case!r}, '--out', {out!r}]))"
    ),
}


def _views(size: int) -> list:
    """The synthetic case's two views (75 deg apart, 900/1200 mm) at ``size`` px, same field of
    view (512 px at 0.3 mm)."""
    a = np.deg2rad(75.0) / 2
    return [
        look_at_view(
            900.0 * np.array([sx * np.sin(a), 0.0, -np.cos(a)]),
            sdd=1200.0,
            pixel=0.3 * 512 / size,
            image_size=(size, size),
            name=name,
        )
        for sx, name in ((-1.0, "cam1"), (1.0, "cam2"))
    ]


def _scale_uv(uv: list, f: float) -> list:
    """Pixel coordinates (pixel centres at integers) from SMALL px to ``f`` times as many."""
    return [(float(c) + 0.5) * f - 0.5 for c in uv]


def make_case(folder: Path, size: int) -> Path:
    """Write the large-radiograph case into ``folder``; returns it."""
    write_synthetic_case(folder, 0, views=_views(SMALL))
    f = size / SMALL
    toml = (folder / "case.toml").read_text()
    for png in sorted((folder / "xray").glob("*.png")):
        small = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        big = cv2.resize(small, (size, size), interpolation=cv2.INTER_LINEAR).astype(np.uint16)
        cv2.imwrite(str(png.with_suffix(".tif")), big * np.uint16(257))
        png.unlink()
        toml = toml.replace(f"xray/{png.name}", f"xray/{png.stem}.tif")
    (folder / "case.toml").write_text(toml)
    for view, fname, fmt in zip(
        _views(size), ("cam1.txt", "cam2.json"), ("mayacam2", "json"), strict=True
    ):
        save_calibration(view, folder / "calib" / fname, fmt)
    ann = folder / "annotations.json"
    doc = json.loads(ann.read_text())
    for v in doc["views"].values():
        for lm in v.get("landmarks", {}).values():
            lm["uv"] = _scale_uv(lm["uv"], f)
        for c in v.get("contours", []):
            c["uv"] = [_scale_uv(p, f) for p in c["uv"]]
    ann.write_text(json.dumps(doc))
    return folder


def _peak(code: str, pythonpath: str) -> tuple[float, float, int]:
    """Peak RSS of one run, isolated from earlier children by a wrapper process."""
    wrapper = (
        "import resource, subprocess, sys, json; "
        f"p = subprocess.run([sys.executable, '-c', {code!r}]); "
        "r = resource.getrusage(resource.RUSAGE_CHILDREN); "
        "print(json.dumps([r.ru_maxrss / 1024.0, r.ru_utime + r.ru_stime, p.returncode]))"
    )
    env = dict(os.environ, PYTHONPATH=pythonpath)
    # cwd: ``python -c`` puts the working directory first on sys.path, before PYTHONPATH
    out = subprocess.run(
        [sys.executable, "-c", wrapper],
        env=env,
        cwd=tempfile.gettempdir(),
        capture_output=True,
        text=True,
        check=True,
    )
    mb, cpu, rc = json.loads(out.stdout.strip().splitlines()[-1])
    return float(mb), float(cpu), int(rc)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=8000, help="radiograph side, px")
    parser.add_argument("--base", type=Path, help="another checkout to measure side by side")
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    trees = {"this tree": str(Path(__file__).resolve().parents[1])}
    if args.base:
        trees = {"base": str(args.base.resolve()), **trees}
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        case = make_case(Path(tmp) / "large", args.size)
        for step, template in STEPS.items():
            row = [step]
            for name, tree in trees.items():
                out = Path(tmp) / f"out_{name.replace(' ', '_')}"
                shutil.rmtree(out, ignore_errors=True)
                mb, cpu, rc = _peak(template.format(case=str(case), out=str(out)), tree)
                row += [f"{mb:.0f}" if rc == 0 else f"{mb:.0f} (exit {rc})", f"{cpu:.1f}"]
            rows.append(row)
            print(" | ".join(row), flush=True)
    cols = ["step"] + [f"{n}: {k}" for n in trees for k in ("peak MB", "CPU s")]
    cmd = f"python benchmarks/large_image.py --size {args.size}" + (
        " --base PATH" if args.base else ""
    )
    title = f"Memory of a case with two {args.size}x{args.size} 16-bit radiographs"
    lines = header(title, cmd, time.perf_counter() - t0)
    lines += ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    write_text(RESULTS / "large_image.md", "\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
