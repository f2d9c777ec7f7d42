"""The figure of docs/bspline_forms.md: linear acceleration of both cubic B-spline forms
across a knot.

Run from the repository root: ``python docs/figures/forms_acceleration.py`` (writes
``docs/figures/forms_acceleration.png``; matplotlib needed).
"""

import pathlib

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

import torch_dq.dualquat as dq  # noqa: E402
from torch_dq import curves  # noqa: E402

OUT = pathlib.Path(__file__).with_suffix(".png")
F64 = torch.float64


def control_points() -> torch.Tensor:
    """Seven poses: a random walk of screw steps (rotations of ~80 degrees per step)."""
    g = torch.Generator().manual_seed(1)
    steps = torch.randn(6, 6, generator=g, dtype=F64) * torch.tensor([0.8] * 3 + [1.0] * 3,
                                                                        dtype=F64)
    x = [dq.identity(dtype=F64)]
    for xi in dq.exp(steps):
        x.append(dq.mul(x[-1], xi))
    return torch.stack(x)


def acceleration(ctrl, knots, t, form):
    """Linear acceleration ``(T, 3)`` (world axes) of the cubic B-spline of ``form``."""
    jet = curves.bspline_derivatives(ctrl, t, order=2, knots=knots, form=form)
    return curves.kinematics(*jet).linear_acceleration


def main() -> None:
    ctrl = control_points()
    knots = torch.arange(ctrl.shape[0] + 4, dtype=F64)  # uniform, domain [3, 7]
    t = torch.linspace(3.0, 7.0, 801, dtype=F64)
    at = torch.tensor([5.0 - 1e-9, 5.0 + 1e-9], dtype=F64)
    jump = acceleration(ctrl, knots, at, "de_boor").diff(dim=0)[0].abs()
    k = int(jump.argmax())  # the component that jumps most at the knot t = 5
    zoom = torch.linspace(4.97, 5.03, 601, dtype=F64)
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    for form, style in (("de_boor", "-"), ("cumulative", "--")):
        axes[0].plot(t, acceleration(ctrl, knots, t, form).norm(dim=-1), style, label=form)
        axes[1].plot(zoom, acceleration(ctrl, knots, zoom, form)[:, k], style, label=form)
    axes[0].set_title("|linear acceleration| over the domain")
    axes[1].set_title(f"its {'xyz'[k]} component across the knot t = 5 (zoomed)")
    for ax, knot_lines in ((axes[0], (4.0, 5.0, 6.0)), (axes[1], (5.0,))):
        for u in knot_lines:
            ax.axvline(u, color="0.8", lw=0.8, zorder=0)
        ax.set_xlabel("t (uniform knots: interior knots at 4, 5, 6)")
        ax.legend(fontsize=8)
    fig.suptitle("Cubic B-spline on the same control poses: the acceleration of De Boor's form "
                 "jumps at the knots (C1), the cumulative form's is continuous (C2)",
                 fontsize=9)
    fig.tight_layout()
    fig.savefig(OUT, dpi=110)
    print(f"wrote {OUT}; De Boor's jump at t = 5: {jump.tolist()}")


if __name__ == "__main__":
    main()
