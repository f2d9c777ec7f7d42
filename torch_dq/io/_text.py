r"""Text files of numbers, line by line: the parsing every reader of :mod:`torch_dq.io` shares
(private).

Lines and ``#`` comments (:func:`read_lines`), fields (:func:`split`), strict decimal numbers
(:func:`floats`), integer nanoseconds read exactly (:func:`nanoseconds`,
:func:`seconds_from_ns`), increasing times (:func:`check_times`), and the error that names
the file and the line (:class:`TrajectoryFileError`, :func:`first_bad`).
"""

from __future__ import annotations

import os
import re
from collections.abc import Sequence
from decimal import Decimal
from fractions import Fraction

import numpy as np
import torch
from torch import Tensor

__all__ = ["DECIMAL", "INTEGER", "NUMBER", "TrajectoryFileError", "as_tensor", "check_times",
           "first_bad", "floats", "header_row", "nanoseconds", "read_lines",
           "seconds_from_ns", "split"]


class TrajectoryFileError(ValueError):
    """A malformed trajectory, times or IMU file.

    The message reads ``"<file>, line <n>: <what is wrong>"`` (without the line for
    problems of the whole file, e.g. an empty one).

    Attributes:
        path: the file, as given.
        line: the 1-based line number, or ``None``.
    """

    def __init__(self, path: str | os.PathLike[str], line: int | None, message: str):
        self.path = os.fspath(path)
        self.line = line
        where = self.path if line is None else f"{self.path}, line {line}"
        super().__init__(f"{where}: {message}")


def read_lines(path) -> tuple[list[int], list[str], list[str]]:
    """Data lines of a text file: (line numbers, texts, the comment lines before the data).

    ``#`` starts a comment (to the end of the line); blank lines are skipped.
    """
    numbers_, texts, header = [], [], []
    try:
        with open(path, encoding="utf-8-sig") as f:  # a BOM is skipped
            for n, line in enumerate(f, 1):
                text, hash_, comment = line.partition("#")
                text = text.strip()
                if text:
                    numbers_.append(n)
                    texts.append(text)
                elif hash_ and not texts:
                    header.append(comment.strip())
    except UnicodeDecodeError as exc:
        raise TrajectoryFileError(path, None, f"not a UTF-8 text file ({exc.reason} at byte "
                                              f"{exc.start})") from None
    if not texts:
        raise TrajectoryFileError(path, None, "no data (the file is empty or holds only "
                                              "comments)")
    return numbers_, texts, header


def split(texts: list[str], commas: bool) -> list[list[str]]:
    """Fields of each line: at commas when ``commas``, else at whitespace or commas."""
    if commas:
        return [[s.strip() for s in text.split(",")] for text in texts]
    return [text.replace(",", " ").split() for text in texts]


#: A decimal number as files write it (ASCII digits, no ``_`` separators, which Python's
#: ``float`` would accept: ``float("1_0") == 10.0``); nan and inf are numbers here, rejected
#: later as non-finite.
NUMBER = re.compile(r"[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)",
                     re.ASCII | re.IGNORECASE)


def floats(path, lines: list[int], rows: list[list[str]], names: Sequence[str]) -> np.ndarray:
    """Parse rows of numeric fields into a float64 array, naming the first bad line."""
    width = len(names)
    for n, fields in zip(lines, rows, strict=True):
        if len(fields) != width:
            raise TrajectoryFileError(path, n, f"expected {width} columns "
                                               f"({' '.join(names)}), got {len(fields)}")
        for name, text in zip(names, fields, strict=True):
            if not NUMBER.fullmatch(text):
                raise TrajectoryFileError(path, n, f"{name}: {text!r} is not a number")
    values = np.array(rows, dtype=np.float64)
    first_bad(path, lines, ~np.isfinite(values).all(axis=1),
               lambda i: f"non-finite value in {' '.join(rows[i])!r}")
    return values


def first_bad(path, lines: list[int], bad: np.ndarray | np.bool_, message) -> None:
    """Raise for the first True of ``bad`` (per row), saying how many rows are bad."""
    where = np.flatnonzero(bad)
    if where.size:
        i = int(where[0])
        more = f" ({where.size} lines in all)" if where.size > 1 else ""
        raise TrajectoryFileError(path, lines[i], message(i) + more)


def check_times(path, lines: list[int], t: np.ndarray, duplicates: str,
                 unit: str = "s", hint: str = "") -> np.ndarray:
    """Check that times increase strictly; with duplicates="first" drop repeated ones.

    ``hint`` is appended to the message on a repeated time (e.g. that the times were
    rounded to float32 before they got here).

    Returns:
        The indices of the rows kept.
    """
    step = np.diff(t)
    show = lambda i: str(t[i]) if unit == "ns" else repr(float(t[i]))  # noqa: E731
    first_bad(path, lines[1:], step < 0,
               lambda i: f"timestamp {show(i + 1)} {unit} is before the previous one "
                         f"({show(i)} {unit}, line {lines[i]}): the rows must be sorted by "
                         f"time")
    if duplicates == "first":
        return np.flatnonzero(np.concatenate(([True], step > 0)))
    first_bad(path, lines[1:], step == 0,
               lambda i: f"duplicate timestamp {show(i + 1)} {unit} (also on line "
                         f"{lines[i]}){hint}; to keep the first row of each time, pass "
                         f"duplicates='first' (Python) or --duplicates first (the fit and "
                         f"calibrate commands)")
    return np.arange(t.shape[0])


INTEGER = re.compile(r"-?\d+", re.ASCII)
DECIMAL = re.compile(r"-?\d+(?:\.\d*)?", re.ASCII)


def nanoseconds(path, lines: list[int], texts: list[str], fractions: bool) -> list[Decimal]:
    """EuRoC timestamps: integer nanoseconds, exactly (fractions of a nanosecond too, as
    :func:`torch_dq.io.write_trajectory` writes times finer than 1 ns, when the header says
    ``[ns]``)."""
    pattern = DECIMAL if fractions else INTEGER
    for n, text in zip(lines, texts, strict=True):
        if not pattern.fullmatch(text):
            hint = ("; a TUM file with commas? pass format='tum' (fit: --format tum)"
                    if "." in text else "")
            raise TrajectoryFileError(path, n, f"timestamp {text!r} is not an integer number "
                                               f"of nanoseconds{hint}")
    return [Decimal(text) for text in texts]


def seconds_from_ns(ns: list[Decimal], keep: np.ndarray) -> np.ndarray:
    """The rows ``keep`` of nanoseconds as float64 seconds, correctly rounded (``Fraction``
    to float is: the float64 nearest to ``ns * 1e-9``)."""
    return np.array([float(Fraction(ns[i]) / 10**9) for i in keep], dtype=np.float64)


def header_row(path, lines: list[int], texts: list[str], header: list[str]
               ) -> tuple[list[int], list[str], list[str]]:
    """A header row written without the leading ``#`` (its first field a name) moved from
    the data to the header: ``(lines, texts, header)``. A first field that reads as a number
    (``nan``, ``inf``) is data, not a name."""
    if not texts[0][:1].isalpha() or NUMBER.fullmatch(re.split(r"[\s,]+", texts[0])[0]):
        return lines, texts, header
    if len(texts) == 1:
        raise TrajectoryFileError(path, None, "no data (the file holds only a header)")
    return lines[1:], texts[1:], [texts[0]]


def as_tensor(a: np.ndarray) -> Tensor:
    """A float64 CPU tensor of ``a`` (contiguous)."""
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float64))
