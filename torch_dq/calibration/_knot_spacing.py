r"""The body trajectory's knot spacing chosen from the IMU readings and their noise densities
(private; :func:`~torch_dq.calibration.camera_imu` with ``knot_spacing=None``).

The rule. Fitted to dense readings, a cubic B-spline with knots every ``h`` gives the IMU's
model: its first derivative (rotation) the gyroscope's, its second (position) the
accelerometer's. A reading's signal component at frequency ``f`` that the spline cannot
follow stays in the residuals as model error, on top of the white noise. For uniform knots
the best (least-squares) approximation of :math:`e^{i\omega t}` by the ``k``-th derivative
of a cubic spline (the shifts of :math:`\beta_3^{(k)}`, whose Fourier transform is
:math:`(i\omega)^k \mathrm{sinc}^4(\omega/2)` with ``h = 1``) leaves the fraction

.. math::

    \varepsilon_k^2(\omega) = \frac{r}{1 + r}, \qquad
    r = \sum_{m \ne 0} \Big(\frac{\omega}{\omega + 2\pi m}\Big)^{8 - 2k}, \qquad
    \omega = 2 \pi f h

of its power (Unser, "Sampling-50 years after Shannon", Proc. IEEE 88(4), 2000, eq. 28: the
error of the orthogonal projection onto a shift-invariant space; :math:`\mathrm{sinc}^8` is
periodic up to the power of :math:`\omega`, which leaves the ratio above). For small
:math:`fh`: :math:`\varepsilon_1^2 \approx 2\zeta(6)(fh)^6`, :math:`\varepsilon_2^2 \approx
2\zeta(4)(fh)^4` (gyroscope, accelerometer). The signals' one-sided power spectral density
``S(f)`` (Welch, summed over the three axes) minus the white noise's ``6 density^2`` is the
signal; the model error then adds

.. math::

    \Delta\chi^2/\mathrm{dof} = \frac{c_k \int \varepsilon_k^2(2\pi f h)\,
    S_\mathrm{signal}(f)\, df}{3\,\sigma^2\,(1 - 1/(h\,\mathrm{rate}))}, \qquad
    \sigma^2 = \mathrm{density}^2 \cdot \mathrm{rate}

to the term's chi2/dof (1 for the noise alone): the misfit per reading (a least-squares
residual, orthogonal to what the spline fits: the parameters take none of it) over the
term's dof per reading, ``1 - 1 / (h rate)`` (each knot's three coordinates that the term
reads, against three readings per sample: measured, the accelerometer's exact dof
``N - 3.0 T / h``). The signals: the gyroscope's readings; for the accelerometer, the rate of the
body-axes velocity :math:`\dot u = f + R^T g - \omega \times u` (the caller's, from the
start trajectory): the cumulative (SE(3)) spline's body twist is the derivative of its local
cubic, so it models :math:`\dot u`, not the readings (the product :math:`\omega \times u`
puts power at higher frequencies; :math:`R^T g` comes with the rotation). :math:`c_1 = 1`;
:math:`c_2` = ``ACCEL_MARGIN`` (2) for the couplings of rotation and translation in the
cumulative spline's increments that :math:`\dot u` leaves out (measured on simulated rigs,
the accelerometer's model error alone, noise-free readings: 0.9 times :math:`\dot u`'s
prediction on a gentle motion, 2.0 to 2.6 on the EuRoC stand-in's calibration dance, 2.2 on
one 2.5 times faster; a plain cubic fitted to the readings predicted 0.64 and 0.35 of it).
The spacing chosen is the largest ``h`` at most ``coarsest`` (0.05 s: slow motions keep it,
and their time) and at least 0.01 s (and two IMU periods) for which both terms' excess is at
most ``EXCESS`` (0.05: honest uncertainties, the standard deviations too small by at most
2.5 %). Only the bins where the spectrum stands clearly above the noise count as signal (by
four standard deviations of Welch's estimate of the noise there), so that the noise's own
scatter adds nothing; where the spectrum's median over the upper half of the band (above
``rate / 4``, beyond any calibration dance) lies above the densities' floor, that median is
the floor (densities too small: the readings' noise is not motion, and finer knots would not
lower their chi2/dof).

Measured against the estimate (``tests/_camera_imu_sim.py``, its gentle rig and the EuRoC
stand-in): the accelerometer's chi2/dof 1.26 with the earlier rule (0.15, the readings'
spectrum, per reading), 1.02 to 1.07 with this one (knots every 0.026 to 0.027 s).
"""

from __future__ import annotations

import math

import numpy as np

#: the excess chi2/dof of each IMU term the model error may add
EXCESS = 0.05
#: the accelerometer's prediction's factor (the cumulative spline's couplings: docstring)
ACCEL_MARGIN = 2.0
_SEGMENT = 2.0  # seconds per Welch segment (0.5 Hz bins)
_FINEST = 0.01  # seconds: the finest spacing (also at least two IMU periods)
_ALIASES = 16  # terms m = -16..16 of the sum over aliases (the rest: < 1e-4 of it)


def spline_loss(omega: np.ndarray, order: int) -> np.ndarray:
    r""":math:`\varepsilon_k^2(\omega)`: the fraction of a sinusoid's power at
    ``omega = 2 pi f h`` (radians per knot span, any shape) that the ``order``-th derivative
    of a uniform cubic B-spline (``order`` 0 to 3) leaves unexplained (least squares over
    continuous time); 0 at 0, 1 at the multiples of ``2 pi``."""
    w = np.abs(np.asarray(omega, dtype=np.float64))[..., None]
    m = np.arange(-_ALIASES, _ALIASES + 1, dtype=np.float64)
    m = m[m != 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        r = ((w / (w + 2 * np.pi * m)) ** (8 - 2 * order)).sum(-1)
        return np.where(np.isfinite(r), r / (1 + r), 1.0)


def _segments(x: np.ndarray, segment: int) -> np.ndarray:
    """``x (N, 3)`` cut into segments of ``segment`` samples overlapping by half:
    ``(K, segment, 3)``."""
    starts = np.arange(0, x.shape[0] - segment + 1, segment // 2)
    return np.stack([x[s:s + segment] for s in starts])


def welch(seg: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """One-sided power spectral density of the segments ``seg (K, L, 3)`` of a signal
    sampled at ``rate``, averaged over the segments and summed over the axes; returns
    ``(frequencies (F,), psd (F,))``, ``psd`` in units^2/Hz (its integral over
    ``[0, rate/2]`` the variance) and 0 at 0 Hz. Each segment is differenced (its straight
    line, biases and drift, becomes the mean, removed), Hann-windowed and transformed, and
    the spectrum divided by the difference's gain ``(2 sin(pi f / rate))^2``: the
    difference flattens the spectrum first, or the motion's power at a few Hz (50 dB above
    the noise) would leak through the window's side lobes into the bins above."""
    d = np.diff(seg, axis=1)
    d = d - d.mean(1, keepdims=True)
    n = d.shape[1]
    win = np.hanning(n)
    spec = np.abs(np.fft.rfft(d * win[None, :, None], axis=1)) ** 2
    psd = spec.mean(0).sum(-1) * 2.0 / (rate * (win ** 2).sum())
    freq = np.fft.rfftfreq(n, 1.0 / rate)
    gain = (2.0 * np.sin(np.pi * freq / rate)) ** 2
    psd = np.divide(psd, gain, out=np.zeros_like(psd), where=gain > 0)
    if n % 2 == 0:
        psd[-1] /= 2.0
    return freq, psd


def excess(freq: np.ndarray, signal: np.ndarray, sigma2: float, h: float, order: int,
           rate: float) -> float:
    """The chi2/dof that a spline with knots every ``h`` adds to a term whose readings
    (``rate`` per second) have the signal spectrum ``signal`` (``psd`` minus the noise, over
    ``freq``) and the per-sample variance ``sigma2`` per axis: the misfit per reading over
    the share ``1 - 1 / (h rate)`` of the readings that the term's dof keep."""
    df = float(freq[1] - freq[0])
    loss = (spline_loss(2 * np.pi * freq * h, order) * signal).sum() * df / (3 * sigma2)
    return float(loss / (1.0 - 1.0 / (h * rate)))


def choose(times: np.ndarray, readings: tuple[np.ndarray, np.ndarray],
           densities: tuple[float, float], coarsest: float = 0.05
           ) -> tuple[float, dict[str, float]]:
    """The knot spacing (seconds) for the IMU ``times (N,)`` and signals ``readings``
    ``(gyro (N, 3), accel (N, 3))`` (the gyroscope's readings; the accelerometer's, or the
    body velocity's rate that the cumulative spline models: module docstring) with noise
    ``densities`` (module docstring's rule), and what it predicts: ``{"gyro": excess,
    "accel": excess, "gyro_hz": f, "accel_hz": f}`` (the excess chi2/dof at the chosen
    spacing, above ``EXCESS`` where even the finest spacing leaves more; the highest
    frequency clearly above the noise)."""
    rate = 1.0 / float(np.median(np.diff(times)))
    finest = min(coarsest, max(2.0 / rate, _FINEST))
    segment = min(round(_SEGMENT * rate), times.size // 2)
    terms = []
    out: dict[str, float] = {}
    for name, x, density, order, margin in zip(("gyro", "accel"), readings, densities, (1, 2),
                                               (1.0, ACCEL_MARGIN), strict=True):
        seg = _segments(x, segment)
        freq, psd = welch(seg, rate)
        # the white noise's floor: the densities', or the spectrum's median over the upper
        # half of the band where that is higher (densities too small: their floor would
        # count the noise as motion, down to the finest spacing)
        floor = max(6.0 * density ** 2, float(np.median(psd[freq > rate / 4])))
        clear = psd > floor * (1.0 + 4.0 / math.sqrt(3.0 * seg.shape[0]))
        signal = np.where(clear, psd - floor, 0.0) * margin
        out[f"{name}_hz"] = float(freq[clear].max()) if clear.any() else 0.0
        terms.append((name, freq, signal, floor * rate / 6.0, order))

    def worst(h: float) -> float:
        return max(excess(f, s, v, h, o, rate) for _, f, s, v, o in terms)

    h = coarsest
    if worst(h) > EXCESS:
        lo, hi = math.log(finest), math.log(coarsest)
        for _ in range(16):  # bisection on log h (to 2e-5 of it): the excess grows with h
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if worst(math.exp(mid)) <= EXCESS else (lo, mid)
        h = math.exp(lo)
    out.update({name: excess(f, s, v, h, o, rate) for name, f, s, v, o in terms})
    return h, out
