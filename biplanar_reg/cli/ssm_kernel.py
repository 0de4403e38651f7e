"""``biplanar-reg ssm augment``: a shape model with a Gaussian-process deformation kernel
(docs/ssm.md, "ssm augment")."""

from __future__ import annotations

import argparse
from pathlib import Path

from ._parsing import Wanted, emit, number

__all__: list[str] = []


def build_augment(p: argparse.ArgumentParser, wanted: Wanted) -> None:
    p.add_argument("model", help="shape model file (.npz or statismo .h5)")
    p.add_argument("-o", "--output", required=True, help="augmented model (.npz or .h5)")
    p.add_argument(
        "--kernel",
        choices=("gaussian", "gaussian-normal"),
        default="gaussian",
        help="deformation kernel: 3-D Gaussian (default) or Gaussian along the surface normals",
    )
    p.add_argument(
        "--width",
        type=number(float, 0, 1e5, above=True),
        default=20.0,
        help="kernel width in mm: how far a deformation reaches (default 20)",
    )
    p.add_argument(
        "--amplitude",
        type=number(float, 0, 1e4, above=True),
        default=1.0,
        help="kernel amplitude in mm: the prior SD of each coordinate's displacement (default 1)",
    )
    p.set_defaults(func=_cmd_augment)


def _cmd_augment(args: argparse.Namespace) -> int:
    from ..ssm.gaussian_process import augment_model
    from ..ssm.model import ShapeModel

    out = Path(args.output)
    if out.suffix.lower() not in (".h5", ".hdf5", ".npz"):
        raise ValueError(f"{out}: the output must end in .npz, .h5 or .hdf5")
    model = ShapeModel.load(args.model)
    try:
        augmented = augment_model(model, args.width, args.amplitude, kernel=args.kernel)
    except ValueError as exc:
        raise ValueError(f"{args.model}: {exc}") from None
    augmented.save(out)
    info = augmented.provenance["gaussian_process"]
    n_kernel = augmented.n_modes - info["ssm_modes"]
    emit(
        args,
        {"output": str(out), "n_vertices": augmented.n_vertices, **info, "kernel_modes": n_kernel},
        [
            f"wrote {out}: {info['ssm_modes']} shape-model modes + {n_kernel} {args.kernel} "
            f"kernel modes (width {args.width:g} mm, amplitude {args.amplitude:g} mm, "
            f"{100 * info['captured']:.1f} % of the kernel's variance)"
        ],
    )
    return 0
