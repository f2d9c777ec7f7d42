"""``main``: parse the command line and run the chosen command (private)."""

from __future__ import annotations

from ._errors import exit_on_error
from ._parsers import build_parser

__all__ = ["main"]


def _fit(parser, args) -> int:
    """``python -m torch_dq fit``: errors in the file or the options end in one line and
    exit status 2."""
    import torch

    from .fit_file import run_fit

    torch.set_num_threads(args.threads)
    try:
        run_fit(args.file, format=args.format, times=args.times, duplicates=args.duplicates,
                knot_spacing=args.knot_spacing, degree=args.degree, form=args.form,
                holdout=args.holdout,
                steps=args.steps, refine=args.refine, rate=args.rate,
                dtype=getattr(torch, args.dtype),
                out=args.out, overwrite=args.overwrite, imu=args.imu,
                time_offset=args.time_offset, plots=not args.no_plots,
                verbose=not args.quiet)
    except (ValueError, OSError) as exc:
        return exit_on_error("torch-dq fit", exc)
    return 0


def _calibrate(parser, args) -> int:
    """``python -m torch_dq calibrate``: a missing optional dependency (PyYAML for Kalibr's
    yamls, OpenCV for ``--images``) ends, like a user error, in one line naming what to
    install and exit status 2."""
    import torch

    from ._calibrate import run

    torch.set_num_threads(args.threads)
    try:
        return run(args)
    except ImportError as exc:
        return exit_on_error("torch-dq calibrate", exc)


def _demo(parser, args) -> int:
    """``python -m torch_dq demo``: options that contradict each other end as argparse's
    usage errors (exit status 2)."""
    if args.degree >= args.n_ctrl:
        parser.error(f"demo: --degree ({args.degree}) must be < --n-ctrl ({args.n_ctrl})")
    if args.samples < 2:
        parser.error(f"demo: --samples must be >= 2, got {args.samples}")
    if args.samples < args.n_ctrl:
        parser.error(f"demo: --samples ({args.samples}) must be >= --n-ctrl "
                     f"({args.n_ctrl}) for the least-squares initialisation")
    import torch

    from ..demo import run_demo

    try:
        device = torch.device(args.device)
    except RuntimeError as exc:
        parser.error(f"demo: bad --device {args.device!r}: {exc}")
    if device.type == "cuda" and not torch.cuda.is_available():
        parser.error("demo: --device cuda requested but CUDA is not available")
    lr = args.lr
    if lr is not None and not lr > 0:
        parser.error(f"demo: --lr must be > 0, got {args.lr}")
    torch.set_num_threads(args.threads)
    run_demo(args.out, n_ctrl=args.n_ctrl, degree=args.degree, steps=args.steps,
             seed=args.seed, device=str(device), dtype=getattr(torch, args.dtype),
             n_samples=args.samples, rot_noise_deg=args.rot_noise,
             trans_noise_mm=args.trans_noise, optimizer=args.optimizer, lr=lr,
             plots=not args.no_plots, verbose=not args.quiet)
    return 0


_COMMANDS = {"calibrate": _calibrate, "demo": _demo, "fit": _fit}


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m torch_dq`` and of the ``torch-dq`` script.

    Args:
        argv: arguments without the program name (default ``sys.argv[1:]``).

    Returns:
        The exit status: 0 on success (also when matplotlib is missing: the figures are
        skipped with a one-line notice), 2 on bad arguments or options the data cannot
        satisfy (``fit``: the message names a value that works) and when ``fit`` or
        ``calibrate`` meets a malformed or unreadable file (``calibrate`` also when an
        optional dependency it needs is missing): one line on stderr, no traceback.
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 2
    return _COMMANDS[args.command](parser, args)
