r"""Continuous-time estimation: trajectories from the measurements of several sensors.

A trajectory (a :class:`torch_dq.nn.BSpline` or :class:`torch_dq.nn.Bezier`, ``x(t) = (R(t),
p(t))`` body to world) is estimated by :func:`estimate` from timestamped measurements, each
kind a term (a :class:`torch.nn.Module` holding its data, noise and nuisance parameters);
:func:`estimate` returns an :class:`Estimate` with the uncertainties. :func:`fit` refines a
curve on poses alone (Levenberg-Marquardt as :func:`estimate` with one :class:`Poses` term,
or a torch optimizer minimising that term's cost).

**Terms.** Residuals are predicted minus measured, divided by the sigmas (required,
keyword-only: a float or one per axis). ``t' = t + dt`` is a sample's time in the
trajectory's clock (``dt`` its term's ``time_offset``).

============== ==================================== =========================================
term           prediction                           residual frame
============== ==================================== =========================================
Poses          ``x(t') e`` (sensor mount ``e``)     rotation vector of ``R_m^T R R_e``
                                                    (sensor axes), translation (world)
Positions      ``R(t') l + p(t')`` (lever arm)      world
RelativePoses  ``x(t'_from)^-1 x(t'_to)``           rotation: to-frame, translation: from-frame
Gyro           ``R^T w + b_g``                      body
Accel          ``R^T (a - g) + b_a``                body
Reprojections  ``project((T^-1 x(t') e)^-1 p)``,    pixels (:mod:`torch_dq.camera`)
               ``t' = t + dt + line_delay * v``
============== ==================================== =========================================

**Nuisance parameters** (``extrinsic``, ``lever_arm``, ``bias``, ``gravity``,
``time_offset``; a camera's ``target``, ``intrinsics`` and ``line_delay``): ``None`` /
``False`` absent, a tensor or float fixed, ``True`` / ``"estimate"`` estimated from a
default start, a :class:`Free` estimated from its start with an optional Gaussian prior; one
:class:`Free` given to several terms is one parameter. The time offset and the line delay
move the samples' times (a term declares such parameters and their rates ``dt'_i /
d theta``, :meth:`Term.time_rates`): the solver chains them through the curve's time
derivative, and the domain check widens by what their bounds reach. Each is stepped, and its
uncertainty reported, in a chart (one class per kind, ``torch_dq.fitting._charts``):

============  ==========  ====  ================================================
kind          value       dim   chart
============  ==========  ====  ================================================
bias, lever   ``(3,)``    3     ``v + delta``
time_offset   ``()``      1     ``dt + delta`` (seconds; bounded by
                                ``max_time_offset``)
extrinsic     ``(8,)``    6     ``e exp(delta)`` (body-frame twist); a target's pose
                                likewise
intrinsics    ``(P,)``    P     ``params + delta`` (the camera model's parameters)
line_delay    ``()``      1     ``l + delta`` (seconds per row, in ``[0, max_line_delay]``)
gravity       ``(3,)``    2     ``Exp(B delta) g``, ``B`` an orthonormal basis of the
                                plane orthogonal to ``g`` (its norm is kept; its standard
                                deviations are reported in world axes, ``(3,)``)
============  ==========  ====  ================================================

**Robust kernels** on a sample's whitened residual norm ``s``: ``None`` (:math:`s^2`),
``"huber"`` (:math:`s^2` up to ``k``, :math:`2 k s - k^2` beyond) and ``"cauchy"``
(:math:`k^2 \log(1 + s^2 / k^2)`), with the default ``k`` the 95 % quantile of the chi
distribution of the residual's dimension (:func:`chi_quantile`: 2.7955 for 3, 3.5485 for 6);
:func:`estimate` applies them by iteratively reweighted least squares.

**Batches.** Control points ``(B, n, 8)`` with terms whose data carry the leading ``B``
(times ``(B, N)`` of their own or shared ``(N,)``; ``mask`` for unequal counts) are ``B``
independent problems solved together, with per-problem damping and stopping. A larger batch
shards across processes (or GPUs) without communication during the solve: each process
estimates its rows and the results are gathered with ``torch.distributed.all_gather``
(``tests/test_estimation_distributed.py`` runs it on two CPU processes with the gloo
backend).

**Jacobians** are exact: a pose of a degree-``p`` B-spline in a knot span depends on the
span's ``p + 1`` control points and knots only, i.e. it is the value of a one-span layer; each
sample gets its own copy of its span's control points, moved by its own step, and one
reverse pass over ``k`` copies gives every sample's ``k`` Jacobian rows through the layers'
public ``derivatives`` (spans with the same knot pattern share a layer).

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
    >>> [round(v, 3) + 0.0 for v in gyro.bias.tolist()]  # + 0.0: no "-0.0"
    [0.01, 0.0, -0.02]
"""

import torch  # noqa: F401  (the examples' namespace)

from .._start import bspline_basis, check_determined, least_squares_start  # noqa: F401
from .._start import check_sample_times as check_times  # noqa: F401
from ._camera import Reprojections
from ._estimate import estimate
from ._fit import FitHistory, fit
from ._imu import Accel, Gyro
from ._knots import choose_knot_spacing
from ._nuisance import Free
from ._robust import chi_quantile
from ._terms import Options, Poses, Positions, RelativePoses, Term
from ._uncertainty import Estimate

for _obj in (Accel, Estimate, FitHistory, Free, Gyro, Options, Poses, Positions,
             RelativePoses, Reprojections, Term, chi_quantile, estimate, fit):
    _obj.__module__ = __name__  # the public home of the names (and of their documentation)
del _obj

# bspline_basis, check_determined, check_times and least_squares_start stay importable from
# here (0.2's names); they are documented where they live, torch_dq._start.
__all__ = ["Accel", "Estimate", "FitHistory", "Free", "Gyro", "Options", "Poses", "Positions",
           "RelativePoses", "Reprojections", "Term", "chi_quantile", "choose_knot_spacing",
           "estimate", "fit"]
