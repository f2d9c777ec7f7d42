r"""Camera values read from users (private): the numbers of a Kalibr ``camchain.yaml``
entry and a resolution, and the checks of measured pixels against a camera (normalised
coordinates passed as pixels, pixels outside the image). ``torch_dq.camera.Camera`` and the
estimation terms use them.
"""

from __future__ import annotations

import contextlib
import math
import numbers
from collections.abc import Sequence

from torch import Tensor

from . import _checks

__all__ = ["FROM_KALIBR", "KALIBR", "LONGEST_LINE_DELAY", "kalibr_list", "normalised_hint",
           "numbers_list", "outside", "seconds_hint", "width_height", "yaml_number"]

# Kalibr's (camera_model, distortion_model) of each model, and back.
KALIBR = {"pinhole": ("pinhole", "none"), "pinhole-radtan": ("pinhole", "radtan"),
          "pinhole-equidistant": ("pinhole", "equidistant"), "double-sphere": ("ds", "none")}
FROM_KALIBR = {names: model for model, names in KALIBR.items()}
# A rolling shutter's delay per image row beyond any camera's (1 ms reads 480 rows in 0.48
# s): a longer one is in another unit (microseconds?), warned of where it is read.
LONGEST_LINE_DELAY = 1e-3


def seconds_hint(value: float, limit: float) -> str:
    """``" milliseconds? (5 of them: 0.005 s)"``: the coarsest unit of
    ``_checks.TIME_UNITS`` that brings ``value`` (read as seconds) within ``limit``, or
    ``""`` where none does."""
    fit = [(n, f) for n, f in reversed(_checks.TIME_UNITS) if abs(value) * f <= limit]
    return f" {fit[0][0]}? ({value:g} of them: {value * fit[0][1]:.3g} s)" if fit else ""


def numbers_list(fn: str, name: str, value, count: int) -> list[float]:
    """A list of ``count`` finite real numbers (a list, tuple, 1-D array or tensor)."""
    value = _checks.listed(value)
    ok = isinstance(value, Sequence) and not isinstance(value, str) and len(value) == count
    ok = ok and all(isinstance(v, numbers.Real) and not isinstance(v, bool)
                    and math.isfinite(v) for v in value)
    if not ok:
        want = f"a list of {count} finite numbers" if count else "empty (or zeros): no distortion"
        _checks.fail(fn, f"expected {name} to be {want}, got {value!r}")
    return [float(v) for v in value]


def normalised_hint(pixels: Tensor, params: Tensor) -> str | None:
    """A sentence where ``(M, 2)`` measured pixels look like normalised image coordinates
    (``x / z``, ``y / z``) of a camera with the ``(P,)`` params: all of them within 4 of
    ``(0, 0)``, the top-left pixel, while the principal point lies over 20 px from it;
    else None. (A target seen in pixels is spread over more than a few pixels and sits
    near the image's corner only by accident.)"""
    if pixels.numel() == 0:
        return None
    reach = float(pixels.detach().abs().max())
    centre = float(params.detach()[2:4].abs().min())
    if reach >= 4.0 or centre <= 20.0:
        return None
    return (f"the pixels all lie within {reach:.3g} of (0, 0) while the principal point is "
            f"at ({float(params[2]):.6g}, {float(params[3]):.6g}): they look like normalised "
            f"coordinates (x/z, y/z), not pixels; project them with the camera's "
            f"intrinsics (u = fu x/z + cu, v = fv y/z + cv, then the distortion)")


def outside(pixels: Tensor, resolution: tuple[int, int],
             slack: float = 0.0) -> tuple[str, float, str] | None:
    """Where ``(M, 2)`` measured pixels leave an image of ``resolution`` ``(width, height)``:
    ``(0, 0)`` is the top-left pixel's centre, so ``u`` in ``[-0.5, width - 0.5]`` and ``v``
    in ``[-0.5, height - 0.5]``, each widened by ``slack`` times the image's size. None when
    all lie inside, else the axis (``"u"`` or ``"v"``), the farthest value and the range
    expected (text)."""
    if pixels.numel() == 0:
        return None
    for axis, name, size in ((0, "u", resolution[0]), (1, "v", resolution[1])):
        lo, hi = float(pixels[:, axis].min()), float(pixels[:, axis].max())
        low, high = -0.5 - slack * size, size - 0.5 + slack * size
        if lo < low or hi > high:
            return name, lo if lo < low else hi, f"{name} in [{low:.6g}, {high:.6g}]"
    return None


def yaml_number(value):
    """``value``, or the number a string reads as: YAML 1.1 (PyYAML) reads ``2e-4`` (no dot)
    as a string, and a quoted ``'6'`` is one; an integral string reads as an ``int``."""
    for kind in (int, float) if isinstance(value, str) else ():
        with contextlib.suppress(ValueError):
            return kind(value)
    return value


def kalibr_list(value) -> list | object:
    """A Kalibr list (or 1-D array) with ``yaml_number`` applied (others as they are)."""
    if isinstance(value := _checks.listed(value), Sequence) and not isinstance(value, str):
        return [yaml_number(v) for v in value]
    return value


def width_height(fn: str, res) -> tuple[int, int]:
    """``(width, height)``: two positive ints."""
    res = _checks.listed(res)
    if (not isinstance(res, Sequence) or isinstance(res, str) or len(res) != 2
            or not all(isinstance(n, numbers.Integral) and not isinstance(n, bool)
                       and int(n) > 0 for n in res)):
        _checks.fail(fn, f"expected resolution to be (width, height), two positive ints, "
                         f"got {res!r}")
    return int(res[0]), int(res[1])


