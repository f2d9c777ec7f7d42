"""The one registry of public tensor functions and its one sampler.

Every property test walks ``OPS``: bad input, empty batches, non-finite isolation, half
precision and aliasing (``test_reliability.py``), broadcasting across batch ranks
(``test_broadcasting.py``), float32 against float64 (``test_float32.py``), ``torch.func`` /
forward AD / ``vmap`` (``test_modes.py``) and second derivatives at the degenerate points
(``test_second_order.py``). A new public function needs one row here;
``test_reliability.test_registry_covers_the_public_api`` fails until it has one.

Each row names its arguments by *kind* (``KINDS``: the event shape and a seeded float64
sampler), so that one sampler draws every argument: batch shapes of ranks 0 to 3
(``SHAPES``), the dtype of the test, and the degenerate families (``FAMILIES``: identity,
equal poses, opposite signs, pure translations, half turns).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

import torch
from torch import Tensor

import torch_dq.dualquat as dq
from torch_dq import camera, curves, losses, quat
from torch_dq.dual import Dual

F64 = torch.float64
SHAPES = ((), (1,), (5,), (2, 5), (3, 1, 5))
# Times exactly representable in every dtype, so half-precision runs see the same times:
# both ends, the cubic rows' interior knot 0.5, and times inside the other spans.
TIMES = (0.0, 0.25, 0.5, 0.875, 1.0)
# The degenerate families of the sampler (``sample(kind, batch, gen, family)``):
# identity rotations and zero translations; every pose argument equal to the first; the
# second pose argument the antipode of the first (control points alternating in sign);
# identity rotations with random translations; half turns about random axes.
FAMILIES = ("random", "identity", "equal", "opposite", "translation", "half_turn")
POSE_KINDS = ("dq", "q", "rot", "hom", "pose7", "poses", "ctrl")


# ----------------------------------------------------------------------------- sampler

def _unit(x: Tensor) -> Tensor:
    return x / x.norm(dim=-1, keepdim=True)


def _randn(batch, gen, *event) -> Tensor:
    return torch.randn((*batch, *event), generator=gen, dtype=F64)


def _rotation(batch, gen, family: str) -> Tensor:
    """Unit quaternions ``(*batch, 4)``: uniform, identity or half turns."""
    if family in ("identity", "translation"):
        return quat.identity(batch, dtype=F64)
    if family == "half_turn":
        return torch.cat((torch.zeros((*batch, 1), dtype=F64), _unit(_randn(batch, gen, 3))), -1)
    return _unit(_randn(batch, gen, 4))


def _pose(batch, gen, family: str) -> Tensor:
    """Unit dual quaternions ``(*batch, 8)`` of the family (translations N(0, 1))."""
    t = _randn(batch, gen, 3)
    return dq.from_rt(_rotation(batch, gen, family), t * (family != "identity"))


def _twist(batch, gen, family: str) -> Tensor:
    xi = _randn(batch, gen, 6)
    if family in ("identity", "translation"):
        return xi * torch.tensor([0.0] * 3 + [float(family != "identity")] * 3, dtype=F64)
    if family == "half_turn":
        return torch.cat((math.pi * _unit(xi[..., :3]), xi[..., 3:]), -1)
    return xi


def _rotvec(batch, gen, family: str) -> Tensor:
    return _twist(batch, gen, family)[..., :3]


def _chain(batch, gen, family: str, k: int) -> Tensor:
    """``k`` poses ``(*batch, k, 8)``: equal, or alternating in sign, for those families."""
    if family in ("equal", "opposite"):
        x = _pose(batch, gen, "random")[..., None, :].expand(*batch, k, 8)
        if family == "opposite":
            x = x * torch.tensor([(-1.0) ** i for i in range(k)], dtype=F64)[:, None]
        return x.clone()
    return _pose((*batch, k), gen, family)


@dataclass(frozen=True)
class Kind:
    """An argument kind: its event shape (trailing dims) and a seeded float64 sampler."""

    event: tuple
    make: Callable  # (batch, gen, family) -> Tensor


def _scalar(batch, gen, family):
    return torch.rand(batch, generator=gen, dtype=F64)


# Camera parameters (realistic, principal point (256, 256)): jittered by 1 % in the "random"
# family, exact otherwise, so that the "identity" family's points on the optical axis and
# pixels at (256, 256) are the models' degenerate points (r = 0).
CAMERA_PARAMS = {"pinhole": (460.0, 455.0, 256.0, 256.0),
                 "pinhole-radtan": (460.0, 455.0, 256.0, 256.0, -0.28, 0.074, 2e-4, 2e-5),
                 "pinhole-equidistant": (191.0, 190.0, 256.0, 256.0, 0.0035, 7e-4, -2e-3, 2e-4),
                 "double-sphere": (158.0, 157.0, 256.0, 256.0, -0.17, 0.59)}


def _camera(model):
    def make(batch, gen, family):
        p = torch.tensor(CAMERA_PARAMS[model], dtype=F64).expand(*batch, -1)
        jitter = 0.01 * _randn(batch, gen, p.shape[-1]) * (family == "random")
        return p * (1.0 + jitter)
    return make


def _front(batch, gen, family):
    """Points up to 50 degrees off the axis at depths 0.5 to 3 (on the axis: "identity")."""
    d = 0.5 + 2.5 * torch.rand(batch, generator=gen, dtype=F64)
    if family == "identity":
        return torch.stack([0.0 * d, 0.0 * d, d], -1)
    th = math.radians(50.0) * torch.rand(batch, generator=gen, dtype=F64)
    ph = 2 * math.pi * torch.rand(batch, generator=gen, dtype=F64)
    return torch.stack([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()], -1) * d[..., None]


def _pixel(batch, gen, family):
    """Pixels in [76, 436]^2, inside every model's domain; (256, 256) for "identity"."""
    if family == "identity":
        return torch.full((*batch, 2), 256.0, dtype=F64)
    return 76.0 + 360.0 * torch.rand((*batch, 2), generator=gen, dtype=F64)


KINDS = {
    "dq": Kind((8,), _pose),
    "q": Kind((4,), lambda b, g, f: _rotation(b, g, f)),
    "rot": Kind((3, 3), lambda b, g, f: quat.to_matrix(_rotation(b, g, f))),
    "hom": Kind((4, 4), lambda b, g, f: dq.to_matrix(_pose(b, g, f))),
    "pose7": Kind((7,), lambda b, g, f: dq.to_pose7(_pose(b, g, f))),
    "poses": Kind((3, 8), lambda b, g, f: _chain(b, g, f, 3)),
    "ctrl": Kind((5, 8), lambda b, g, f: _chain(b, g, f, 5)),
    "vec": Kind((3,), lambda b, g, f: _randn(b, g, 3)),
    "dir": Kind((3,), lambda b, g, f: _unit(_randn(b, g, 3))),
    "rotvec": Kind((3,), _rotvec),
    "twist": Kind((6,), _twist),
    "scalar": Kind((), _scalar),
    "weights": Kind((3,), lambda b, g, f: torch.rand((*b, 3), generator=g, dtype=F64) + 0.1),
    **{f"cam:{m}": Kind((len(p),), _camera(m)) for m, p in CAMERA_PARAMS.items()},
    "front": Kind((3,), _front),
    "pixel": Kind((2,), _pixel),
}
EVENT = {name: kind.event for name, kind in KINDS.items()}


def sample(kind: str, batch, gen, family: str = "random") -> Tensor:
    """A valid float64 argument of ``kind`` with batch shape ``batch``, from ``family``."""
    return KINDS[kind].make(tuple(batch), gen, family)


def sample_args(op: Op, batch, gen, family: str = "random", dtype=F64) -> list[Tensor]:
    """The arguments of ``op`` with batch shape ``batch`` (one shape, or one per argument),
    from ``family`` and in ``dtype``. ``equal``: every pose argument of the first's kind is
    the first; ``opposite``: the second is the first's antipode."""
    batches = batch if batch and isinstance(batch[0], tuple) else [batch] * len(op.args)
    args = [sample(kind, b, gen, family) for (_, kind), b in zip(op.args, batches, strict=True)]
    kinds = [kind for _, kind in op.args]
    if family in ("equal", "opposite") and kinds[0] in POSE_KINDS:
        for i in range(1, len(args)):
            if kinds[i] == kinds[0] and args[i].shape == args[0].shape:
                args[i] = args[0].clone() * (-1.0 if family == "opposite" and i == 1 else 1.0)
    return [a.to(dtype) for a in args]


# ----------------------------------------------------------------------------- the rows

@dataclass(frozen=True)
class Op:
    """One public function (or one option set of it) and what the properties need."""

    name: str  # public name, as in error messages
    fn: Callable  # called positionally with the tensors of ``args``
    args: tuple  # ((argument name, kind), ...)
    variant: str = ""  # options of a second row for the same function
    curve: bool = False  # output (..., T, 8): dependence is per time and up to sign
    signed: bool = False  # outputs are (dual) quaternions, equal up to their sign
    # float32 bound: max |f32 - f64| / max(1, |f64|) on the sampler's float32-rounded inputs
    f32: float | None = None
    periodic: bool = False  # outputs are angles: an error of 2 pi - e is an error of e
    # Families where the function has no second derivative (a cone, or a choice of sign
    # or branch that jumps there), skipped by the second-order check, with the reason.
    kinks: dict = field(default_factory=dict)

    @property
    def id(self) -> str:
        return f"{self.name}({self.variant})" if self.variant else self.name

    @property
    def differentiable(self) -> bool:
        return self.name != "dualquat.is_unit"


def times(like) -> Tensor:
    """``TIMES`` in the dtype and on the device of ``like`` (the curve rows' evaluation
    times)."""
    if isinstance(like, Tensor):
        return torch.tensor(TIMES, dtype=like.dtype, device=like.device)
    return torch.tensor(TIMES, dtype=F64)


def outs(r) -> list[Tensor]:
    """Flat list of the output tensors of a call (a ``Dual`` gives its two parts)."""
    if isinstance(r, Tensor):
        return [r]
    if isinstance(r, Dual):
        return [r.real, r.dual]
    return [o for x in r for o in outs(x)]


Q2, DQ2 = (("a", "q"), ("b", "q")), (("a", "dq"), ("b", "dq"))
XDX = (("x", "dq"), ("dx", "dq"), ("ddx", "dq"))
CTRL = (("ctrl", "ctrl"),)
# Cones: an angle or a distance at zero (no second derivative there).
CONE_EQUAL = {"equal": "a cone at zero", "opposite": "a cone at zero",
              "identity": "a cone at zero", "translation": "a cone at zero"}
SIGN_AT_HALF_TURN = {"half_turn": "w = 0: the canonical sign (w >= 0) jumps"}

# float32 bounds of the camera rows (measured x 1.5): project's pixels are off by about an
# ulp of the principal point (256: 3e-5 px), large relative to pixels near 0 (u = f a + c
# cancels); unproject's rays (unit) by a few ulps.
CAMERA_F32 = {"project": {"pinhole": 4.2e-5, "pinhole-radtan": 8e-5,
                          "pinhole-equidistant": 5.2e-7, "double-sphere": 5.9e-7},
              "unproject": {"pinhole": 2.2e-7, "pinhole-radtan": 2.2e-7,
                            "pinhole-equidistant": 4e-7, "double-sphere": 3.8e-7}}

OPS = [
    Op("quat.mul", quat.mul, Q2, signed=True, f32=2e-7),
    Op("quat.conj", quat.conj, (("q", "q"),), f32=0.0),
    Op("quat.inv", quat.inv, (("q", "q"),), f32=2.2e-7),
    Op("quat.norm", quat.norm, (("q", "q"),), f32=1.4e-7),
    Op("quat.normalize", quat.normalize, (("q", "q"),), f32=1.4e-7),
    Op("quat.dot", quat.dot, Q2, f32=1.8e-7),
    Op("quat.rotate", quat.rotate, (("q", "q"), ("v", "vec")), f32=1.1e-6),
    Op("quat.slerp", quat.slerp, (("q0", "q"), ("q1", "q"), ("t", "scalar")), signed=True,
       f32=5e-7),
    Op("quat.slerp", lambda a, b, t: quat.slerp(a, b, t, shortest=False),
       (("q0", "q"), ("q1", "q"), ("t", "scalar")), "shortest=False", signed=True, f32=5e-7,
       kinks={"opposite": "q1 = -q0 without the short way: no unique path"}),
    Op("quat.exp", quat.exp, (("q", "q"),), signed=True, f32=5e-7),
    Op("quat.log", quat.log, (("q", "q"),), f32=8e-7),
    Op("quat.from_matrix", quat.from_matrix, (("R", "rot"),), signed=True, f32=2e-7,
       kinks=SIGN_AT_HALF_TURN),
    Op("quat.to_matrix", quat.to_matrix, (("q", "q"),), f32=6e-7),
    Op("quat.from_axis_angle", quat.from_axis_angle, (("axis", "dir"), ("angle", "scalar")),
       signed=True, f32=8e-8),
    Op("quat.to_axis_angle", quat.to_axis_angle, (("q", "q"),), f32=4e-7,
       kinks={"identity": "no axis at a zero angle", "translation": "no axis at a zero angle",
              **SIGN_AT_HALF_TURN}),
    Op("quat.from_rotvec", quat.from_rotvec, (("rotvec", "rotvec"),), signed=True, f32=3e-7),
    Op("quat.to_rotvec", quat.to_rotvec, (("q", "q"),), f32=8e-7, kinks=SIGN_AT_HALF_TURN),
    Op("quat.from_euler", lambda a: quat.from_euler(a, "ZXZ"), (("angles", "vec"),),
       signed=True, f32=3e-7),
    Op("quat.from_euler", lambda a: quat.from_euler(a, "xyz"), (("angles", "vec"),), "xyz",
       signed=True, f32=3e-7),
    Op("quat.to_euler", lambda q: quat.to_euler(q, "zxz"), (("q", "q"),), periodic=True,
       f32=1e-6, kinks={"identity": "gimbal lock", "translation": "gimbal lock"}),
    Op("quat.to_euler", lambda q: quat.to_euler(q, "XYZ"), (("q", "q"),), "XYZ",
       periodic=True, f32=1e-6),
    Op("quat.from_xyzw", quat.from_xyzw, (("q", "q"),), f32=0.0),
    Op("quat.to_xyzw", quat.to_xyzw, (("q", "q"),), f32=0.0),
    Op("dualquat.mul", dq.mul, DQ2, signed=True, f32=5e-7),
    Op("dualquat.conj", dq.conj, (("x", "dq"),), f32=0.0),
    Op("dualquat.conj_dual", dq.conj_dual, (("x", "dq"),), f32=0.0),
    Op("dualquat.conj_full", dq.conj_full, (("x", "dq"),), f32=0.0),
    Op("dualquat.inv", dq.inv, (("x", "dq"),), signed=True, f32=8e-7),
    Op("dualquat.norm", dq.norm, (("x", "dq"),), f32=1.7e-7),
    Op("dualquat.dot", dq.dot, DQ2, f32=3e-7),
    Op("dualquat.normalize", dq.normalize, (("x", "dq"),), signed=True, f32=5e-7),
    Op("dualquat.is_unit", dq.is_unit, (("x", "dq"),)),
    Op("dualquat.from_rt", dq.from_rt, (("q", "q"), ("t", "vec")), signed=True, f32=2.4e-7),
    Op("dualquat.to_rt", dq.to_rt, (("x", "dq"),), f32=3.4e-7),
    Op("dualquat.from_matrix", dq.from_matrix, (("T", "hom"),), signed=True, f32=4e-7,
       kinks=SIGN_AT_HALF_TURN),
    Op("dualquat.to_matrix", dq.to_matrix, (("x", "dq"),), f32=7e-7),
    Op("dualquat.from_pose7", dq.from_pose7, (("p", "pose7"),), signed=True, f32=2.5e-7),
    Op("dualquat.to_pose7", dq.to_pose7, (("x", "dq"),), f32=3.4e-7),
    Op("dualquat.from_screw", dq.from_screw,
       (("axis", "dir"), ("moment", "vec"), ("theta", "scalar"), ("d", "scalar")),
       signed=True, f32=2.2e-7),
    Op("dualquat.to_screw", dq.to_screw, (("x", "dq"),), f32=2.3e-6,
       kinks={"identity": "no axis at rest", "translation": "a pure translation's axis",
              **SIGN_AT_HALF_TURN}),
    Op("dualquat.exp", dq.exp, (("xi", "twist"),), signed=True, f32=1.2e-6),
    Op("dualquat.log", dq.log, (("x", "dq"),), f32=2e-6, kinks=SIGN_AT_HALF_TURN),
    Op("dualquat.apply", dq.apply, (("x", "dq"), ("points", "vec")), f32=1.2e-6),
    Op("dualquat.apply_line", dq.apply_line,
       (("x", "dq"), ("direction", "dir"), ("moment", "vec")), f32=1.6e-6),
    Op("dualquat.angle", dq.angle, DQ2, f32=2e-6, kinks=CONE_EQUAL),
    Op("dualquat.sclerp", dq.sclerp, (*DQ2, ("t", "scalar")), signed=True, f32=1.2e-6),
    # No float32 bound: ill-conditioned where the real parts are nearly opposite (documented).
    Op("dualquat.sclerp", lambda a, b, t: dq.sclerp(a, b, t, shortest=False),
       (*DQ2, ("t", "scalar")), "shortest=False", signed=True,
       kinks={"opposite": "b = -a without the short way: no unique path"}),
    Op("dualquat.dlb", dq.dlb, (("weights", "weights"), ("xs", "poses")), signed=True,
       f32=9e-7),
    Op("losses.rotation_angle", losses.rotation_angle, DQ2, f32=4e-7, kinks=CONE_EQUAL),
    Op("losses.squared_rotation_angle", losses.squared_rotation_angle, DQ2, f32=7e-7),
    Op("losses.translation_error", losses.translation_error, DQ2, f32=7e-7,
       kinks={"equal": "a cone at zero", "opposite": "a cone at zero",
              "identity": "a cone at zero"}),
    Op("losses.pose_loss", lambda a, b: losses.pose_loss(a, b, reduction="none"), DQ2,
       f32=9e-7),
    Op("curves.bezier", lambda c: curves.bezier(c, times(c)), CTRL, curve=True, f32=1.5e-6),
    Op("curves.bspline", lambda c: curves.bspline(c, times(c), degree=2), CTRL, curve=True,
       f32=1.5e-6),
    Op("curves.bspline", lambda c: curves.bspline(c, times(c), form="cumulative"), CTRL,
       "cumulative", curve=True, f32=1.5e-6),
    Op("curves.bspline", lambda c: curves.bspline(c, times(c), form="split"), CTRL,
       "split", curve=True, f32=1.5e-6),
    Op("curves.twists", curves.twists, (("x", "dq"), ("dx", "dq")), f32=7e-7),
    Op("curves.twists", lambda x, v: curves.twists(x, v, frame="spatial"),
       (("x", "dq"), ("dx", "dq")), "spatial", f32=7e-7),
    Op("curves.screw_axis", curves.screw_axis, (("omega", "vec"), ("v", "vec")), f32=3.3e-6),
    # Jerks of random (not smooth) control polygons reach 1e3: ill-conditioned in float32.
    Op("curves.bezier_derivatives", lambda c: curves.bezier_derivatives(c, times(c), 3), CTRL,
       curve=True, f32=9e-4),
    Op("curves.bspline_derivatives",
       lambda c: curves.bspline_derivatives(c, times(c), 2, degree=2), CTRL, curve=True,
       f32=4e-5),
    Op("curves.bspline_derivatives",
       lambda c: curves.bspline_derivatives(c, times(c), 3, form="cumulative"), CTRL,
       "cumulative", curve=True, f32=6e-4),
    Op("curves.bspline_derivatives",
       lambda c: curves.bspline_derivatives(c, times(c), 3, form="split"), CTRL,
       "split", curve=True, f32=6e-4),
    Op("curves.kinematics", curves.kinematics, XDX, f32=1.1e-6),
    Op("curves.kinematics", lambda x, v, a: curves.kinematics(x, v, a, frame="body"), XDX,
       "body", f32=2.2e-6),
    Op("curves.imu", curves.imu, XDX, f32=4.7e-6),
    *(Op(f"camera.{f.__name__}", lambda p, x, f=f, m=m: f(m, p, x)[0],
         (("params", f"cam:{m}"), ("points" if f is camera.project else "pixels",
                                   "front" if f is camera.project else "pixel")),
         "" if m == "pinhole-radtan" else m, f32=f32)
      for f in (camera.project, camera.unproject)
      for m, f32 in CAMERA_F32[f.__name__].items()),
]
IDS = [op.id for op in OPS]
DIFFERENTIABLE = [op for op in OPS if op.differentiable]
# Functions of no tensor argument or of a callable, and camera's table and value class:
# tested apart, not rows of OPS.
FACTORIES = {"quat.identity", "dualquat.identity", "curves.clamped_uniform_knots",
             "curves.velocity", "camera.MODELS", "camera.Camera"}
MODULES = {"quat": quat, "dualquat": dq, "curves": curves, "losses": losses, "camera": camera}


def op(op_id: str) -> Op:
    """The row of ``OPS`` with this id (``name`` or ``name(variant)``)."""
    return next(o for o in OPS if o.id == op_id)


def flat(o: Op):
    """``o.fn`` returning a tuple of tensors (a ``Dual`` as its two parts, nested tuples
    flattened): the pytree that ``torch.func`` transforms take."""
    return lambda *a: tuple(outs(o.fn(*a)))
