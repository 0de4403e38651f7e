"""The "relaxation not tight" flag: certificate and relaxation gap against the vertex error.

For seeded ``boosting_case`` problems of the synthetic bone (truth = its 8 modes, the modes from
``--modes`` on scaled by ``--outside``; the model keeps the first ``--modes``) prints one line per
seed: the last SDP certificate, the gap between the rounded relaxation and the returned fit
(:func:`biplanar_reg.registration.register.relaxation_gap_px`, px), the vertex RMS (mm) and the
model floor (mm). Used to set ``relaxation_flag_px`` (docs/registration.md, Measured).

Usage::

    python benchmarks/relaxation_flag.py MODES LANDMARKS_PER_VIEW SILHOUETTES(0/1) NOISE_PX
        FIRST_SEED END_SEED OUTSIDE
    e.g. python benchmarks/relaxation_flag.py 8 3 1 0.5 0 8 1   (in span, with outlines)
"""

from __future__ import annotations

import sys

import numpy as np
from robust_landmarks import model_floor
from threadpoolctl import threadpool_limits

from biplanar_reg.registration import RegistrationOptions, register_views
from biplanar_reg.registration.problem import make_problem
from biplanar_reg.registration.register import relaxation_gap_px
from biplanar_reg.simulate import boosting_case, synthetic_bone_model
from biplanar_reg.ssm.model import ShapeModel


def main() -> None:
    modes, per_view, sil = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "1"
    noise, first, end, outside = (
        float(sys.argv[4]),
        int(sys.argv[5]),
        int(sys.argv[6]),
        float(sys.argv[7]),
    )
    bone = synthetic_bone_model(8, seed=0, resolution=(40, 32))
    m = bone.modes.copy()
    m[modes:] *= outside
    full = ShapeModel(bone.mean, m, faces=bone.faces)
    model = ShapeModel(bone.mean, bone.modes[:modes], faces=bone.faces)
    with threadpool_limits(1):
        for seed in range(first, end):
            views, truth = boosting_case(
                full,
                seed,
                fraction=0.8,
                noise_px=noise,
                outline_noise_px=0.5,
                landmarks_per_view=per_view,
            )
            res = register_views(model, views, silhouettes=sil)
            p = make_problem(model, views, RegistrationOptions(), False, lambda msg: None)
            X = truth[3]
            err = float(np.sqrt(np.mean(np.sum((res.vertices - X) ** 2, 1))))
            print(
                f"modes {modes} landmarks {per_view} silhouettes {int(sil)} seed {seed}: "
                f"certificate {res.certificate:.3g} gap {relaxation_gap_px(p, res.gsft):.3g} px "
                f"vertex RMS {err:.3f} mm floor {model_floor(model, X):.3f} mm",
                flush=True,
            )


if __name__ == "__main__":
    main()
