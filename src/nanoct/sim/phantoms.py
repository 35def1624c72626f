"""Random phantoms of the paper's data set: a main shape with up to three sub-shapes.

A phantom is drawn in two steps, so that the same random draws describe the same continuous
object whatever resolution it is rasterised at:

1. :func:`random_phantom_spec` draws a :class:`PhantomSpec` (shapes in physical pixel units).
2. :func:`rasterize` evaluates it at the centres of ``oversample x oversample`` sub-pixels per
   image pixel; :func:`downsample` averages the sub-pixels back to image pixels.

Coordinates follow the package convention: for an (N, N) image ``x[row, col]`` the physical
position of a pixel centre is ``r1 = col - (N-1)/2`` (right) and ``r2 = (N-1)/2 - row`` (up),
and the image centre is the rotation axis.

The random phantom follows the paper (section "Data set generation"): background 0, one main
shape (rectangle or ellipse with probability 1/2 each, density uniform in [0.1, 1]) with random
size, centre and rotation, and 0 to 3 sub-shapes (rectangles or ellipses, density uniform in
[0, 1]) strictly inside the main shape, each replacing the value inside it. The main shape lies
inside the disc of radius ``0.9 (N-1)/2`` around the rotation axis, so it stays in the field of
view at every view angle and under small motion.

A second family, outside the paper's generator, serves as a shifted test set
(:func:`random_ellipse_phantom`, ``SimulationConfig(phantoms="ellipses")``): Shepp-Logan-like
heads, an elliptic body with a dense rim and 4-10 inner ellipses whose densities add (they
overlap, and may lower the density), clipped to [0, 1].
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from ..core.validation import check_int, check_rng

__all__ = [
    "Shape",
    "PhantomSpec",
    "random_phantom_spec",
    "pixel_centers",
    "rasterize",
    "downsample",
    "random_phantom",
    "random_ellipse_phantom",
    "family_phantom",
    "MIN_SIZE",
    "FOV_FRACTION",
    "PHANTOM_FAMILIES",
]

ShapeKind = Literal["ellipse", "rectangle"]

#: Smallest image side length ``n`` accepted.
MIN_SIZE = 16
#: The main shape lies inside the disc of radius ``FOV_FRACTION * (n-1)/2``.
FOV_FRACTION = 0.9

# Bounding radius of the main shape, as a fraction of the allowed disc radius.
_MAIN_EXTENT = (0.4, 0.95)
# Bounding radius of a sub-shape, as a fraction of the main shape's smaller half-axis.
_SUB_EXTENT = (0.15, 0.45)
# Ratio of the smaller to the larger half-axis of any shape.
_ASPECT = (0.3, 1.0)
# Main shape density range (the sub-shapes use [0, 1]).
_MAIN_DENSITY = (0.1, 1.0)
# Sub-shape centres are drawn from this fraction of the admissible region, so sub-shapes stay
# strictly inside the main shape.
_STRICT = 0.95
_MAX_SUBSHAPES = 3
#: Phantom families of :func:`family_phantom`: the paper's shapes and Shepp-Logan-like ellipses.
PHANTOM_FAMILIES = ("shapes", "ellipses")


@dataclass(frozen=True)
class Shape:
    """One filled ellipse or rectangle in physical pixel units.

    Parameters
    ----------
    kind : {"ellipse", "rectangle"}
        Shape type.
    center : tuple of float
        Centre ``(r1, r2)`` in pixels.
    half_axes : tuple of float
        Half-lengths ``(a, b)`` in pixels along the shape's own first and second axes.
    angle : float
        Rotation of the shape's first axis from the r1 axis, in degrees, counter-clockwise.
    density : float
        Value inside the shape, in [0, 1].
    """

    kind: ShapeKind
    center: tuple[float, float]
    half_axes: tuple[float, float]
    angle: float
    density: float

    def __post_init__(self) -> None:
        if self.kind not in ("ellipse", "rectangle"):
            raise ValueError(f"kind={self.kind!r} is not a shape; use 'ellipse' or 'rectangle'")
        if not all(h > 0 for h in self.half_axes):
            raise ValueError(f"half_axes={self.half_axes!r} must both be positive")
        if not 0.0 <= self.density <= 1.0:
            raise ValueError(f"density={self.density!r} must lie in [0, 1]")

    @property
    def bounding_radius(self) -> float:
        """Radius of the smallest disc around ``center`` that contains the shape (pixels)."""
        a, b = self.half_axes
        return max(a, b) if self.kind == "ellipse" else math.hypot(a, b)

    def contains(self, r1: np.ndarray, r2: np.ndarray) -> np.ndarray:
        """Whether points lie inside the closed shape.

        Parameters
        ----------
        r1, r2 : array_like
            Physical coordinates in pixels; broadcast against each other.

        Returns
        -------
        ndarray of bool
            Mask of the broadcast shape of ``r1`` and ``r2``.
        """
        theta = math.radians(self.angle)
        c, s = math.cos(theta), math.sin(theta)
        dx = np.asarray(r1) - self.center[0]
        dy = np.asarray(r2) - self.center[1]
        u = (c * dx + s * dy) / self.half_axes[0]
        v = (c * dy - s * dx) / self.half_axes[1]
        if self.kind == "ellipse":
            return u * u + v * v <= 1.0
        return (np.abs(u) <= 1.0) & (np.abs(v) <= 1.0)


@dataclass(frozen=True)
class PhantomSpec:
    """A continuous phantom: shapes painted in order on a zero background.

    Parameters
    ----------
    shapes : tuple of Shape
        ``shapes[0]`` is the main shape, the others its sub-shapes; each later shape replaces
        the value inside it.
    """

    shapes: tuple[Shape, ...]

    def __post_init__(self) -> None:
        if not self.shapes:
            raise ValueError("shapes is empty; a phantom needs at least its main shape")

    @property
    def main(self) -> Shape:
        """The main shape."""
        return self.shapes[0]

    @property
    def subshapes(self) -> tuple[Shape, ...]:
        """The sub-shapes inside the main shape (possibly none)."""
        return self.shapes[1:]


def _random_half_axes(rng: np.random.Generator, kind: ShapeKind, extent: float) -> tuple[float, float]:
    """Half-axes with random aspect ratio whose bounding radius equals ``extent``."""
    aspect = rng.uniform(*_ASPECT)
    a = extent if kind == "ellipse" else extent / math.hypot(1.0, aspect)
    return (float(a), float(aspect * a))


def _random_kind(rng: np.random.Generator) -> ShapeKind:
    return "rectangle" if rng.random() < 0.5 else "ellipse"


def _random_subshape(rng: np.random.Generator, main: Shape) -> Shape:
    """A shape whose bounding disc lies strictly inside ``main``."""
    big_a, big_b = main.half_axes
    kind = _random_kind(rng)
    extent = rng.uniform(*_SUB_EXTENT) * min(big_a, big_b)
    half_axes = _random_half_axes(rng, kind, extent)
    if main.kind == "rectangle":
        # Disc of radius `extent` at (u, v) is inside iff |u| + extent <= A and |v| + extent <= B.
        u = rng.uniform(-1.0, 1.0) * _STRICT * (big_a - extent)
        v = rng.uniform(-1.0, 1.0) * _STRICT * (big_b - extent)
    else:
        # In coordinates normalised by the half-axes the disc becomes an ellipse inside a disc of
        # radius extent / min(A, B); its centre must lie within 1 - that radius of the origin.
        radius = _STRICT * (1.0 - extent / min(big_a, big_b)) * math.sqrt(rng.random())
        alpha = rng.uniform(0.0, 2.0 * math.pi)
        u = big_a * radius * math.cos(alpha)
        v = big_b * radius * math.sin(alpha)
    theta = math.radians(main.angle)
    c, s = math.cos(theta), math.sin(theta)
    center = (main.center[0] + c * u - s * v, main.center[1] + s * u + c * v)
    return Shape(
        kind=kind,
        center=(float(center[0]), float(center[1])),
        half_axes=half_axes,
        angle=float(rng.uniform(0.0, 180.0)),
        density=float(rng.uniform(0.0, 1.0)),
    )


def _random_center(rng: np.random.Generator, radius: float) -> tuple[float, float]:
    """A point uniform in the disc of ``radius`` about the origin (where a shape's bounding disc
    stays inside the field of view)."""
    offset = radius * math.sqrt(rng.random())
    direction = rng.uniform(0.0, 2.0 * math.pi)
    return float(offset * math.cos(direction)), float(offset * math.sin(direction))


def random_phantom_spec(rng: np.random.Generator, n: int) -> PhantomSpec:
    """Draw a random phantom description for an ``n x n`` field of view.

    The draws are in physical pixel units and do not depend on any rasterisation resolution.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness, e.g. ``numpy.random.default_rng((seed, index))``.
    n : int
        Image side length in pixels, at least :data:`MIN_SIZE`.

    Returns
    -------
    PhantomSpec
        Main shape inside the disc of radius ``FOV_FRACTION * (n-1)/2`` and 0-3 sub-shapes
        strictly inside the main shape.
    """
    rng = check_rng(rng)
    n = check_int(n, "n", MIN_SIZE)
    fov_radius = FOV_FRACTION * (n - 1) / 2
    kind = _random_kind(rng)
    extent = rng.uniform(*_MAIN_EXTENT) * fov_radius
    half_axes = _random_half_axes(rng, kind, extent)
    main = Shape(
        kind=kind,
        center=_random_center(rng, fov_radius - extent),
        half_axes=half_axes,
        angle=float(rng.uniform(0.0, 180.0)),
        density=float(rng.uniform(*_MAIN_DENSITY)),
    )
    n_sub = int(rng.integers(0, _MAX_SUBSHAPES + 1))
    subshapes = tuple(_random_subshape(rng, main) for _ in range(n_sub))
    return PhantomSpec(shapes=(main, *subshapes))


def pixel_centers(n: int, oversample: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Physical coordinates of the sub-pixel centres of an ``n x n`` image.

    Parameters
    ----------
    n : int
        Image side length in (coarse) pixels.
    oversample : int, optional
        Sub-pixels per pixel along each axis.

    Returns
    -------
    r1 : ndarray of shape (1, n*oversample)
        Horizontal coordinate of each fine column.
    r2 : ndarray of shape (n*oversample, 1)
        Vertical coordinate of each fine row (decreasing with the row index).
    """
    n = check_int(n, "n", 1)
    oversample = check_int(oversample, "oversample", 1)
    fine = (np.arange(n * oversample) + 0.5) / oversample - n / 2
    return fine[np.newaxis, :], -fine[:, np.newaxis]


def rasterize(spec: PhantomSpec, n: int, oversample: int = 1) -> np.ndarray:
    """Sample a phantom at sub-pixel centres.

    Parameters
    ----------
    spec : PhantomSpec
        The phantom.
    n : int
        Image side length in pixels, at least :data:`MIN_SIZE`.
    oversample : int, optional
        Sub-pixels per pixel along each axis (fine pixel size ``1/oversample``); the field of
        view is the same for every value.

    Returns
    -------
    ndarray of shape (n*oversample, n*oversample), float32
        Point samples of the phantom; ``downsample(result, oversample)`` is the pixel image.
    """
    n = check_int(n, "n", MIN_SIZE)
    oversample = check_int(oversample, "oversample", 1)
    r1, r2 = pixel_centers(n, oversample)
    image = np.zeros((n * oversample, n * oversample), dtype=np.float32)
    for shape in spec.shapes:
        image[shape.contains(r1, r2)] = shape.density
    return image


def downsample(fine: np.ndarray, oversample: int) -> np.ndarray:
    """Average ``oversample x oversample`` blocks of a fine image.

    Parameters
    ----------
    fine : ndarray of shape (n*oversample, m*oversample)
        Fine image, e.g. from :func:`rasterize`.
    oversample : int
        Block size.

    Returns
    -------
    ndarray of shape (n, m), float32
        Block means.
    """
    oversample = check_int(oversample, "oversample", 1)
    fine = np.asarray(fine)
    if fine.ndim != 2 or fine.shape[0] % oversample or fine.shape[1] % oversample:
        raise ValueError(
            f"fine has shape {fine.shape}; it must be 2-D with both sides divisible by oversample={oversample}"
        )
    rows, cols = fine.shape[0] // oversample, fine.shape[1] // oversample
    blocks = fine.reshape(rows, oversample, cols, oversample)
    return blocks.mean(axis=(1, 3), dtype=np.float64).astype(np.float32)


def random_phantom(rng: np.random.Generator, n: int, *, oversample: int = 1) -> np.ndarray:
    """Draw a random phantom and rasterise it.

    Equivalent to ``rasterize(random_phantom_spec(rng, n), n, oversample)``, so the same
    generator state gives the same continuous phantom for every ``oversample``.

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness, e.g. ``numpy.random.default_rng((seed, index))``.
    n : int
        Image side length in pixels, at least :data:`MIN_SIZE`.
    oversample : int, optional
        Sub-pixels per pixel along each axis.

    Returns
    -------
    ndarray of shape (n*oversample, n*oversample), float32
        Values in [0, 1]; ``downsample(result, oversample)`` is the ground-truth phantom.
    """
    n = check_int(n, "n", MIN_SIZE)
    oversample = check_int(oversample, "oversample", 1)
    return rasterize(random_phantom_spec(rng, n), n, oversample)


def random_ellipse_phantom(rng: np.random.Generator, n: int, *, oversample: int = 1) -> np.ndarray:
    """Draw a Shepp-Logan-like phantom of additive ellipses and rasterise it.

    The body is an ellipse (larger half-axis ``U(0.6, 0.95)`` of the allowed disc radius
    ``FOV_FRACTION * (n-1)/2``, aspect ``U(0.6, 1)``, random centre and orientation, inside the
    disc) of density ``U(0.1, 0.35)`` with a rim of relative thickness ``U(0.04, 0.1)`` and density
    ``U(0.6, 1)``; inside the rim 4 to 10 ellipses (bounding radius ``U(0.15, 0.45)`` of the
    smaller inner half-axis, aspect ``U(0.3, 1)``, placed as the sub-shapes of
    :func:`random_phantom_spec`) each add ``U(-0.5, 1)`` times the body density. The sum is
    sampled at sub-pixel centres and clipped to [0, 1].

    Parameters
    ----------
    rng : numpy.random.Generator
        Source of randomness.
    n : int
        Image side length in pixels, at least :data:`MIN_SIZE`.
    oversample : int, optional
        Sub-pixels per pixel along each axis.

    Returns
    -------
    ndarray of shape (n*oversample, n*oversample), float32
        Values in [0, 1]; ``downsample(result, oversample)`` is the ground-truth phantom.
    """
    rng = check_rng(rng)
    n = check_int(n, "n", MIN_SIZE)
    oversample = check_int(oversample, "oversample", 1)
    fov_radius = FOV_FRACTION * (n - 1) / 2
    a = rng.uniform(0.6, 0.95) * fov_radius
    b = rng.uniform(0.6, 1.0) * a
    center = _random_center(rng, fov_radius - a)
    angle = rng.uniform(0.0, 180.0)
    body, rim = rng.uniform(0.1, 0.35), rng.uniform(0.6, 1.0)
    inner = 1.0 - rng.uniform(0.04, 0.1)
    inside = Shape("ellipse", center, (inner * a, inner * b), angle, 1.0)
    # (shape, added density): the rim ellipse, the body inside it, then the inner features
    parts = [(Shape("ellipse", center, (a, b), angle, 1.0), rim), (inside, body - rim)]
    for _ in range(int(rng.integers(4, 11))):
        place = _random_subshape(rng, inside)  # its bounding disc lies inside the rim
        half_axes = _random_half_axes(rng, "ellipse", place.bounding_radius)
        parts.append((Shape("ellipse", place.center, half_axes, place.angle, 1.0), rng.uniform(-0.5, 1.0) * body))
    r1, r2 = pixel_centers(n, oversample)
    image = np.zeros((n * oversample, n * oversample))
    for shape, density in parts:
        image += density * shape.contains(r1, r2)
    return np.clip(image, 0.0, 1.0).astype(np.float32)


def family_phantom(family: str, rng: np.random.Generator, n: int, *, oversample: int = 1) -> np.ndarray:
    """A random phantom of ``family`` (:data:`PHANTOM_FAMILIES`), fine grid as :func:`random_phantom`.

    Raises
    ------
    ValueError
        For an unknown family.
    """
    if family == "shapes":
        return random_phantom(rng, n, oversample=oversample)
    if family == "ellipses":
        return random_ellipse_phantom(rng, n, oversample=oversample)
    raise ValueError(f"phantom family {family!r} is unknown; use one of {', '.join(PHANTOM_FAMILIES)}")
