r"""Continuous-time estimation: trajectories from the measurements of several sensors.

A trajectory (a :class:`torch_dq.nn.BSpline` or :class:`torch_dq.nn.Bezier`) is estimated
from timestamped measurements, each kind a term (:class:`Poses`, :class:`Positions`,
:class:`RelativePoses`, :class:`Gyro`, :class:`Accel`; :mod:`~torch_dq.fitting.terms`) with
its noise, robust kernel (:mod:`~torch_dq.fitting.robust`) and nuisance parameters
(:class:`Free`; :mod:`~torch_dq.fitting.nuisance`), by :func:`estimate`
(:mod:`~torch_dq.fitting.estimate`), which returns an :class:`Estimate` with the
uncertainties (:mod:`~torch_dq.fitting.uncertainty`). :func:`fit` refines a curve on poses
alone (Levenberg-Marquardt as :func:`estimate` with one :class:`Poses` term, or a torch
optimizer).

Example (poses at 20 Hz and a gyroscope at 200 Hz with a bias):
    >>> import torch_dq.dualquat as dq
    >>> from torch_dq.nn import BSpline
    >>> f64 = torch.float64
    >>> xi = torch.tensor([0.0, 0.3, 1.0, 0.5, 0.0, 0.1], dtype=f64)  # rad/s, m/s
    >>> tc = torch.linspace(0.0, 4.0, 81, dtype=f64)
    >>> ti = torch.linspace(0.0, 4.0, 801, dtype=f64)
    >>> cam = Poses(tc, dq.exp(tc[:, None] * xi), rot_sigma=1e-3, trans_sigma=1e-3)
    >>> gyro = Gyro(ti, xi[:3].expand(801, 3) + torch.tensor([0.01, 0.0, -0.02], dtype=f64),
    ...             sigma=1e-3, bias=True)
    >>> spline = BSpline.from_dualquats(dq.exp(tc[:, None] * xi), tc, n_ctrl=23)
    >>> est = estimate(spline, [cam, gyro], verbose=False)
    >>> [round(v, 3) for v in gyro.bias.tolist()]
    [0.01, 0.0, -0.02]
"""

import torch  # noqa: F401  (the examples' namespace)

from .._spacing import choose_knot_spacing
from .._start import bspline_basis, check_determined, least_squares_start
from .._start import check_sample_times as check_times
from .estimate import estimate
from .fit import FitHistory, fit
from .nuisance import Free
from .robust import chi_quantile
from .terms import Accel, Gyro, Poses, Positions, RelativePoses, Term
from .uncertainty import Estimate

__all__ = ["Accel", "Estimate", "FitHistory", "Free", "Gyro", "Poses", "Positions",
           "RelativePoses", "Term", "bspline_basis", "check_determined", "check_times",
           "chi_quantile", "choose_knot_spacing", "estimate", "fit", "least_squares_start"]
