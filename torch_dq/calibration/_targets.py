r"""Calibration targets: Kalibr's AprilGrid and checkerboard, their points and yaml files.

Target frame (Kalibr's): the board is the plane ``Z = 0``, ``X`` to the right and ``Y`` up
as the printed board is seen from the front, so that ``Z`` points out of the board, towards
a camera looking at it.

* AprilGrid (Kalibr's ``aprilgrid``): ``rows x cols`` tags of the family 36h11 with a 2-bit
  black border; tag ids row by row from the bottom-left tag (``id = row * cols + col``); the
  edge of a tag is ``tag_size`` metres, the gap between two tags ``tag_size * tag_spacing``
  (the pitch is ``tag_size * (1 + tag_spacing)``); tag 0's lower-left corner is the origin.
  Point ``4 * id + k`` is corner ``k`` of tag ``id``: 0 lower-left, 1 lower-right,
  2 upper-right, 3 upper-left (counter-clockwise seen from the front).
* Checkerboard (Kalibr's ``checkerboard``): ``rows x cols`` inner corners; point
  ``r * cols + c`` is ``(row_spacing * r, col_spacing * c, 0)``, as Kalibr's
  ``GridCalibrationTargetCheckerboard::createGridPoints`` writes it (the row index along
  ``X``).
"""

from __future__ import annotations

import math
import numbers
import os
from dataclasses import dataclass

import torch
from torch import Tensor

from .. import _checks
from .._camera_values import yaml_number

__all__ = ["Target", "aprilgrid", "checkerboard", "read_target"]

KINDS = ("aprilgrid", "checkerboard")

#: Lower-left, lower-right, upper-right, upper-left (Kalibr's corner numbering of a tag).
_TAG_CORNERS = ((0.0, 0.0), (1.0, 0.0), (1.0, 1.0), (0.0, 1.0))


def _count(fn: str, name: str, v, least: int) -> int:
    if isinstance(v, bool) or not isinstance(v, numbers.Integral) or int(v) < least:
        _checks.fail(fn, f"{name} must be an int >= {least}, got {v!r}")
    return int(v)


def _length(fn: str, name: str, v, zero_ok: bool = False) -> float:
    ok = (not isinstance(v, bool) and isinstance(v, numbers.Real) and math.isfinite(v)
          and (float(v) >= 0 if zero_ok else float(v) > 0))
    if not ok:
        _checks.fail(fn, f"{name} must be a finite real number {'>= 0' if zero_ok else '> 0'}"
                         f", got {v!r}")
    return float(v)


def aprilgrid(rows: int, cols: int, tag_size: float, tag_spacing: float) -> Tensor:
    r"""The corners of a Kalibr AprilGrid in Kalibr's order.

    Args:
        rows: number of tag rows (Kalibr's ``tagRows``), ``>= 1``.
        cols: number of tag columns (``tagCols``), ``>= 1``.
        tag_size: the edge of one tag in metres (``tagSize``), ``> 0``.
        tag_spacing: the gap between two tags as a fraction of ``tag_size``
            (``tagSpacing``), ``>= 0``.

    Returns:
        ``(rows * cols * 4, 3)`` float64 CPU tensor: row ``4 * id + k`` is corner ``k`` of
        tag ``id`` (ids row by row from the bottom-left tag: row ``r = id // cols``, column
        ``c = id % cols``; corners counter-clockwise from the tag's lower-left,
        ``(a_k, b_k) = (0, 0), (1, 0), (1, 1), (0, 1)``):
        ``(c p + a_k s, r p + b_k s, 0)`` with ``s = tag_size`` and the pitch
        ``p = tag_size * (1 + tag_spacing)``.

    Example:
        >>> aprilgrid(6, 6, 0.088, 0.3)[[0, 1, 2, 3, 4, 27]]
        tensor([[0.0000, 0.0000, 0.0000],
                [0.0880, 0.0000, 0.0000],
                [0.0880, 0.0880, 0.0000],
                [0.0000, 0.0880, 0.0000],
                [0.1144, 0.0000, 0.0000],
                [0.0000, 0.2024, 0.0000]], dtype=torch.float64)
    """
    fn = "calibration.aprilgrid"
    rows, cols = _count(fn, "rows", rows, 1), _count(fn, "cols", cols, 1)
    size = _length(fn, "tag_size", tag_size)
    pitch = size * (1.0 + _length(fn, "tag_spacing", tag_spacing, zero_ok=True))
    ids = torch.arange(rows * cols, dtype=torch.int64)
    origin = torch.stack((ids % cols, ids // cols), -1).to(torch.float64) * pitch  # (T, 2)
    offsets = torch.tensor(_TAG_CORNERS, dtype=torch.float64) * size  # (4, 2)
    xy = (origin[:, None, :] + offsets).reshape(-1, 2)
    return torch.cat((xy, xy.new_zeros(xy.shape[0], 1)), -1)


def checkerboard(rows: int, cols: int, row_spacing: float, col_spacing: float) -> Tensor:
    r"""The inner corners of a Kalibr checkerboard in Kalibr's order.

    Args:
        rows: inner corners per column (Kalibr's ``targetRows``), ``>= 3`` (OpenCV's
            detector needs 3).
        cols: inner corners per row (``targetCols``), ``>= 3``.
        row_spacing: ``rowSpacingMeters`` (the square's edge along the row index).
        col_spacing: ``colSpacingMeters``.

    Returns:
        ``(rows * cols, 3)`` float64 CPU tensor: row ``r * cols + c`` is
        ``(row_spacing * r, col_spacing * c, 0)`` (Kalibr's ``createGridPoints``).

    Example:
        >>> checkerboard(3, 4, 0.05, 0.04)[[0, 1, 4]]
        tensor([[0.0000, 0.0000, 0.0000],
                [0.0000, 0.0400, 0.0000],
                [0.0500, 0.0000, 0.0000]], dtype=torch.float64)
    """
    fn = "calibration.checkerboard"
    rows, cols = _count(fn, "rows", rows, 3), _count(fn, "cols", cols, 3)
    dr = _length(fn, "row_spacing", row_spacing)
    dc = _length(fn, "col_spacing", col_spacing)
    r, c = torch.meshgrid(torch.arange(rows, dtype=torch.float64),
                          torch.arange(cols, dtype=torch.float64), indexing="ij")
    return torch.stack((dr * r, dc * c, torch.zeros_like(r)), -1).reshape(-1, 3)


@dataclass(frozen=True)
class Target:
    r"""A calibration target: Kalibr's AprilGrid or checkerboard (frozen).

    Build it with :meth:`Target.aprilgrid`, :meth:`Target.checkerboard` or
    :func:`read_target`.

    Attributes:
        kind: ``"aprilgrid"`` or ``"checkerboard"``.
        rows: tag rows (AprilGrid) or inner-corner rows (checkerboard).
        cols: tag columns or inner-corner columns.
        size: the tag's edge (AprilGrid, ``tagSize``) or ``rowSpacingMeters``, metres.
        spacing: the gap between tags over the tag's edge (AprilGrid, ``tagSpacing``) or
            ``colSpacingMeters`` (checkerboard).

    The target's points (:attr:`points`) are indexed by ``tag_id * corners_per_tag +
    corner_id``: a checkerboard counts as one tag (id 0) with all its inner corners.
    """

    kind: str
    rows: int
    cols: int
    size: float
    spacing: float

    def __post_init__(self) -> None:
        fn = "calibration.Target"
        if self.kind not in KINDS:
            _checks.fail(fn, f"kind must be one of {KINDS}, got {self.kind!r}")
        least = 1 if self.kind == "aprilgrid" else 3
        for name in ("rows", "cols"):
            object.__setattr__(self, name, _count(fn, name, getattr(self, name), least))
        object.__setattr__(self, "size", _length(fn, "size", self.size))
        object.__setattr__(self, "spacing", _length(fn, "spacing", self.spacing,
                                                    zero_ok=self.kind == "aprilgrid"))

    @classmethod
    def aprilgrid(cls, rows: int, cols: int, tag_size: float, tag_spacing: float) -> Target:
        """A Kalibr AprilGrid (see :func:`aprilgrid` for the arguments)."""
        return cls("aprilgrid", rows, cols, tag_size, tag_spacing)

    @classmethod
    def checkerboard(cls, rows: int, cols: int, row_spacing: float,
                     col_spacing: float) -> Target:
        """A Kalibr checkerboard (see :func:`checkerboard` for the arguments)."""
        return cls("checkerboard", rows, cols, row_spacing, col_spacing)

    @property
    def tags(self) -> int:
        """Number of tags (1 for a checkerboard)."""
        return self.rows * self.cols if self.kind == "aprilgrid" else 1

    @property
    def corners_per_tag(self) -> int:
        """4 for an AprilGrid, ``rows * cols`` for a checkerboard."""
        return 4 if self.kind == "aprilgrid" else self.rows * self.cols

    @property
    def points(self) -> Tensor:
        """``(K, 3)`` float64 target points in Kalibr's order (:func:`aprilgrid`,
        :func:`checkerboard`)."""
        make = aprilgrid if self.kind == "aprilgrid" else checkerboard
        return make(self.rows, self.cols, self.size, self.spacing)


_YAML_KEYS = {"aprilgrid": ("tagRows", "tagCols", "tagSize", "tagSpacing"),
              "checkerboard": ("targetRows", "targetCols", "rowSpacingMeters",
                               "colSpacingMeters")}


def yaml_module(fn: str):
    """PyYAML, imported on first use, or an ImportError naming the ``calib`` extra."""
    try:
        import yaml
    except ImportError:
        raise ImportError(f"{fn}: reading Kalibr's yaml files needs PyYAML: pip install "
                          f"torch_dq[calib] (or pip install pyyaml)") from None
    return yaml


def load_yaml(fn: str, path, what: str) -> tuple:
    """``(yaml, text, mapping)`` of a Kalibr yaml file, or a ValueError naming ``fn``, the
    file and (for bad yaml) the line: not UTF-8 text, not valid yaml, not a mapping
    (``what`` says what it should hold); a TypeError for a ``path`` that is no path."""
    if not isinstance(path, (str, os.PathLike)):
        _checks.fail(fn, f"expected a path (str or os.PathLike) for path, got "
                         f"{type(path).__name__}", TypeError)
    yaml = yaml_module(fn)
    try:
        with open(path, encoding="utf-8") as f:
            text = f.read()
    except UnicodeDecodeError as exc:
        _checks.fail(fn, f"{os.fspath(path)}: not a UTF-8 text file ({exc.reason} at byte "
                         f"{exc.start})")
    try:
        doc = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        at = f", line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        problem = " ".join(str(getattr(exc, "problem", None) or exc).split())
        _checks.fail(fn, f"{os.fspath(path)}{at}: not a valid yaml file ({problem})")
    if not isinstance(doc, dict):
        _checks.fail(fn, f"{os.fspath(path)}: expected a yaml mapping {what}")
    return yaml, text, doc


def read_target(path: str | os.PathLike[str]) -> Target:
    r"""Read Kalibr's target yaml (``april_6x6.yaml``, ``checkerboard.yaml``).

    ====================  =====================================================
    ``target_type``       keys
    ====================  =====================================================
    ``'aprilgrid'``       ``tagRows``, ``tagCols``, ``tagSize`` [m], ``tagSpacing`` [ratio]
    ``'checkerboard'``    ``targetRows``, ``targetCols`` (inner corners),
                          ``rowSpacingMeters``, ``colSpacingMeters``
    ====================  =====================================================

    Other keys (Kalibr's ``circlegrid`` options, comments) are ignored. Needs PyYAML (the
    ``calib`` extra: ``pip install torch_dq[calib]``).

    Args:
        path: the yaml file.

    Returns:
        A :class:`Target`.

    Raises:
        ValueError: naming the file: not UTF-8 text, not a yaml mapping, an unknown or missing
            ``target_type`` (``circlegrid`` is not supported), a missing key or a bad value
            (and its line).
        ImportError: PyYAML is not installed.
        OSError: the file cannot be opened.

    Example:
        >>> import os, tempfile
        >>> path = os.path.join(tempfile.mkdtemp(), "april_6x6.yaml")
        >>> with open(path, "w") as f:
        ...     _ = f.write("target_type: 'aprilgrid'\ntagCols: 6\ntagRows: 6\n"
        ...                 "tagSize: 0.088\ntagSpacing: 0.3\n")
        >>> read_target(path)
        Target(kind='aprilgrid', rows=6, cols=6, size=0.088, spacing=0.3)
    """
    fn = "calibration.read_target"
    yaml, text, doc = load_yaml(fn, path, "with target_type and the target's sizes")
    where = f"{os.fspath(path)}: "
    kind = doc.get("target_type")
    if not isinstance(kind, str) or kind not in _YAML_KEYS:
        _checks.fail(fn, where + f"target_type must be 'aprilgrid' or 'checkerboard', got "
                                 f"{kind!r}{_line(yaml, text, 'target_type')}")
    keys = _YAML_KEYS[kind]
    missing = [k for k in keys if k not in doc]
    if missing:
        _checks.fail(fn, where + f"a {kind} target needs {', '.join(keys)}; missing "
                                 f"{', '.join(missing)}")
    try:
        return Target(kind, *(yaml_number(doc[k]) for k in keys))
    except ValueError as exc:
        names = dict(zip(("rows", "cols", "size", "spacing"), keys, strict=True))
        message = str(exc).removeprefix("calibration.Target: ")
        for ours, theirs in names.items():
            if message.startswith(f"{ours} must"):
                message = message.replace(ours, theirs, 1) + _line(yaml, text, theirs)
        _checks.fail(fn, where + message)


def _line(yaml, text: str, key: str) -> str:
    """``" (line N)"``: where the top-level ``key`` of the yaml ``text`` is written
    (1-based), or ``""`` when it is not found."""
    node = yaml.compose(text)
    for k, _ in getattr(node, "value", []):
        if getattr(k, "value", None) == key:
            return f" (line {k.start_mark.line + 1})"
    return ""
