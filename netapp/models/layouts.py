"""The anchor grids of the YOLO exports: how many anchor points an input size has, and where they sit. Pure."""

from __future__ import annotations

import numpy as np

STRIDES = (8, 16, 32)


def grid_points(input_hw: tuple[int, int], strides: tuple[int, ...] = STRIDES) -> tuple[np.ndarray, np.ndarray]:
    """(x, y) grid offsets and the stride of every anchor point, in YOLOX order (stride by stride, row-major)."""
    grids, expanded = [], []
    for s in strides:
        gh, gw = input_hw[0] // s, input_hw[1] // s
        ys, xs = np.meshgrid(np.arange(gh), np.arange(gw), indexing="ij")
        grids.append(np.stack((xs, ys), axis=-1).reshape(-1, 2))
        expanded.append(np.full((gh * gw, 1), s))
    return np.concatenate(grids).astype(np.float32), np.concatenate(expanded).astype(np.float32)


def anchor_count(input_hw: tuple[int, int], strides: tuple[int, ...] = STRIDES) -> int:
    return sum((input_hw[0] // s) * (input_hw[1] // s) for s in strides)
