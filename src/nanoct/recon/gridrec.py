"""Fourier (gridding) reconstruction for parallel beam: FBP computed in Fourier space.

The filtered back projection ``x(r) = sum_k w_k f_k(r . e_k / s + c - d_k)`` (``f_k`` the
ramp-filtered view ``k``, ``w_k`` its angular weight, ``s`` the detector spacing, ``c`` the
detector position of the rotation axis and ``d_k`` the per-view shift in detector pixels: the
measured view is ``p_k(u) = P_k(u + d_k)``, see ``docs/conventions.md``) is, with each filtered
view written as its Fourier series of period ``M``,

    x(r) = sum_k sum_m  w_k / M * F_k[m] * exp(2 pi i m (c - d_k) / M) * exp(i omega_m r . e_k),

``omega_m = 2 pi m / (M s)``: the adjoint of the Fourier slice theorem, a type-1 non-uniform FFT
from the polar samples ``omega_m e_k`` to the image grid. The axis offset and the per-view
shifts are exact phase ramps; nothing is interpolated in real space. Each view is filtered as
:func:`~nanoct.recon.fbp.ramp_filter` does (the same Ram-Lak or Hann filter, zero-padded to a
power of two at least ``2 L``, truncated to the ``L`` detector pixels), then transformed again
with a period ``M`` just long enough that the periodic copies of the detector stay clear of the
image (shifts and axis included). With ``interpolation="linear"`` (default) every frequency is
also weighted by ``sinc^2(m / M)``, the response of the linear interpolation in nanoct's
pixel-driven back projection, so the images agree with :func:`~nanoct.recon.fbp.fbp` to
about 1e-4 of the phantom's range; ``"sinc"`` keeps the exact band-limited interpolation.

Two real slices go through one complex transform (``slice_a + i slice_b``: every factor above
is real-linear), so a stack costs one NUFFT per pair of slices. The non-uniform FFT is
``finufft`` on the CPU, ``cufinufft`` (with torch CUDA tensors for the FFTs) where a CUDA device
and ``cufinufft`` are present; :func:`select_backend` chooses. Fan beam has no such form here:
use :func:`~nanoct.recon.fbp.fbp`.
"""

from __future__ import annotations

import importlib
import importlib.util
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.fft as sfft

from ..core.errors import NanoctError
from ..core.fanout import usable_cpus
from ..core.geometry import Geometry
from ..core.operators import RayTransform
from ..core.validation import check_array, check_choice, check_float, check_int
from .fbp import FILTERS, ramp_response
from .params import MethodParams, resolve_geometry
from .result import ReconResult

__all__ = [
    "BACKENDS",
    "GPU_DEVICE",
    "GPU_PAIRS",
    "INTERPOLATIONS",
    "GridrecParams",
    "GridrecPlan",
    "backend_label",
    "cached_plan",
    "gpu_available",
    "gridrec",
    "gridrec_available",
    "gridrec_slices",
    "select_backend",
]

#: Non-uniform FFT libraries: ``auto`` picks ``cufinufft`` where a GPU is usable, else ``finufft``.
BACKENDS = ("auto", "finufft", "cufinufft")
#: ``linear``: weighted as FBP's linear interpolation on the detector; ``sinc``: exact band-limited.
INTERPOLATIONS = ("linear", "sinc")
#: Pairs of slices per cufinufft call (the GPU is kept busy with a batch of transforms).
GPU_PAIRS = 8
#: Torch device of the ``cufinufft`` backend (a test runs that path on the CPU with a stand-in library).
GPU_DEVICE = "cuda"


def _importable(module: str) -> bool:
    return importlib.util.find_spec(module) is not None


def gridrec_available() -> bool:
    """Whether the CPU non-uniform FFT (``finufft``) can be imported."""
    return _importable("finufft")


def gpu_available() -> bool:
    """Whether the GPU path can run: ``cufinufft`` importable and torch sees a CUDA device."""
    if not _importable("cufinufft"):
        return False
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a dependency
        return False
    return bool(torch.cuda.is_available())


def select_backend(backend: str = "auto") -> str:
    """The non-uniform FFT library to use: ``cufinufft`` where a GPU is usable, else ``finufft``.

    Parameters
    ----------
    backend : {"auto", "finufft", "cufinufft"}
        ``auto`` chooses; a name insists on that library.

    Returns
    -------
    str
        ``"finufft"`` or ``"cufinufft"``.

    Raises
    ------
    NanoctError
        If the chosen library (or, for ``cufinufft``, a CUDA device) is missing.
    """
    check_choice(backend, "backend", BACKENDS)
    if backend in ("auto", "cufinufft") and gpu_available():
        return "cufinufft"
    if backend == "cufinufft":
        raise NanoctError("backend='cufinufft' needs cufinufft and a CUDA device; use backend='finufft' or 'auto'")
    if not gridrec_available():
        raise NanoctError("gridrec needs finufft: pip install finufft (or use --method fbp)")
    return "finufft"


def backend_label(backend: str) -> str:
    """``"gridrec/<library> <version>"``: what a result records as the engine that made it."""
    module = importlib.import_module(backend)
    return f"gridrec/{backend} {getattr(module, '__version__', '?')}"


def _filter_response(size: int, spacing: float, filter: str) -> np.ndarray:
    """The DFT (length ``size``) of :func:`~nanoct.recon.fbp.ramp_filter`'s kernel, times ``spacing``."""
    return ramp_response(size, spacing, filter) * spacing


def _period(geometry: Geometry, shifts: np.ndarray, axis_range: float = 0.0) -> int:
    """The Fourier period M (detector pixels) whose periodic copies of the detector miss every image pixel.

    ``axis_range``: per-slice axis offsets within ``+-axis_range`` of the geometry's are allowed too.
    """
    centre = (geometry.n_det - 1) / 2 + geometry.center_offset
    reach = (geometry.n - 1) / 2 * np.sqrt(2.0) / geometry.det_spacing + axis_range  # detector pixels
    top = centre - float(shifts.min()) + reach  # largest detector position an image pixel reads
    bottom = centre - float(shifts.max()) - reach  # smallest
    need = max(top, geometry.n_det - 1 - bottom, geometry.n_det) + 16  # + the interpolant's tails
    return int(sfft.next_fast_len(int(np.ceil(need))))


def _polar_samples(geometry: Geometry, shifts: np.ndarray, period: int, interpolation: str, dtype: Any) -> tuple:
    """Points ``(x, y)`` (row and column frequencies, wrapped to [-pi, pi)) and the weights (K, M) of every sample.

    The weight of sample ``(k, m)`` is ``w_k / M * H(m) * exp(i phase)``, the phase holding the
    axis, the shift ``d_k`` and the half-pixel offset of the image grid of even size relative to
    the NUFFT's integer modes (pixel centre ``r1 = k1 + delta``, ``r2 = -(k2 + delta)``).
    """
    phi = geometry.angles
    m = np.fft.fftfreq(period) * period  # integer frequencies in FFT order
    omega = 2 * np.pi * m / (period * geometry.det_spacing)
    delta = geometry.n // 2 - (geometry.n - 1) / 2
    cos, sin = np.cos(phi)[:, None], np.sin(phi)[:, None]
    centre = (geometry.n_det - 1) / 2 + geometry.center_offset
    phase = 2 * np.pi * m[None] * (centre - shifts[:, None]) / period + delta * omega[None] * (cos - sin)
    gain = np.sinc(m / period) ** 2 if interpolation == "linear" else np.ones(period)
    if period % 2 == 0:
        gain[period // 2] = 0.0  # the Nyquist sample alone is not real-symmetric: left out
    weights = (geometry.angle_weights[:, None] / period) * gain[None] * np.exp(1j * phase)
    real = np.float32 if dtype == np.complex64 else np.float64
    rows = np.mod(-omega[None] * sin + np.pi, 2 * np.pi) - np.pi  # modes are integers: 2 pi periodic
    cols = np.mod(omega[None] * cos + np.pi, 2 * np.pi) - np.pi
    return rows.ravel().astype(real), cols.ravel().astype(real), weights.astype(dtype)


#: finufft's upsampling factor on the CPU (double precision). Measured at 1800 views x 2048
#: columns to a 2048^2 image, one pair of slices on one thread: 0.66 s with an error of 3.7e-6 of
#: the image's L2 norm (2.2e-5 of its maximum) against a 1e-9 transform; single precision at the
#: default 2.0 took 1.28 s for 9.5e-5 (1.3e-4), single at 1.25 0.43 s for 1.4e-4 (2.5e-4).
UPSAMPFAC = 1.25


def _options(engine: Any) -> dict[str, Any]:
    """finufft's ``eps`` and ``upsampfac`` (:data:`UPSAMPFAC` down to ``eps = 1e-9``, where its kernel reaches)."""
    return {"eps": engine.eps, "upsampfac": UPSAMPFAC if engine.eps >= 1e-9 else 2.0}


class _FinufftEngine:
    """CPU: scipy FFTs and one single-threaded finufft type-1 plan per thread (points set once each).

    The pairs of a call are transformed side by side, one plan (and one thread) each: every
    image is computed by the same single-threaded steps whatever the number of threads or pairs
    per call, so the result is the same bit for bit on every run and every machine setting
    (finufft's own multithreaded spreading adds into one grid in thread order).
    """

    def __init__(self, points: tuple, weights: np.ndarray, response: np.ndarray, n: int, eps: float) -> None:
        self.points, self.weights, self.n, self.eps, self.dtype = points, weights, n, eps, weights.dtype
        self.response = response.astype(weights.real.dtype)
        self._plans: list[Any] = []

    def _plan(self, index: int) -> Any:
        while len(self._plans) <= index:
            import finufft

            plan = finufft.Plan(
                1, (self.n, self.n), isign=1, dtype=np.dtype(self.dtype).name, nthreads=1, **_options(self)
            )
            plan.setpts(*self.points)
            self._plans.append(plan)
        return self._plans[index]

    def _spectra(self, views: np.ndarray, filtered: bool) -> np.ndarray:
        """(B, K, L) views -> (B, K, M) Fourier coefficients of the (filtered) views, period M."""
        n_det, pad, period = views.shape[-1], self.response.size, self.weights.shape[1]
        views = views.astype(self.dtype, copy=False)
        if filtered:
            spectrum = sfft.fft(views, n=pad, axis=-1, workers=-1)
            spectrum *= self.response
            views = sfft.ifft(spectrum, axis=-1, workers=-1, overwrite_x=True)[..., :n_det]
        return sfft.fft(views, n=period, axis=-1, workers=-1)

    def __call__(self, block: np.ndarray, filtered: bool = True, ramps: np.ndarray | None = None) -> np.ndarray:
        """(2P, K, L) real views -> (P, N, N) complex images (real part slice 2p, imaginary part slice 2p + 1).

        ``filtered=False``: the views are already filtered (only the back projection is done).
        ``ramps`` (2P, M): a phase ramp per slice (its own axis); the pairs are packed after it.
        """
        if ramps is None:  # pack first: one complex FFT per pair
            coefficients = self._spectra(block[0::2] + 1j * block[1::2], filtered)
        else:
            spectra = self._spectra(block, filtered) * ramps.astype(self.dtype)[:, None, :]
            coefficients = spectra[0::2] + 1j * spectra[1::2]
        coefficients *= self.weights
        plans = [self._plan(i) for i in range(coefficients.shape[0])]
        if len(plans) == 1:
            return plans[0].execute(coefficients[0].ravel())[None]
        with ThreadPoolExecutor(len(plans)) as pool:  # finufft releases the GIL
            return np.stack(list(pool.map(lambda i: plans[i].execute(coefficients[i].ravel()), range(len(plans)))))


class _CufinufftEngine:
    """GPU: torch FFTs on :data:`GPU_DEVICE` and cufinufft type-1 plans (the steps of :class:`_FinufftEngine`)."""

    def __init__(self, points: tuple, weights: np.ndarray, response: np.ndarray, n: int, eps: float) -> None:
        import torch

        self.torch, self.device, self.dtype, self.n, self.eps = torch, torch.device(GPU_DEVICE), weights.dtype, n, eps
        self.weights = torch.as_tensor(weights, device=self.device)
        self.response = torch.as_tensor(response.astype(weights.real.dtype), device=self.device)
        self.points = [torch.as_tensor(p, device=self.device) for p in points]  # kept alive with the plans
        self._plans: dict[int, Any] = {}

    def _plan(self, n_trans: int) -> Any:
        if n_trans not in self._plans:
            import cufinufft

            plan = cufinufft.Plan(
                1, (self.n, self.n), n_trans=n_trans, eps=self.eps, isign=1, dtype=np.dtype(self.dtype).name
            )
            plan.setpts(*self.points)
            self._plans[n_trans] = plan
        return self._plans[n_trans]

    def __call__(self, block: np.ndarray, filtered: bool = True, ramps: np.ndarray | None = None) -> np.ndarray:
        """(2P, K, L) real views -> (P, N, N) complex images, computed on the device (see :class:`_FinufftEngine`)."""
        fft, n_det = self.torch.fft, block.shape[-1]
        views = self.torch.as_tensor(block.astype(self.dtype), device=self.device)
        if ramps is None:
            views = views[0::2] + 1j * views[1::2]
        if filtered:
            views = fft.ifft(fft.fft(views, n=self.response.numel(), dim=-1) * self.response, dim=-1)[..., :n_det]
        spectra = fft.fft(views, n=self.weights.shape[1], dim=-1)
        if ramps is not None:
            spectra = spectra * self.torch.as_tensor(ramps.astype(self.dtype), device=self.device)[:, None, :]
            spectra = spectra[0::2] + 1j * spectra[1::2]
        count = spectra.shape[0]
        out = self._plan(count).execute((spectra * self.weights).reshape(count, -1).contiguous())
        return out.reshape(count, self.n, self.n).cpu().numpy()


@dataclass(frozen=True)
class GridrecParams(MethodParams):
    """The parameters of :func:`gridrec`.

    Parameters
    ----------
    filter : {"ram-lak", "hann"}
        Reconstruction filter, as :func:`~nanoct.recon.fbp.fbp`'s (default Ram-Lak).
    interpolation : {"linear", "sinc"}
        Detector interpolation modelled: ``linear`` weights each frequency as the linear
        interpolation of FBP's back projection does (images match FBP's), ``sinc`` is the exact
        band-limited one (a little sharper).
    eps : float
        Relative tolerance of the non-uniform FFT, in [1e-12, 1e-2] (default 1e-5); on the CPU in
        double precision at upsampling :data:`UPSAMPFAC`, on the GPU in single precision at 1e-5
        and above.
    backend : {"auto", "finufft", "cufinufft"}
        Non-uniform FFT library; ``auto``: the GPU (cufinufft) where usable, else finufft.
    """

    filter: str = "ram-lak"
    interpolation: str = "linear"
    eps: float = 1e-5
    backend: str = "auto"

    def __post_init__(self) -> None:
        self._set("filter", check_choice(self.filter, "filter", FILTERS))
        self._set("interpolation", check_choice(self.interpolation, "interpolation", INTERPOLATIONS))
        self._set("eps", check_float(self.eps, "eps", low=1e-12, high=1e-2))
        self._set("backend", check_choice(self.backend, "backend", BACKENDS))

    def resolve(self, geometry: Geometry) -> dict[str, Any]:
        """The values for ``geometry``, which must be parallel beam."""
        if geometry.kind != "parallel":
            raise ValueError("gridrec handles parallel beam only; use fbp for a fan-beam scan")
        return super().resolve(geometry)


class GridrecPlan:
    """Everything that depends only on the geometry and the shifts, built once for many slices.

    Parameters
    ----------
    geometry : Geometry
        Parallel-beam geometry (angles with their quadrature weights, axis offset).
    shifts : array_like of shape (K,), optional
        Per-view shifts ``d_k`` in detector pixels (view ``k`` read at ``u - d_k``, as
        :func:`~nanoct.recon.stack.corrected_fbp`). Default: none.
    filter, interpolation, eps, backend
        See :class:`GridrecParams`.
    threads : int, optional
        Pairs of slices transformed at once on the CPU, one thread each (default: the usable
        CPUs); on the GPU at least :data:`GPU_PAIRS` pairs go in one call.
    axis_range : float
        Largest per-slice change of the axis offset (detector pixels) the calls may ask for
        (``axis=``, e.g. a tilted axis); it lengthens the period by as much.

    Attributes
    ----------
    backend : str
        The library that runs (``"finufft"`` or ``"cufinufft"``).
    period : int
        Length M of each view's Fourier series (the number of polar samples per view).
    """

    def __init__(
        self,
        geometry: Geometry,
        shifts: Any = None,
        *,
        filter: str = "ram-lak",
        interpolation: str = "linear",
        eps: float = 1e-5,
        backend: str = "auto",
        threads: int | None = None,
        axis_range: float = 0.0,
    ) -> None:
        self.threads = usable_cpus() if threads is None else check_int(threads, "threads", 1)
        self.axis_range = check_float(axis_range, "axis_range", low=0.0)
        params = GridrecParams.check(geometry, filter=filter, interpolation=interpolation, eps=eps, backend=backend)
        k = geometry.n_angles
        d = np.zeros(k) if shifts is None else check_array(shifts, "shifts", shape=(k,), dtype=np.float64)
        self.geometry, self.backend = geometry, select_backend(params["backend"])
        self.period = _period(geometry, d, self.axis_range)
        gpu_single = self.backend == "cufinufft" and params["eps"] >= 1e-5
        dtype = np.complex64 if gpu_single else np.complex128  # the CPU: double (:data:`UPSAMPFAC`)
        *points, weights = _polar_samples(geometry, d, self.period, params["interpolation"], dtype)
        pad = int(2 ** np.ceil(np.log2(2 * geometry.n_det)))
        response = _filter_response(pad, geometry.det_spacing, params["filter"])
        engine = _CufinufftEngine if self.backend == "cufinufft" else _FinufftEngine
        self._engine = engine(tuple(points), weights, response, geometry.n, params["eps"])

    def __call__(self, sinograms: Any, axis: Any = None) -> np.ndarray:
        """Reconstruct slices, two per transform.

        Parameters
        ----------
        sinograms : array_like of shape (S, K, L) or (K, L)
            Line integrals of each slice; must be finite.
        axis : array_like of shape (S,), optional
            Each slice's axis offset minus the geometry's, in detector pixels, within
            ``+-axis_range`` (a phase ramp per slice, applied before two slices share a transform).

        Returns
        -------
        ndarray of shape (S, N, N) or (N, N), float32
        """
        return self._run(sinograms, "sinograms", filtered=True, axis=axis)

    def backproject(self, views: Any) -> np.ndarray:
        """The weighted back projection ``sum_k w_k v_k(r . e_k / s + c - d_k)`` of views already filtered.

        Parameters
        ----------
        views : array_like of shape (S, K, L) or (K, L)
            One value per view and detector pixel (e.g. :func:`~nanoct.recon.fbp.ramp_filter`'s output).

        Returns
        -------
        ndarray of shape (S, N, N) or (N, N), float32
        """
        return self._run(views, "views", filtered=False)

    def _ramps(self, axis: Any, count: int) -> np.ndarray | None:
        """(S, M) phase ramps ``exp(2 pi i m a_s / M)`` of the per-slice axis offsets, or None."""
        if axis is None:
            return None
        a = check_array(axis, "axis", shape=(count,), dtype=np.float64)
        if np.abs(a).max(initial=0.0) > self.axis_range + 1e-9:
            raise ValueError(f"axis offsets up to {np.abs(a).max():.3g} px exceed axis_range={self.axis_range:g}")
        m = np.fft.fftfreq(self.period) * self.period
        return np.exp(2j * np.pi * a[:, None] * m[None] / self.period)

    def _run(self, data: Any, label: str, filtered: bool, axis: Any = None) -> np.ndarray:
        sino = np.asarray(data)
        single = sino.ndim == 2
        sino = check_array(sino[None] if single else sino, label, ndim=3, dtype=None)
        if sino.shape[1:] != self.geometry.sino_shape:
            raise ValueError(f"{label} have shape {sino.shape[1:]} per slice, expected {self.geometry.sino_shape}")
        count = sino.shape[0]
        ramps = self._ramps(np.atleast_1d(axis) if axis is not None else None, count)
        out = np.empty((count, self.geometry.n, self.geometry.n), dtype=np.float32)
        # slices per call: one pair per thread on the CPU, at least 8 pairs per call on the GPU
        step = 2 * (self.threads if self.backend == "finufft" else max(self.threads, GPU_PAIRS))
        for first in range(0, count, step):
            stop = min(first + step, count)
            block = np.zeros((stop - first + (stop - first) % 2, *sino.shape[1:]), dtype=sino.dtype)
            block[: stop - first] = sino[first:stop]  # an odd count: a zero slice fills the last pair
            part = None if ramps is None else np.concatenate([ramps[first:stop], ramps[:1]])[: block.shape[0]]
            images = self._engine(block, filtered, part)
            out[first:stop:2] = images.real
            out[first + 1 : stop : 2] = images.imag[: (stop - first) // 2]
        return out[0] if single else out


_CACHE: dict[tuple, GridrecPlan] = {}


def cached_plan(geometry: Geometry, shifts: np.ndarray | None = None, **params: Any) -> GridrecPlan:
    """The :class:`GridrecPlan` of the last call with the same geometry, shifts and parameters, or a new one.

    One plan is kept (the last), so a loop of single-slice calls on one geometry (the batch
    runner, notebooks) builds it once. ``params`` are those of :class:`GridrecPlan`; the library
    chosen by ``backend`` is part of the key.
    """
    d = None if shifts is None else np.asarray(shifts, dtype=np.float64)
    backend = select_backend(params.get("backend", "auto"))
    key = (geometry, None if d is None else d.tobytes(), tuple(sorted(params.items())), backend)
    if key not in _CACHE:
        _CACHE.clear()
        _CACHE[key] = GridrecPlan(geometry, d, **params)
    return _CACHE[key]


def gridrec_slices(geometry: Geometry, sinograms: Any, shifts: Any = None, **params: Any) -> np.ndarray:
    """Reconstruct a stack of slices with one geometry and one per-view shift, two slices per transform.

    Parameters
    ----------
    geometry : Geometry
        Parallel-beam geometry.
    sinograms : array_like of shape (S, K, L) or (K, L)
        Line integrals.
    shifts : array_like of shape (K,), optional
        Per-view shifts ``d_k`` in detector pixels (:class:`GridrecPlan`).
    **params
        ``filter``, ``interpolation``, ``eps``, ``backend`` (:class:`GridrecParams`).

    Returns
    -------
    ndarray of shape (S, N, N) or (N, N), float32
    """
    return GridrecPlan(geometry, shifts, **params)(sinograms)


def gridrec(op: Geometry | RayTransform, sino: Any, *, shifts: Any = None, **params: Any) -> ReconResult:
    """Fourier (gridding) reconstruction of one parallel-beam slice: FBP computed with a non-uniform FFT.

    Parameters
    ----------
    op : Geometry or RayTransform
        Parallel-beam geometry (explicit view angles weighted by their share of the half circle,
        the axis offset applied as a phase ramp), or an unperturbed ray transform with
        ``oversample=1``.
    sino : array_like of shape (K, L)
        Sinogram of line integrals in pixel units; must be finite.
    shifts : array_like of shape (K,), optional
        Per-view object shift along the detector axis in image pixels, with the sign and units
        of :func:`~nanoct.recon.fbp.fbp`'s ``shifts`` (detector pixels times ``det_spacing``).
    **params
        The method's parameters: :class:`GridrecParams`.

    Returns
    -------
    ReconResult
        ``image`` is the (N, N) float32 reconstruction; ``stop_reason`` is ``"direct"``;
        ``params`` also records ``engine`` (the library and its version).
    """
    params = GridrecParams.check(op, **params)
    geometry = resolve_geometry(op)
    sino = check_array(sino, "sinogram", shape=geometry.sino_shape, dtype=np.float64)
    dshift = None
    if shifts is not None:
        shifts = check_array(shifts, "shifts", shape=(geometry.n_angles,), dtype=np.float64)
        dshift = shifts / geometry.det_spacing
    plan = cached_plan(geometry, dshift, **params)
    image = plan(sino)
    return ReconResult(image=image, params={"method": "gridrec", **params, "engine": backend_label(plan.backend)})
