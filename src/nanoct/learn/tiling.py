"""Tiled inference: a network applied to an image of any size in overlapping tiles, blended smoothly.

A network trained on T x T images is applied to an H x W slice in T x T tiles (the size it was
trained on, so every tile looks like a training image to it), ``overlap`` pixels apart at
interior tile edges; the last tile of a row or column is moved back to end at the image's edge.
Each tile's output is weighted by a separable window (:func:`edge_window`): 1 in its interior,
0 within ``margin`` pixels of an edge it shares with another tile (where the tile's own border
makes its output differ from the whole image's), and a raised-cosine ramp between; 1 up to the
image's own edges. The stitched mean is the weighted mean of the tiles' means, the stitched std
the square root of the weighted mean of their variances. Memory is at most ``workers + 2`` batches of
tiles and three float64 accumulators of the slice, whatever its size.

With ``workers`` > 1 the network is called on several batches at once from a pool of threads
(the blending stays in the calling thread, in tile order, each batch with its own seed), so the
output is the same as with one worker, bit for bit. For a torch network on the CPU,
:func:`parallel_tiles` gives each worker one torch thread: independent single-threaded calls keep
both cores of a small machine busy without the synchronisation of torch's own threads, which on
a machine shared with other processes wait on each other (measured in benchmarks/README.md).
One torch thread instead of several changes the convolutions' summation order only: the outputs
differ by float32 rounding (tested to 1e-5).

Where a network's output at a pixel depends only on the input within ``margin`` pixels (its
receptive field fits in the margin) and does not depend on the tile's position, the tiled
output equals the untiled one to rounding (tested with a convolutional network of known
receptive field); for the project's networks, whose receptive fields are larger than a tile,
the seams are measured in the tests and benchmarks/README.md.
"""

from __future__ import annotations

import sys
from collections.abc import Callable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from contextlib import contextmanager
from typing import Any

import numpy as np

__all__ = [
    "DEFAULT_MARGIN",
    "DEFAULT_OVERLAP",
    "batch_seed",
    "edge_window",
    "parallel_tiles",
    "predict_tiled",
    "tile_starts",
]

#: Pixels shared by neighbouring tiles (at least 2 margins plus a ramp).
DEFAULT_OVERLAP = 16
#: Pixels at a shared tile edge whose output is not used (weight 0).
DEFAULT_MARGIN = 2

#: A network on a batch of tiles (B, T, T) with a seed: (mean, std or None), each (B, T, T).
TileFunction = Callable[[np.ndarray, int], tuple[np.ndarray, np.ndarray | None]]


def tile_starts(n: int, tile: int, overlap: int) -> list[int]:
    """Start offsets of tiles of length ``tile`` covering ``n`` pixels, ``tile - overlap`` apart.

    The last tile ends at ``n`` (it may overlap its neighbour by more than ``overlap``); one tile
    at 0 when ``n <= tile``.

    Raises
    ------
    ValueError
        If ``tile`` < 1 or ``overlap`` is not in [0, tile).
    """
    if tile < 1 or not 0 <= overlap < tile:
        raise ValueError(f"tile {tile} and overlap {overlap}: need tile >= 1 and 0 <= overlap < tile")
    if n <= tile:
        return [0]
    step = tile - overlap
    starts = list(range(0, n - tile, step))
    return starts + [n - tile]


def edge_window(tile: int, overlap: int, margin: int, first: bool, last: bool) -> np.ndarray:
    """1-D blending weights of a tile: 0 within ``margin`` of a shared edge, a raised-cosine ramp to 1 over
    the next ``overlap - 2 margin`` pixels, 1 elsewhere; an edge at the image's border (``first`` / ``last``)
    keeps weight 1.

    Raises
    ------
    ValueError
        If ``overlap - 2 margin`` < 1 (no pixel of the overlap would carry weight) or ``overlap``
        is more than half the tile.
    """
    ramp_len = overlap - 2 * margin
    if margin < 0 or ramp_len < 1 or 2 * overlap > tile:
        raise ValueError(
            f"overlap {overlap} and margin {margin} for tile {tile}: need margin >= 0, overlap >= 2 margin + 1 "
            "and overlap <= tile / 2"
        )
    ramp = np.sin(0.5 * np.pi * (np.arange(ramp_len) + 0.5) / ramp_len) ** 2
    rise = np.concatenate([np.zeros(margin), ramp])
    w = np.ones(tile)
    if not first:
        w[: rise.size] = rise
    if not last:
        w[tile - rise.size :] = np.minimum(w[tile - rise.size :], rise[::-1])
    return w


@contextmanager
def parallel_tiles(device: Any = "cpu") -> Iterator[int]:
    """The number of tile workers for a torch network on ``device``, with torch set to one thread meanwhile.

    On the CPU: yields torch's intra-op thread count ``n`` and sets it to 1 until the block ends (then
    restores ``n``), so :func:`predict_tiled` with ``workers=n`` runs ``n`` single-threaded network calls
    at once. Elsewhere (a GPU): yields 1 and changes nothing. The thread count changes a convolution's
    summation order, so outputs differ from those with torch's threads by float32 rounding (at most
    5e-7 for the tiny study's CiUNetRes on values of order 1; tested to 1e-5).
    """
    import torch

    if torch.device(device).type != "cpu":
        yield 1
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield threads
    finally:
        torch.set_num_threads(threads)


def _take_torch_threads() -> None:
    """In a new thread: take torch's intra-op thread count now (one under :func:`parallel_tiles`).

    torch applies its setting to a thread's OpenMP team size at the thread's first parallel loop;
    a convolution run before that would use OpenMP's default team of all cores.
    """
    if "torch" in sys.modules:
        sys.modules["torch"].get_num_threads()


def _in_order(call: Callable[[int], Any], n: int, workers: int) -> Iterator[Any]:
    """``call(0), ..., call(n - 1)`` in order, computed by ``workers`` threads, at most ``workers + 1`` ahead."""
    if workers <= 1:
        yield from (call(k) for k in range(n))
        return
    with ThreadPoolExecutor(workers, initializer=_take_torch_threads) as pool:
        pending: list[Future] = [pool.submit(call, k) for k in range(min(n, workers + 1))]
        try:
            for k in range(n):
                result = pending.pop(0).result()
                if k + len(pending) + 1 < n:
                    pending.append(pool.submit(call, k + len(pending) + 1))
                yield result
        finally:  # an error or an interruption: calls not yet started are dropped
            for future in pending:
                future.cancel()


def batch_seed(seed: int, k: int) -> int:
    """The seed of the k-th batch of tiles of an image seeded ``seed``: ``seed`` itself for the first (so one
    tile is the untiled prediction), else a 32-bit hash of ``(seed, k)`` by ``numpy.random.SeedSequence``, which
    meets the seed of another batch or image only by chance (not, as ``seed * c + k`` did, image ``seed``'s
    k-th batch meeting image k's first)."""
    return int(seed) if k == 0 else int(np.random.SeedSequence([int(seed), int(k)]).generate_state(1)[0])


def predict_tiled(
    image: np.ndarray,
    network: TileFunction,
    tile: int,
    *,
    overlap: int = DEFAULT_OVERLAP,
    margin: int = DEFAULT_MARGIN,
    batch: int = 16,
    seed: int = 0,
    workers: int = 1,
    progress: bool = False,
    desc: str = "tiles",
) -> tuple[np.ndarray, np.ndarray | None]:
    """Apply ``network`` to an (H, W) image in overlapping ``tile`` x ``tile`` tiles and blend the outputs.

    Parameters
    ----------
    image : array (H, W)
        Input (a first reconstruction). An image not larger than ``tile`` in either direction is
        padded with its edge values to ``tile`` and cropped back.
    network : callable
        ``network(tiles (B, tile, tile) float32, seed) -> (mean, std or None)``, each (B, tile, tile).
    tile, overlap, margin
        Tile size, pixels shared by neighbouring tiles, unused pixels at a shared edge
        (:func:`edge_window`).
    batch : int
        Tiles per call of ``network``.
    seed : int
        The first call gets ``seed``, the k-th a seed drawn from ``numpy.random.SeedSequence([seed, k])``
        (:func:`batch_seed`; latent samples of sampling networks), so a prediction depends on nothing but
        the image, its seed, the tiling and ``batch`` (a tile's draws depend on the batch it is in), and a
        single tile is the untiled prediction with that seed.
    workers : int
        Calls of ``network`` running at once, each on its own batch, from as many threads (``network``
        must then be safe to call from several threads, as a torch module in evaluation is); the
        output does not depend on it. For a torch network see :func:`parallel_tiles`.
    progress, desc
        A progress bar over the tiles.

    Returns
    -------
    (mean, std) : float32 arrays (H, W); std None for a network without one.
    """
    from tqdm.auto import tqdm

    image = np.asarray(image, np.float32)
    h0, w0 = image.shape
    if min(h0, w0) < tile:
        padded = np.pad(image, ((0, max(tile - h0, 0)), (0, max(tile - w0, 0))), mode="edge")
        mean, std = predict_tiled(
            padded,
            network,
            tile,
            overlap=overlap,
            margin=margin,
            batch=batch,
            seed=seed,
            workers=workers,
            progress=progress,
            desc=desc,
        )
        return mean[:h0, :w0], None if std is None else std[:h0, :w0]
    ys, xs = tile_starts(h0, tile, overlap), tile_starts(w0, tile, overlap)
    win_y = {y: edge_window(tile, overlap, margin, y == 0, y + tile == h0) for y in ys}
    win_x = {x: edge_window(tile, overlap, margin, x == 0, x + tile == w0) for x in xs}
    acc_mean, acc_var, acc_w = (np.zeros((h0, w0)) for _ in range(3))
    has_std = True
    corners = [(y, x) for y in ys for x in xs]
    parts = [corners[start : start + batch] for start in range(0, len(corners), batch)]

    def call(k: int) -> tuple[np.ndarray, np.ndarray | None]:
        tiles = np.stack([image[y : y + tile, x : x + tile] for y, x in parts[k]])
        return network(tiles, batch_seed(seed, k))

    with tqdm(total=len(corners), desc=desc, unit="tile", disable=not progress) as bar:
        for part, (mean, std) in zip(parts, _in_order(call, len(parts), workers)):
            has_std = has_std and std is not None
            for j, (y, x) in enumerate(part):
                w = np.outer(win_y[y], win_x[x])
                acc_w[y : y + tile, x : x + tile] += w
                acc_mean[y : y + tile, x : x + tile] += w * mean[j]
                if std is not None:
                    acc_var[y : y + tile, x : x + tile] += w * np.square(std[j], dtype=np.float64)
            bar.update(len(part))
    out_std = np.sqrt(acc_var / acc_w).astype(np.float32) if has_std else None
    return (acc_mean / acc_w).astype(np.float32), out_std
