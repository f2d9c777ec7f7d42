"""Figures of ``python -m torch_dq calibrate`` (private; matplotlib's ``pyplot`` passed in)."""

from __future__ import annotations

import torch

__all__ = ["imu_figure", "reprojection_figure"]


def _residuals(term, spline):
    """Unwhitened residuals ``(N, k)`` of ``term`` (zero where masked) and its times."""
    with torch.no_grad():
        r = term(spline) * term.sigma
    return r.double().cpu().numpy(), term.times.double().cpu().numpy()


def reprojection_figure(res, plt):
    """Per camera: the pixel error's norm over time (and per-frame RMS), and the errors in
    the image (points at the measured pixels, coloured by the error's norm)."""
    C = len(res.cameras)
    fig, axes = plt.subplots(C, 2, figsize=(11, 3.2 * C), squeeze=False,
                             gridspec_kw={"width_ratios": [1.6, 1]})
    for i, term in enumerate(res.terms[:C]):
        r, t = _residuals(term, res.trajectory)
        used = term.mask.cpu().numpy()
        e = (r ** 2).sum(-1) ** 0.5
        t0 = t[used].min()
        ax = axes[i, 0]
        ax.plot(t[used] - t0, e[used], ".", ms=1.0, alpha=0.3, color="0.5", label="corner")
        frames, inv = torch.unique(torch.as_tensor(t[used]), return_inverse=True)
        sq = torch.zeros(frames.numel(), dtype=torch.float64).index_add_(
            0, inv, torch.as_tensor(e[used] ** 2))
        n = torch.bincount(inv, minlength=frames.numel()).clamp_min(1)
        ax.plot(frames.numpy() - t0, (sq / n).sqrt().numpy(), "-", lw=1.0, color="C0",
                label="frame RMS")
        ax.set_xlabel("time (s)")
        ax.set_ylabel(f"cam{i} error (px)")
        ax.set_title(f"cam{i}: reprojection RMS {float(res.reprojection_rms[i]):.3f} px",
                     fontsize=10)
        ax.legend(loc="upper right", fontsize=8)
        ax = axes[i, 1]
        uv = term.pixels.double().cpu().numpy()[used]
        sc = ax.scatter(uv[:, 0], uv[:, 1], c=e[used], s=1.0, cmap="viridis",
                        vmax=max(float(e[used].max()), 1e-9) if e[used].size else 1.0)
        w, h = res.cameras[i].resolution
        ax.set_xlim(0, w)
        ax.set_ylim(h, 0)
        ax.set_aspect("equal")
        ax.set_title(f"cam{i}: error in the image", fontsize=10)
        fig.colorbar(sc, ax=ax, label="px")
    fig.tight_layout()
    return fig


def imu_figure(res, plt):
    """Gyroscope and accelerometer residuals over time (IMU axes) and the biases with their
    standard deviations: bars for constant biases, steps over time with one-std bands for
    random-walk ones (``(K, 3)``, one row per segment of ``res.bias_edges``)."""
    gyro, accel = res.terms[-2], res.terms[-1]
    walk = res.bias_edges is not None
    fig, axes = plt.subplots(4 if walk else 3, 1, figsize=(10, 11 if walk else 8.5))
    t0 = float(gyro.times[0])
    for ax, term, label, unit in ((axes[0], gyro, "gyroscope", "rad/s"),
                                  (axes[1], accel, "accelerometer", "m/s$^2$")):
        r, t = _residuals(term, res.trajectory)
        if walk:  # the ties' rows are not readings
            keep = ~term.link.cpu().numpy()
            r, t = r[keep], t[keep]
        for k, name in enumerate("xyz"):
            ax.plot(t - t0, r[:, k], lw=0.5, label=name)
        ax.set_ylabel(f"{label} residual ({unit})")
        ax.legend(loc="upper right", fontsize=8, ncol=3)
    axes[1].set_xlabel("time (s)")
    biases = (("gyro_bias", "mrad/s", 1e3), ("accel_bias", "cm/s$^2$", 1e2))
    if walk:
        for ax, (key, unit, scale) in zip(axes[2:], biases, strict=True):
            _bias_steps(ax, res, key, unit, scale, t0)
        axes[3].set_xlabel("time (s)")
    else:
        _bias_bars(axes[2], res, biases)
    fig.tight_layout()
    return fig


def _bias_steps(ax, res, key, unit, scale, t0):
    """``res``'s random-walk bias ``key`` per axis as steps over its segments, with the
    one-standard-deviation band."""
    edges = res.bias_edges.double().cpu().numpy() - t0
    b, s = ((torch.cat((x, x[-1:])) * scale).double().cpu().numpy()  # last step drawn
            for x in (getattr(res, key), res.std[key]))
    for k, name in enumerate("xyz"):
        ax.step(edges, b[:, k], where="post", lw=1.0, color=f"C{k}", label=name)
        ax.fill_between(edges, b[:, k] - s[:, k], b[:, k] + s[:, k], step="post",
                        color=f"C{k}", alpha=0.2, lw=0)
    ax.set_ylabel(f"{key} ({unit})")
    ax.set_title(f"estimated {key}: {len(edges) - 1} segments tied by the random walk "
                 "(bands: one standard deviation)", fontsize=10)
    ax.legend(loc="upper right", fontsize=8, ncol=3)


def _bias_bars(ax, res, biases):
    """Constant biases as bars per axis with one-standard-deviation error bars."""
    x = torch.arange(3).numpy()
    for off, (key, unit, scale) in zip((-0.2, 0.2), biases, strict=True):
        ax.bar(x + off, (getattr(res, key) * scale).cpu().numpy(), width=0.35,
               yerr=(res.std[key] * scale).cpu().numpy(), capsize=3,
               label=f"{key} ({unit})")
    ax.set_xticks(x, ["x", "y", "z"])
    ax.axhline(0.0, color="0.3", lw=0.5)
    ax.set_title("estimated biases (error bars: one standard deviation)", fontsize=10)
    ax.legend(fontsize=8)
