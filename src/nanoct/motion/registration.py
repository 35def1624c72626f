"""Sub-pixel 2-D registration of many image pairs at once (batched cross-correlation).

For image pairs ``(a_k, b_k)`` with ``b_k(z, x) = a_k(z + s_z, x + s_x)`` (``b`` is ``a`` moved up
and left by ``s``), :func:`register_shifts` returns ``s`` per pair: the peak of the
cross-correlation, found on the integer grid and refined by Newton steps on its band-limited
(trigonometric) interpolation, which is exact for shifted band-limited images. Both images are
tapered to zero near their edges and high-pass filtered first (a smooth background, such as the
open beam or the mass of an object wider than the field of view, carries no lag).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import scipy.fft as sfft

__all__ = ["register_shifts", "taper_window"]


def taper_window(shape: tuple[int, int], margin: tuple[int, int]) -> np.ndarray:
    """Separable cosine taper: zero at the edges, rising over ``margin`` pixels, one in the middle."""
    parts = []
    for n, m in zip(shape, margin):
        w = np.ones(n)
        m = int(min(max(m, 0), n // 4))
        if m > 0:
            ramp = 0.5 - 0.5 * np.cos(np.pi * (np.arange(m) + 0.5) / m)
            w[:m] = ramp
            w[n - m :] = ramp[::-1]
        parts.append(w)
    return np.outer(parts[0], parts[1])


def register_shifts(
    a: Any,
    b: Any,
    *,
    sigma: float = 4.0,
    smooth: float = 0.0,
    margin: tuple[int, int] = (4, 4),
    max_shift: tuple[float, float] | None = None,
    newton_steps: int = 5,
) -> np.ndarray:
    """Shift ``s = (s_z, s_x)`` per pair with ``b_k(z, x) = a_k(z + s_z, x + s_x)``.

    Parameters
    ----------
    a, b : array_like of shape (K, R, L)
        Reference and moved images.
    sigma : float
        High-pass: the Gaussian of this width (pixels) is removed from both spectra (0: none).
    smooth : float
        Low-pass: both images blurred by a Gaussian of this width (pixels; 0: none).
    margin : (int, int)
        Taper width along rows and columns (pixels).
    max_shift : (float, float), optional
        Largest ``|s_z|`` and ``|s_x|`` searched (default: a quarter of the image).
    newton_steps : int
        Sub-pixel refinement steps.

    Returns
    -------
    ndarray of shape (K, 2), float64
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.shape != b.shape or a.ndim != 3:
        raise ValueError(f"register_shifts needs two arrays of the same shape (K, R, L); got {a.shape} and {b.shape}")
    _, n_r, n_l = a.shape
    window = taper_window((n_r, n_l), margin)
    limit = max_shift if max_shift is not None else (n_r / 4, n_l / 4)
    # no wrap-around within the searched lags
    size = (sfft.next_fast_len(n_r + int(np.ceil(limit[0])) + 2), sfft.next_fast_len(n_l + int(np.ceil(limit[1])) + 2))
    fz = sfft.fftfreq(size[0])[:, None]
    fx = sfft.rfftfreq(size[1])[None, :]
    f2 = fz**2 + fx**2
    keep = (1.0 - np.exp(-2 * (np.pi * sigma) ** 2 * f2) if sigma > 0 else 1.0) * np.exp(
        -2 * (np.pi * smooth) ** 2 * f2
    )
    spec_a = sfft.rfft2((a - a.mean(axis=(1, 2), keepdims=True)) * window, size, workers=-1) * keep
    spec_b = sfft.rfft2((b - b.mean(axis=(1, 2), keepdims=True)) * window, size, workers=-1) * keep
    spec = spec_a * np.conj(spec_b)  # c(t) = sum_y a(y + t) b(y): peak at t = s
    corr = sfft.irfft2(spec, size, workers=-1)
    lag_z = sfft.fftfreq(size[0], 1.0 / size[0])
    lag_x = sfft.fftfreq(size[1], 1.0 / size[1])
    allowed = (np.abs(lag_z)[:, None] <= limit[0]) & (np.abs(lag_x)[None, :] <= limit[1])
    corr = np.where(allowed, corr, -np.inf)
    flat = np.argmax(corr.reshape(corr.shape[0], -1), axis=1)
    iz, ix = np.unravel_index(flat, size)
    tau = np.stack([lag_z[iz], lag_x[ix]], axis=1)
    return _refine(spec, tau, size, newton_steps)


def _refine(spec: np.ndarray, tau: np.ndarray, size: tuple[int, int], steps: int) -> np.ndarray:
    """Newton steps to the maximum of ``c(t) = Re sum_w W(w) S(w) exp(i w . t)`` near ``tau``."""
    wz = 2 * np.pi * sfft.fftfreq(size[0])[:, None]
    wx = 2 * np.pi * sfft.rfftfreq(size[1])[None, :]
    weight = np.full(spec.shape[1:], 2.0)  # the half spectrum of a real correlation counts twice ...
    weight[:, 0] = 1.0  # ... except its zero and Nyquist columns
    if size[1] % 2 == 0:
        weight[:, -1] = 1.0
    s = spec * weight
    start = tau.copy()
    for _ in range(steps):
        phase = s * np.exp(1j * (wz[None] * tau[:, 0, None, None] + wx[None] * tau[:, 1, None, None]))
        gz = -(phase.imag * wz).sum(axis=(1, 2))
        gx = -(phase.imag * wx).sum(axis=(1, 2))
        hzz = -(phase.real * wz**2).sum(axis=(1, 2))
        hxx = -(phase.real * wx**2).sum(axis=(1, 2))
        hzx = -(phase.real * wz * wx).sum(axis=(1, 2))
        det = hzz * hxx - hzx**2
        ok = (hzz < 0) & (det > 0)  # a maximum: negative definite Hessian
        safe = np.where(ok, det, 1.0)
        dz = np.where(ok, -(hxx * gz - hzx * gx) / safe, 0.0)
        dx = np.where(ok, -(hzz * gx - hzx * gz) / safe, 0.0)
        tau = np.clip(tau + np.stack([dz, dx], axis=1), start - 1.0, start + 1.0)
    return tau
