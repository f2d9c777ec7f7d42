"""Progress bars for long work (private): one place for the optional tqdm dependency."""

__all__ = ["progress"]


def progress(total: int, enabled: bool, desc: str):
    """A tqdm bar when enabled and tqdm is installed, else None."""
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:  # tqdm is optional
        return None
    return tqdm(total=total, desc=desc, leave=False)
