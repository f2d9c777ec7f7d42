"""Progress reporting for long work (private): one place for the optional tqdm dependency
and for the plain lines printed without a terminal."""

import sys

__all__ = ["Lines", "progress", "reporter"]


def progress(total: int, enabled: bool, desc: str):
    """A tqdm bar when enabled and tqdm is installed, else None."""
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm is optional
        return None
    return tqdm(total=total, desc=desc, leave=False)


class Lines:
    """Progress without a terminal: one plain line per step on stderr (tqdm's methods:
    ``update``, ``set_postfix``, ``close``)."""

    def __init__(self, desc: str) -> None:
        self.desc, self.k = desc, 0

    def update(self, n: int) -> None:
        self.k += n

    def set_postfix(self, **fields: str) -> None:
        text = ", ".join(f"{name} {value}" for name, value in fields.items())
        print(f"{self.desc}: step {self.k}: {text}", file=sys.stderr, flush=True)

    def close(self) -> None:
        pass


def reporter(total: int, verbose: bool, desc: str):
    """Progress of ``total`` steps: None when not ``verbose``, a tqdm bar when stderr is a
    terminal and tqdm is installed, :class:`Lines` otherwise."""
    if not verbose:
        return None
    bar = progress(total, sys.stderr.isatty(), desc)
    return Lines(desc) if bar is None else bar
