"""Tiled inference: a network applied to an image of any size in overlapping tiles, blended smoothly.

A network trained on T x T images is applied to an H x W slice in T x T tiles (the size it was
trained on, so every tile looks like a training image to it), ``overlap`` pixels apart at
interior tile edges; the last tile of a row or column is moved back to end at the image's edge.
Each tile's output is weighted by a separable window (:func:`edge_window`): 1 in its interior,
0 within ``margin`` pixels of an edge it shares with another tile (where the tile's own border
makes its output differ from the whole image's), and a raised-cosine ramp between; 1 up to the
image's own edges. The stitched mean is the weighted mean of the tiles' means, the stitched std
the square root of the weighted mean of their variances. Memory is one batch of tiles and three
float64 accumulators of the slice, whatever its size.

Where a network's output at a pixel depends only on the input within ``margin`` pixels (its
receptive field fits in the margin) and does not depend on the tile's position, the tiled
output equals the untiled one to rounding (tested with a convolutional network of known
receptive field); for the project's networks, whose receptive fields are larger than a tile,
the seams are measured in the tests and benchmarks/README.md.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

__all__ = ["DEFAULT_MARGIN", "DEFAULT_OVERLAP", "edge_window", "predict_tiled", "tile_starts"]

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


def predict_tiled(
    image: np.ndarray,
    network: TileFunction,
    tile: int,
    *,
    overlap: int = DEFAULT_OVERLAP,
    margin: int = DEFAULT_MARGIN,
    batch: int = 16,
    seed: int = 0,
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
        The first call gets ``seed``, the k-th ``seed * 1_000_003 + k`` (latent samples of sampling
        networks), so a prediction depends on nothing but the image, its seed and the tiling, and a
        single tile is the untiled prediction with that seed.
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
        mean, std = predict_tiled(padded, network, tile, overlap=overlap, margin=margin, batch=batch, seed=seed)
        return mean[:h0, :w0], None if std is None else std[:h0, :w0]
    ys, xs = tile_starts(h0, tile, overlap), tile_starts(w0, tile, overlap)
    win_y = {y: edge_window(tile, overlap, margin, y == 0, y + tile == h0) for y in ys}
    win_x = {x: edge_window(tile, overlap, margin, x == 0, x + tile == w0) for x in xs}
    acc_mean, acc_var, acc_w = (np.zeros((h0, w0)) for _ in range(3))
    has_std = True
    corners = [(y, x) for y in ys for x in xs]
    with tqdm(total=len(corners), desc=desc, unit="tile", disable=not progress) as bar:
        for k, start in enumerate(range(0, len(corners), batch)):
            part = corners[start : start + batch]
            tiles = np.stack([image[y : y + tile, x : x + tile] for y, x in part])
            mean, std = network(tiles, seed if k == 0 else seed * 1_000_003 + k)
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
