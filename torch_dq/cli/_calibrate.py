r"""``python -m torch_dq calibrate``: camera-IMU calibration from Kalibr's files, or the
cameras' alone without ``--imu`` (private; the options are in :mod:`._parsers`).

Reads Kalibr's target yaml (:func:`~torch_dq.calibration.read_target`), the IMU file
(:func:`torch_dq.io.read_imu`), Kalibr's ``imu.yaml`` (``gyroscope_noise_density``,
``accelerometer_noise_density``; ``gyroscope_random_walk`` and ``accelerometer_random_walk``
for ``--bias random-walk``, the default, as in Kalibr: ``camera_imu``'s ``bias_walk``, biases
piecewise constant over ``--bias-interval`` seconds, at most ``sqrt(3)`` times the smaller
ratio of noise density to random walk, 1.15 s for EuRoC's IMU: ``camera_imu``'s
``bias_interval``; ``update_rate`` is reported, and warned of where it is not the IMU
file's rate: Kalibr's per-sample sigmas come from it, ours from the file) and a camchain yaml
(``cam0``, ``cam1``, ...: ``camera_model``, ``distortion_model``, ``resolution`` and, when
known, ``intrinsics`` and ``distortion_coeffs``; the cameras without intrinsics are
calibrated first by :func:`~torch_dq.calibration.cameras`, those with them keep them as
given), one ``--corners`` CSV (:func:`~torch_dq.calibration.read_corners`) or ``--images`` folder
(:func:`~torch_dq.calibration.detect_folder`) per camera in the camchain's order; runs
:func:`~torch_dq.calibration.camera_imu` and writes to ``--out``:

- ``camchain-imucam.yaml``: Kalibr's keys and nesting (``T_cam_imu``, ``T_cn_cnm1``,
  ``timeshift_cam_imu``, the camera models), reloadable by
  :meth:`torch_dq.camera.Camera.from_kalibr`;
- ``summary.json``: every value with its standard deviation (random-walk biases ``(K, 3)``,
  one row per segment, the segments' edges under ``bias``), per-term chi2/dof and outliers
  (keys unique: ``reprojections_cam<i>``, ``gyro``, ``accel``; ``--robust huber|cauchy`` on
  the reprojection errors, default none: the corners beyond the kernel's inlier cutoff,
  counted, left out of chi2), the reprojection RMS per camera, the
  trajectory's knot spacing (``--knot-spacing``: given, or chosen from the IMU readings by
  default), the warnings (one where the IMU's chi2/dof exceeds 3: the noise densities, or
  ``--knot-spacing`` where it was given);
- figures (matplotlib, optional): ``reprojection.png`` (errors per camera over time and in
  the image), ``imu.png`` (gyroscope and accelerometer residuals, the biases: random-walk
  ones as steps over time with their standard deviation bands).

Without ``--imu`` and ``--imu-noise`` it calibrates the cameras alone (Kalibr's
``calibrate_cameras``): :func:`~torch_dq.calibration.cameras` on every camera of the camchain
(its models and resolutions; intrinsics there are ignored), writing ``camchain.yaml``
(:meth:`~torch_dq.calibration.CameraCalibration.to_kalibr`: intrinsics and ``T_cn_cnm1``)
and ``summary.json`` (intrinsics and relative poses with their formal standard deviations,
reprojection RMS, the warnings).

User errors (unreadable or malformed files, options the data cannot satisfy, an output
that would overwrite an input, an ``--out`` holding an earlier run's results without
``--overwrite``, as ``fit``) end in one line on stderr and exit status 2.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import time
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

from ._errors import exit_on_error

if TYPE_CHECKING:
    from ..calibration import CameraImuCalibration

__all__ = ["run"]

_OUTPUTS = ("camchain-imucam.yaml", "camchain.yaml", "summary.json", "reprojection.png",
            "imu.png")


class UserError(ValueError):
    """A problem with the command's inputs (one line, exit status 2)."""


def _yaml(path: str) -> dict:
    try:
        import yaml
    except ImportError:
        raise UserError("PyYAML is needed: pip install 'torch_dq[calib]'") from None
    try:
        with open(path, encoding="utf-8") as f:
            data = yaml.safe_load(f)
    except OSError as exc:
        raise UserError(f"cannot read {path}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise UserError(f"{path}: not a UTF-8 text file ({exc.reason} at byte {exc.start})"
                        ) from None
    except yaml.YAMLError as exc:
        raise UserError(f"{path} is not valid yaml: {' '.join(str(exc).split())}") from None
    if not isinstance(data, dict):
        raise UserError(f"{path}: expected a yaml mapping")
    return data


_WALKS = ("gyroscope_random_walk", "accelerometer_random_walk")


def _noise(path: str, walk: bool) -> dict:
    """The noise densities of Kalibr's imu.yaml (and its random walks, required with
    ``walk``; numbers written without a dot, ``1e-4``, which YAML 1.1 reads as strings,
    taken as numbers); ``update_rate`` and, without ``walk``, the walks are copied as
    given. The keys at the top, or under ``imu0`` (Kalibr's ``imu-*.yaml`` output)."""
    data = _yaml(path)
    if "gyroscope_noise_density" not in data and isinstance(data.get("imu0"), dict):
        data = data["imu0"]  # Kalibr's imu-camchain output and multi-IMU yamls: imu0 nested
    out = {}
    for key in ("gyroscope_noise_density", "accelerometer_noise_density",
                *(_WALKS if walk else ())):
        v = data.get(key)
        if isinstance(v, str):  # 1e-4 without a dot: a string to YAML 1.1 (PyYAML)
            try:
                v = float(v)
            except ValueError:
                pass
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0 < v < math.inf:
            need = " (needed by --bias random-walk; --bias constant does without)" * (
                key in _WALKS)
            raise UserError(f"{path}: expected a positive number under {key}, got {v!r}{need}")
        out[key] = float(v)
    for key in (*_WALKS, "update_rate"):
        if key in data and key not in out:
            out[key] = data[key]
    rate = out.get("update_rate")
    if rate is not None:
        try:
            out["update_rate"] = float(rate) if not isinstance(rate, bool) else math.nan
        except (TypeError, ValueError):
            out["update_rate"] = math.nan
        if not 0 < out["update_rate"] < math.inf:
            raise UserError(f"{path}: expected a positive number (Hz) under update_rate, "
                            f"got {rate!r}")
    return out


def _update_rate(noise: dict, times, path: str) -> None:
    """A warning where imu.yaml's ``update_rate`` is more than 5 % off the IMU file's rate
    (its median sample spacing): Kalibr's per-sample sigmas (``density *
    sqrt(update_rate)``) would then differ from ``camera_imu``'s (the file's rate)."""
    from ..calibration._camera_imu import sample_rate

    given = noise.get("update_rate")
    if given is None or times.numel() < 2:
        return
    rate = sample_rate(times)
    if abs(given / rate - 1.0) > 0.05:
        warnings.warn(f"{path}: update_rate {given:g} Hz is not the IMU file's rate "
                      f"({rate:.4g} Hz, its median sample spacing): the noise sigmas per "
                      f"sample use the file's rate (density * sqrt(rate)); Kalibr's, from "
                      f"update_rate, would be {math.sqrt(given / rate):.3g} times these "
                      f"(a stale update_rate: correct it)",
                      UserWarning, stacklevel=2)


def _bias_options(args) -> tuple[bool, float]:
    """``--bias`` (random-walk: True, constant: False) and ``--bias-interval`` (seconds)."""
    model = str(args.bias).strip().lower()
    if model not in ("random-walk", "constant"):
        raise UserError(f"--bias must be random-walk or constant, got {args.bias!r}")
    try:
        interval = float(args.bias_interval)
    except ValueError:
        interval = math.nan
    if not 0 < interval < math.inf:
        raise UserError(f"--bias-interval must be a number of seconds > 0, got "
                        f"{args.bias_interval!r}")
    return model == "random-walk", interval


def _camchain(path: str) -> list[dict]:
    data = _yaml(path)
    names = sorted((k for k in data if isinstance(k, str) and k.startswith("cam")
                    and k[3:].isdigit()), key=lambda k: int(k[3:]))
    if not names or names != [f"cam{i}" for i in range(len(names))]:
        raise UserError(f"{path}: expected cameras cam0, cam1, ... got {sorted(map(str, data))}")
    for k in names:
        if not isinstance(data[k], dict):
            raise UserError(f"{path}: {k} must be a mapping (camera_model, intrinsics, ...), "
                            f"got {data[k]!r}")
    return [data[k] for k in names]


def _on_target(path, points, target, target_path) -> None:
    """A corners file whose points are not the target's (another grid, tag size or
    spacing: its metric scale would be wrong) is a user error naming the first one."""
    import torch

    ref = target.points.to(points.dtype)
    gap = torch.cdist(points, ref).amin(-1) if len(points) else points.new_zeros(0)
    tol = 1e-4 * max(float(ref.abs().max()), 1e-3)
    bad = (gap > tol).nonzero()
    if len(bad):
        i = int(bad[0])
        units = (("millimetres", 1000), ("centimetres", 100))
        # the target's yaml in another unit first: points / k all lie near a large target's
        # corner 0, which the second test alone took for corners in millimetres
        why = next((f"the target's sizes are in {unit}, not metres (Kalibr's tagSize, "
                    f"rowSpacingMeters, colSpacingMeters): divide them by {k} in {target_path}"
                    for unit, k in units
                    if bool((torch.cdist(points, ref / k).amin(-1) <= tol / k).all())), None)
        why = why or next((f"the points are in {unit}, not metres: divide X_m, Y_m, Z_m by {k}"
                           for unit, k in units
                           if bool((torch.cdist(points / k, ref).amin(-1) <= tol).all())),
                          "the corners were measured on another target, or --target is not it")
        raise UserError(f"{path}: the point {points[i].tolist()} (row {i + 1}) is not a "
                        f"corner of the target in {target_path} (nearest {float(gap[i]):.3g} "
                        f"m away; {len(bad)} of {len(points)} rows are off): {why}")


def _imu_file(path: str) -> str:
    """``--imu``: the file, or EuRoC's ``imu0`` folder holding it as ``data.csv``."""
    if not Path(path).is_dir():
        return path
    if (Path(path) / "data.csv").is_file():
        return os.fspath(Path(path) / "data.csv")
    raise UserError(f"--imu {path} is a folder without data.csv: give the IMU file (EuRoC: "
                    f"mav0/imu0/data.csv)")


def _observations(args, target, n: int):
    from ..calibration import detect_folder, read_corners

    if args.corners and args.images:
        raise UserError("give --corners or --images, not both")
    sources = args.corners or args.images
    if len(sources) != n:
        raise UserError(f"the camchain has {n} camera(s): give one --corners or --images per "
                        f"camera, got {len(sources)}")
    if args.corners:
        obs = [tuple(read_corners(p)[:3]) for p in args.corners]
        for path, (_, points, _) in zip(args.corners, obs, strict=True):
            _on_target(path, points, target, args.target)
        return obs
    return [tuple(detect_folder(p, target, verbose=not args.quiet)[:3]) for p in args.images]


def _models(entries, path: str) -> list[tuple[str, tuple]]:
    """Each camchain entry's model name and resolution (its intrinsics not needed)."""
    from ..camera import Camera

    models = []
    for i, e in enumerate(entries):
        probe = dict(e)
        probe.setdefault("intrinsics", [0.0, 0.5, 1.0, 1.0, 0.0, 0.0]  # Kalibr's ds order
                         if e.get("camera_model") == "ds" else [1.0, 1.0, 0.0, 0.0])
        if e.get("distortion_model", "none") in ("radtan", "equidistant"):
            probe.setdefault("distortion_coeffs", [0.0] * 4)
        try:
            models.append((Camera.from_kalibr(probe).model, tuple(e["resolution"])))
        except (KeyError, TypeError) as exc:
            raise UserError(f"{path}: cam{i} needs camera_model, distortion_model and "
                            f"resolution ({exc})") from None
    return models


def _robust(args) -> dict:
    """``--robust`` as the keywords of :func:`~torch_dq.calibration.cameras`: the kernel
    (None for ``none``) and its scale in pixels, ``2.45 --pixel-sigma`` (the 95 % quantile
    of the norm of two normal components, ``sqrt(-2 ln 0.05)``, as ``camera_imu``'s)."""
    kind = None if args.robust == "none" else args.robust
    return {"robust": kind, "robust_k": math.sqrt(-2.0 * math.log(0.05)) * args.pixel_sigma}


def _cameras(entries, obs, path: str, say, robust: dict | None = None):
    """The camchain's cameras: those with intrinsics as given (fixed), the others calibrated
    first from their corners (:func:`~torch_dq.calibration.cameras`: jointly where none has
    intrinsics, else each camera without alone; ``robust``: its keywords, ``_robust``,
    None: least squares)."""
    from ..calibration import cameras
    from ..camera import Camera

    robust = robust or {}
    missing = [i for i, e in enumerate(entries) if "intrinsics" not in e]
    if not missing:
        return [Camera.from_kalibr(e) for e in entries]
    models = _models(entries, path)
    if len(missing) == len(entries):
        say("calibrating the cameras' intrinsics first (the camchain has none)")
        return cameras(obs, [m for m, _ in models], [r for _, r in models], **robust).cameras
    out = [None if i in missing else Camera.from_kalibr(e) for i, e in enumerate(entries)]
    say(f"calibrating the intrinsics of {', '.join(f'cam{i}' for i in missing)} first (the "
        f"camchain has none for them; the others' are kept as given)")
    for i in missing:
        out[i] = cameras([obs[i]], [models[i][0]], [models[i][1]], **robust).cameras[0]
    return out


def _check_outputs(args) -> Path:
    out = Path(args.out)
    inputs = [p for p in (args.target, args.imu, args.imu_noise, args.cameras, *args.corners,
                          *args.images) if p is not None]
    resolved = {Path(p).resolve() for p in inputs}
    for name in _OUTPUTS:
        if (out / name).resolve() in resolved:
            raise UserError(f"--out {args.out} would overwrite the input {out / name}")
    for p in args.images:  # the folder or its data subfolder (EuRoC's cam0/data)
        if out.resolve() in (Path(p).resolve(), (Path(p) / "data").resolve()):
            raise UserError(f"--out {args.out} is an --images folder (an input)")
    if out.exists() and not out.is_dir():
        raise UserError(f"--out {args.out} is a file, not a folder")
    earlier = [name for name in _OUTPUTS if (out / name).exists()]
    if earlier and not args.overwrite:  # fit's rule (fit_file._check_out)
        raise UserError(f"{args.out} already holds results of an earlier run "
                        f"({', '.join(earlier)}): pass --overwrite to replace them, or choose "
                        f"another --out")
    return out


def _val(x):
    return x.detach().double().cpu().tolist()


def _chi2(res) -> dict:
    """Per-term chi2, dof, chi2/dof and outliers (``--robust``: the samples beyond the
    kernel's inlier cutoff, left out of chi2; else 0) keyed ``reprojections_cam<i>``,
    ``gyro``, ``accel`` (a suffix ``_2``, ``_3`` ... on a name taken already: the keys are
    unique)."""
    from ..fitting import Accel, Gyro

    est, chi2 = res.estimate, {}
    for i, term in enumerate(res.terms):
        base = (f"reprojections_cam{i}" if i < len(res.cameras) else "gyro"
                if isinstance(term, Gyro) else "accel" if isinstance(term, Accel)
                else type(term).__name__.lower())
        name, n = base, 1
        while name in chi2:
            n += 1
            name = f"{base}_{n}"
        c, d = float(est.chi2[term]), float(est.dof[term])
        chi2[name] = {"chi2": c, "dof": d, "chi2_per_dof": c / d if d else None,
                      "outliers": int(est.outliers[term])}
    return chi2


def _summary(res, noise: dict, caught: list[str], elapsed: float, interval: float) -> dict:
    val, est = _val, res.estimate
    walk = res.bias_edges is not None
    bias = {"model": "random-walk" if walk else "constant",
            "interval_s": interval if walk else None,
            "edges_s": val(res.bias_edges) if walk else None,
            "segments": int(res.bias_edges.numel() - 1) if walk else 1}
    values = {k: {"value": val(getattr(res, k)), "std": val(res.std[k])} for k in res.std}
    values["extrinsics"]["T_cam_imu"] = [res.to_kalibr()[f"cam{i}"]["T_cam_imu"]
                                         for i in range(len(res.cameras))]
    return {"values": values, "bias": bias, "chi2": _chi2(res),
            "reprojection_rms_px": val(res.reprojection_rms),
            "imu_noise": noise, "steps": int(est.steps),
            "converged": bool(est.converged.all()), "reason": est.reason,
            "knot_spacing_s": res.knot_spacing,
            "seconds": elapsed, "seconds_per_stage": res.timings, "warnings": caught,
            "notes": ["extrinsics' std: chart e exp(delta), rotation (rad) then translation "
                      "(m) in camera axes; gravity in the target frame, its magnitude fixed "
                      f"(--gravity {float(res.gravity.norm()):.6g} m/s^2); "
                      + ("biases (K, 3): one row per segment between bias.edges_s (IMU "
                         "clock, s), tied by imu.yaml's random walks; the IMU terms' chi2 "
                         "counts the K - 1 ties" if walk else "biases constant (--bias "
                         "constant: the random walks are not modelled)")]}


def run(args) -> int:
    """Run ``calibrate`` with parsed ``args``; 0 on success, 2 on a user error."""
    try:
        return _run(args)
    except (UserError, ValueError, OSError) as exc:
        return exit_on_error("torch-dq calibrate", exc)


def _run(args) -> int:
    from ..calibration import read_target

    def say(text: str) -> None:
        if not args.quiet:
            print(f"torch-dq calibrate: {text}", flush=True)

    if not args.pixel_sigma > 0:
        raise UserError(f"--pixel-sigma must be > 0, got {args.pixel_sigma}")
    if (args.imu is None) != (args.imu_noise is None):
        raise UserError("--imu and --imu-noise go together: both for a camera-IMU "
                        "calibration, neither to calibrate the cameras alone")
    if args.imu is None:
        return _run_cameras(args, say)
    walk, interval = _bias_options(args)
    out = _check_outputs(args)
    start = time.perf_counter()
    target = read_target(args.target)
    noise = _noise(args.imu_noise, walk)
    entries = _camchain(args.cameras)
    cams, res, caught = _estimate(args, target, noise, entries, walk, interval, say)
    elapsed = time.perf_counter() - start
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create --out {args.out}: {exc.strerror}") from None
    _write(out, res, entries, _summary(res, noise, caught, elapsed, interval))
    if not args.no_plots:
        _figures(out, res, say)
    for i in range(len(cams)):
        say(f"cam{i}: reprojection RMS {float(res.reprojection_rms[i]):.3f} px, "
            f"timeshift_cam_imu {1e3 * float(res.time_offsets[i]):.3f} "
            f"+- {1e3 * float(res.std['time_offsets'][i]):.3f} ms")
    say(f"wrote {out} in {elapsed:.1f} s")
    return 0


def _estimate(args, target, noise: dict, entries: list, walk: bool, interval: float, say
              ) -> tuple[list, CameraImuCalibration, list[str]]:
    """Read the IMU and the corners, calibrate cameras without intrinsics, run
    :func:`~torch_dq.calibration.camera_imu`: ``(cameras, result, warnings)``. Every warning
    (the readers' included) is printed as one ``warning:`` line on stderr, also when an
    error ends the run."""
    from .. import io
    from ..calibration import camera_imu

    with _printed_warnings() as caught:
        _stated_line_delays(entries, args)
        imu = io.read_imu(_imu_file(args.imu), duplicates=args.duplicates)
        _update_rate(noise, imu[0], args.imu_noise)
        say(f"read {imu[0].numel()} IMU samples; reading the corners of {len(entries)} "
            f"camera(s)")
        obs = _observations(args, target, len(entries))
        robust = _robust(args)
        cams = _cameras(entries, obs, args.cameras, say, robust)
        say("estimating (start from the gyroscope and the target poses, then one joint fit)")
        res = camera_imu(cams, obs, imu, gyro_noise=noise["gyroscope_noise_density"],
                         accel_noise=noise["accelerometer_noise_density"],
                         pixel_sigma=args.pixel_sigma, rolling_shutter=args.rolling_shutter,
                         robust=robust["robust"],
                         shared_time_offset=args.shared_time_offset,
                         bias_walk=tuple(noise[k] for k in _WALKS) if walk else None,
                         bias_interval=interval, gravity_magnitude=args.gravity,
                         max_time_offset=args.max_time_offset,
                         knot_spacing=None if args.knot_spacing == "auto" else args.knot_spacing,
                         verbose=not args.quiet)
        _imu_fit(res, args.knot_spacing == "auto")
    return cams, res, caught


def _stated_line_delays(entries: list, args) -> None:
    """A warning where the camchain states a rolling shutter (``line_delay`` or
    ``line_delay_nanoseconds`` above 0) but ``--rolling-shutter`` is not given: the cameras
    would be calibrated as global shutters, the stated delays unused."""
    from ..calibration._camchain import _line_delay

    stated = [f"cam{i}" for i, e in enumerate(entries)
              if (_line_delay("calibrate", f"{args.cameras}: cam{i}", e) or 0.0) > 0]
    if stated and not args.rolling_shutter:
        warnings.warn(f"{args.cameras}: {', '.join(stated)} state{'s' * (len(stated) == 1)} a "
                      f"line delay (a rolling shutter), which is not used: without "
                      f"--rolling-shutter every camera is calibrated as a global shutter "
                      f"(pass --rolling-shutter to estimate the line delays)",
                      UserWarning, stacklevel=2)


def _imu_fit(res, auto: bool) -> None:
    """A warning where the IMU terms' chi2/dof exceeds 3: with the knot spacing chosen from
    the readings (``auto``), the noise densities too small or biases that drift (the
    spacing follows the motion's spectrum); with one given, also a trajectory too coarse
    for the motion (``--knot-spacing`` named)."""
    from ..fitting import Accel, Gyro

    est = res.estimate
    high = {name: float(est.chi2[t]) / float(est.dof[t]) for t in res.terms
            for name, kind in (("gyro", Gyro), ("accel", Accel))
            if isinstance(t, kind) and float(est.dof[t]) > 0}
    high = {k: v for k, v in high.items() if v > 3.0}
    if not high:
        return
    spacing = res.knot_spacing
    knots = (f"the knots every {spacing:.3g} s (chosen from the readings' spectrum: "
             f"--knot-spacing auto) follow the motion, so " if auto else
             f"the trajectory's knots every {spacing:g} s are too coarse for this motion "
             f"(try --knot-spacing {spacing / 2:g} or auto), ")
    warnings.warn(f"the IMU's chi2/dof is {', '.join(f'{k} {v:.3g}' for k, v in high.items())}"
                  f" (expected about 1): {knots}"
                  + ("the biases drift (--bias random-walk), " if res.bias_edges is None
                     else "") + "or imu.yaml's noise densities are too small",
                  UserWarning, stacklevel=2)


@contextlib.contextmanager
def _printed_warnings():
    """Record the warnings raised inside (the readers' included) into the list it yields,
    each printed as one ``warning:`` line on stderr, also when an error ends the run."""
    caught: list[str] = []
    with warnings.catch_warnings(record=True) as record:
        warnings.simplefilter("always")
        try:
            yield caught
        finally:
            caught.extend(" ".join(str(w.message).split()) for w in record)
            for text in caught:
                print(f"torch-dq calibrate: warning: {text}", file=sys.stderr)


def _run_cameras(args, say) -> int:
    """The cameras alone (no ``--imu``): :func:`~torch_dq.calibration.cameras` on the
    camchain's models and resolutions; writes ``camchain.yaml`` and ``summary.json``."""
    from .. import dualquat
    from ..calibration import cameras, read_target

    given = [flag for flag, dest, default in args.imu_options
             if getattr(args, dest) != default]
    if given:
        raise UserError(f"{', '.join(given)} need{'s' * (len(given) == 1)} --imu and "
                        f"--imu-noise (camera-IMU options; the cameras alone have no use "
                        f"for them)")
    out = _check_outputs(args)
    start = time.perf_counter()
    target = read_target(args.target)
    entries = _camchain(args.cameras)
    models = _models(entries, args.cameras)
    with _printed_warnings() as caught:
        say(f"reading the corners of {len(entries)} camera(s)")
        obs = _observations(args, target, len(entries))
        say(f"calibrating {len(entries)} camera(s) from the target alone (no --imu)"
            + "; the camchain's intrinsics are not used" * any("intrinsics" in e
                                                              for e in entries))
        res = cameras(obs, [m for m, _ in models], [r for _, r in models], **_robust(args))
    elapsed = time.perf_counter() - start
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UserError(f"cannot create --out {args.out}: {exc.strerror}") from None
    _write(out, res, entries, _cameras_summary(res, caught, elapsed), "camchain.yaml")
    for i, cam in enumerate(res.cameras):
        say(f"cam{i}: {cam.model} {', '.join(f'{v:.6g}' for v in _val(cam.params))}; "
            f"reprojection RMS {float(res.reprojection_rms[i]):.3f} px")
    for i, pose in enumerate(res.relative_poses, 1):
        say(f"cam{i} in cam0's frame: translation "
            f"{', '.join(f'{v:+.5f}' for v in _val(dualquat.to_rt(pose)[1]))} m")
    say(f"wrote {out} in {elapsed:.1f} s")
    return 0


def _cameras_summary(res, caught: list[str], elapsed: float) -> dict:
    std = res.std["intrinsics"]
    return {"cameras": [{"model": c.model, "params": _val(c.params),
                         "std": _val(std[i, :c.params.numel()]),
                         "resolution": list(c.resolution),
                         "reprojection_rms_px": float(res.reprojection_rms[i]),
                         "used": int(res.used[i]), "excluded": int(res.excluded[i]),
                         "outliers": int(res.outliers[i])}
                        for i, c in enumerate(res.cameras)],
            "relative_poses": {"value": _val(res.relative_poses),
                               "std": _val(res.std["relative_poses"])},
            "sigma_px": float(res.sigma), "iterations": int(res.iterations),
            "converged": bool(res.converged), "seconds": elapsed, "warnings": caught,
            "notes": ["relative_poses: camera i's pose in camera 0's frame (p_cam0 = T "
                      "p_cami) as unit dual quaternions; camchain.yaml's T_cn_cnm1 is "
                      "p_camN = T p_camN-1", "std: formal standard deviations (white noise "
                      "on every corner), lower bounds for real corners; relative poses' in "
                      "the chart T exp(delta), rotation (rad) then translation (m)"]}


def _write(out: Path, res, entries, summary: dict, chain: str = "camchain-imucam.yaml"
           ) -> None:
    """The result's camchain (``res.to_kalibr``, the input camchain's rostopics) as
    ``chain`` and ``summary`` as ``summary.json`` in ``out``."""
    import yaml

    topics = [str(e.get("rostopic", f"/cam{i}/image_raw")) for i, e in enumerate(entries)]
    with open(out / chain, "w", encoding="utf-8") as f:
        yaml.safe_dump(res.to_kalibr(topics), f, default_flow_style=None, sort_keys=True)
    with open(out / "summary.json", "w", encoding="utf-8") as f:
        json.dump(summary, f, indent=2, allow_nan=True)


def _figures(out: Path, res, say) -> None:
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        say("matplotlib is not installed: figures skipped (pip install 'torch_dq[plot]')")
        return
    from ._calibrate_plots import imu_figure, reprojection_figure

    for name, fig in (("reprojection.png", reprojection_figure(res, plt)),
                      ("imu.png", imu_figure(res, plt))):
        fig.savefig(os.fspath(out / name), dpi=130)
        plt.close(fig)
