"""Old spelling of :mod:`biplanar_reg.simulate.case_folder`, kept importable.

``from biplanar_reg.cases.synthetic_case import write_synthetic_case`` was the documented import
before the synthetic scenes became the public :mod:`biplanar_reg.simulate` package; new code
imports ``from biplanar_reg.simulate import write_synthetic_case``.
"""

from ..simulate import synthetic_landmarks, write_synthetic_case

__all__ = ["write_synthetic_case", "synthetic_landmarks"]
