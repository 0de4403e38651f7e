"""Measurements behind the input limits and checks of the case loader (docs/cases.md, "Size
limits and template checks"; docs/registration.md, "Nearly parallel views").

Sub-commands (each prints one line per setting; ``--work`` holds the generated cases)::

    python benchmarks/input_limits.py templates 0,1,2,3,4,5   # template subdivided k times
    python benchmarks/input_limits.py views 2,8,32,128          # N annotated views
    python benchmarks/input_limits.py extra-views 1000          # 2 annotated + N-2 others
    python benchmarks/input_limits.py defects 0,1,2             # defective templates, seeds
    python benchmarks/input_limits.py angles 0.2,1,3,5,30,75 20 # views ANGLE deg apart (A)
    python benchmarks/input_limits.py angles-b 0.5,2,5,75 20    # the same, harder trials (B)

``templates``/``views``/``defects`` run ``biplanar-reg register --no-report`` in a child
process under ``/usr/bin/time`` (wall, CPU, peak memory); ``angles`` registers the synthetic
case (482-vertex bone, 8 landmarks per view at 0.5 px, 80 % outlines) with its two views the
angle apart and reports the vertex RMS, the median vertex sd, the error over the sd and the 2-sd
coverage; ``angles-b`` does so on the ``--simple`` trials of ``benchmarks/uncertainty.py``
(radius model, truth outside its span, 6 landmarks at 1.5 px).
"""

from __future__ import annotations

import argparse
import collections
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def _register(case: Path) -> tuple[int, str]:
    """``register --no-report`` in a child process: exit code and the time line (or error)."""
    cmd = ["/usr/bin/time", "-f", "%e s wall, %U+%S s CPU, %M KB peak", sys.executable, "-m"]
    cmd += ["biplanar_reg.cli", "register", str(case), "--no-report"]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=3600)
    lines = p.stderr.strip().splitlines()
    errors = [ln for ln in lines if ln.startswith("error")]
    return p.returncode, (errors[0] if p.returncode and errors else lines[-1])[:300]


def _with_template(base: Path, dst: Path, V: np.ndarray, F: np.ndarray) -> Path:
    """A copy of case ``base`` registering the template mesh (V, F) instead of its SSM."""
    from biplanar_reg.io import write_mesh

    if dst.exists():
        shutil.rmtree(dst)
    shutil.copytree(base, dst)
    write_mesh(dst / "gt/template.ply", V, F)
    toml = (dst / "case.toml").read_text()
    toml = toml.replace('ssm = "model/bone_ssm.npz"', 'template = "gt/template.ply"')
    (dst / "case.toml").write_text(toml)
    return dst


def _base(work: Path, seed: int = 0) -> Path:
    from biplanar_reg.simulate import write_synthetic_case

    base = work / f"base{seed}"
    if not base.exists():
        write_synthetic_case(base, seed, image_size=(512, 512))
    return base


def templates(work: Path, ks: list[int]) -> None:
    """The synthetic case's truth mesh midpoint-subdivided k times (the same surface, the
    original vertices keep their indices and so the landmarks) as ``[model] template``."""
    import trimesh

    from biplanar_reg.io import read_mesh

    base = _base(work)
    V, F = read_mesh(base / "gt/bone.ply")
    for k in ks:
        v, f = V, F
        for _ in range(k):
            v, f = trimesh.remesh.subdivide(v, f)
        rc, line = _register(_with_template(base, work / f"sub{k}", v, f))
        print(f"{len(f):>9,} faces ({len(v):,} vertices): exit {rc}, {line}", flush=True)


def views(work: Path, ns: list[int], extra: bool) -> None:
    """N views on a half circle, all annotated; or (``extra``) the case's two annotated views
    and N - 2 copies of the second's calibration without annotations."""
    from biplanar_reg.simulate import write_synthetic_case
    from biplanar_reg.simulate.scenes import look_at_view

    for n in ns:
        d = work / f"{'extra' if extra else 'all'}{n}"
        if d.exists():
            shutil.rmtree(d)
        if extra:
            write_synthetic_case(d, 0, image_size=(512, 512))
            more = "".join(
                f'\n[[views]]\nname = "x{i}"\ncalibration = "calib/cam2.json"\n'
                for i in range(n - 2)
            )
            toml = (d / "case.toml").read_text().replace("[annotations]", more + "\n[annotations]")
            (d / "case.toml").write_text(toml)
        else:
            angles = np.deg2rad(np.linspace(-60, 60, n))
            cams = [
                look_at_view(900.0 * np.array([np.sin(a), 0.0, -np.cos(a)]), sdd=1200.0,
                             pixel=0.3, image_size=(512, 512), name=f"cam{i + 1}")
                for i, a in enumerate(angles)
            ]  # fmt: skip
            write_synthetic_case(d, 0, views=cams)
        rc, line = _register(d)
        print(f"{n} views ({'2 annotated' if extra else 'all annotated'}): exit {rc}, {line}")


def _defects(V: np.ndarray, F: np.ndarray):
    """(name, vertices, faces) of every defect variant of a closed mesh."""
    import trimesh

    def sphere(c, r):
        s = trimesh.creation.icosphere(2, r)
        return s.vertices + c, s.faces

    c = V[np.argmax(V[:, 2])]
    d = np.linalg.norm(V[F].mean(axis=1) - c, axis=1)
    half = F.copy()
    half[: len(F) // 2] = half[: len(F) // 2, ::-1]
    yield "ok", V, F
    yield "open, hole of 5 % of the faces", V, F[d > np.quantile(d, 0.05)]
    yield "open, one face missing", V, F[1:]
    yield "open, half of the bone", V, F[V[F].mean(axis=1)[:, 2] < np.median(V[:, 2])]
    for name, (sv, sf) in (
        ("two pieces, a sphere 40 mm away", sphere(V.mean(axis=0) + [40.0, 0, 0], 5.0)),
        ("two pieces, a sphere inside", sphere(V.mean(axis=0) + [8.0, 0, 0], 2.0)),
        ("two pieces, the bone 25 mm away", (V + [25.0, 0, 0], F)),
    ):
        yield name, np.vstack([V, sv]), np.vstack([F, sf + len(V)])
    yield "every face twice", V, np.vstack([F, F])
    yield "10 faces twice", V, np.vstack([F, F[:10]])
    yield "inward (every face flipped)", V, F[:, ::-1]
    yield "half the faces flipped", V, half


def defects(work: Path, seeds: list[int]) -> None:
    """Register each defective template; surface RMS against the truth, flags and warnings."""
    from biplanar_reg.io import read_mesh

    for seed in seeds:
        base = _base(work, seed)
        V, F = read_mesh(base / "gt/bone.ply")
        for k, (name, v, f) in enumerate(_defects(V, F)):
            d = _with_template(base, work / f"defect{k}_{seed}", v, f)
            rc, line = _register(d)
            if rc == 0:
                doc = json.loads((d / "out/result.json").read_text())
                m = doc["metrics"]
                line = (f"surface RMS {m['surface_rms_mm']:.2f} mm, vertex RMS "
                        f"{m['vertex_rms_mm']:.2f} mm, warnings {doc['warnings']}")  # fmt: skip
            print(f"seed {seed}, {name}: exit {rc}, {line}", flush=True)


def _summary(angle: float, runs: list, fails: int) -> str:
    errs = [r[0] for r in runs]
    sds = [r[1] for r in runs]
    z = np.array([r[2] for r in runs])
    cov = np.mean([r[3] for r in runs])
    flags = collections.Counter(f for r in runs for f in r[4])
    return (
        f"{angle:g} deg: {len(runs)} registered, {fails} failed; vertex RMS median "
        f"{np.median(errs):.3f} mm (max {np.max(errs):.2f}); median sd {np.median(sds):.3f} mm; "
        f"error / sd median {np.median(z):.2f}; 2-sd coverage {cov:.0%}; flags {dict(flags)}"
    )


def _scores(res, truth: np.ndarray) -> tuple:
    e = np.linalg.norm(res.vertices - truth, axis=1)
    sd = res.vertex_sd_mm
    z = np.sqrt(np.mean(e**2) / 3) / np.sqrt(np.mean(sd**2))
    kinds = {f.split("(")[0].split(":")[0] for f in res.flags}
    return (
        float(np.sqrt(np.mean(e**2))),
        float(np.median(sd)),
        z,
        np.mean(e / 3**0.5 <= 2 * sd),
        kinds,
    )


def angles(work: Path, degs: list[float], seeds: int) -> None:
    """Set-up A: the synthetic case with its two views ``deg`` apart about the bone."""
    from biplanar_reg.cases import load_case, to_view_observations
    from biplanar_reg.registration import register_views
    from biplanar_reg.simulate import write_synthetic_case
    from biplanar_reg.simulate.scenes import look_at_view

    for deg in degs:
        a, runs, fails = np.deg2rad(deg) / 2, [], 0
        cams = [
            look_at_view(900.0 * np.array([sx * np.sin(a), 0.0, -np.cos(a)]), sdd=1200.0,
                         pixel=0.3, image_size=(512, 512), name=n)
            for sx, n in ((-1.0, "cam1"), (1.0, "cam2"))
        ]  # fmt: skip
        for seed in range(seeds):
            d = work / f"angle{deg:g}_{seed}"
            if not (d / "case.toml").exists():
                write_synthetic_case(d, seed, views=cams)
            try:
                case = load_case(d)
                res = register_views(case.model, to_view_observations(case), options=case.options)
            except ValueError:
                fails += 1
                continue
            runs.append(_scores(res, case.ground_truth.vertices))
        print(_summary(deg, runs, fails), flush=True)


def angles_b(degs: list[float], trials: int) -> None:
    """Set-up B: the ``--simple`` trials of ``benchmarks/uncertainty.py`` with the views
    ``deg`` apart (radius model, truth outside its span, 6 landmarks at 1.5 px)."""
    sys.path.insert(0, str(HERE))
    import uncertainty as U

    from biplanar_reg.registration import register_views

    real_views = U.biplanar_views
    template, faces = U.reference.radius_template(1000)
    model = U.reference.radius_model(template, faces)
    for deg in degs:
        U.biplanar_views = lambda a=75.0, deg=deg: real_views(deg)
        runs, fails = [], 0
        for s in range(trials):
            views, X = U.synthetic_case(model, template, s, 6, 1.5, 0.5)
            try:
                runs.append(_scores(register_views(model, views), X))
            except ValueError:
                fails += 1
        print(_summary(deg, runs, fails), flush=True)
    U.biplanar_views = real_views


def main() -> None:
    from threadpoolctl import threadpool_limits

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=("templates", "views", "extra-views", "defects", "angles",
                                     "angles-b"))  # fmt: skip
    ap.add_argument("values", help="comma-separated settings")
    ap.add_argument("count", nargs="?", type=int, default=20, help="seeds / trials (angles)")
    ap.add_argument("--work", type=Path, help="folder for the generated cases (default: temp)")
    args = ap.parse_args()
    work = args.work or Path(tempfile.mkdtemp(prefix="input_limits_"))
    work.mkdir(parents=True, exist_ok=True)
    vals = args.values.split(",")
    with threadpool_limits(1):
        if args.what == "templates":
            templates(work, [int(v) for v in vals])
        elif args.what in ("views", "extra-views"):
            views(work, [int(v) for v in vals], args.what == "extra-views")
        elif args.what == "defects":
            defects(work, [int(v) for v in vals])
        elif args.what == "angles":
            angles(work, [float(v) for v in vals], args.count)
        else:
            angles_b([float(v) for v in vals], args.count)


if __name__ == "__main__":
    main()
