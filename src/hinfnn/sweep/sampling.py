"""Grid points and seeded random draws of a sweep.

Every random value is a function of (seed, key, sample index) alone: draw ``i`` of key ``K`` is
value ``i % 1024`` of the stream of ``numpy.random.default_rng([seed, crc32(K), i // 1024])``,
turned into a number in (0, 1) and mapped through the distribution's inverse CDF. So a sweep
resumed, re-run with more samples, or extended with another varied key draws the same values
for the samples and keys it had, and the same draws are used at every grid point (common random
numbers: two grid points differ only in their grid values).
"""

from __future__ import annotations

import dataclasses
import itertools
import math
import zlib

import numpy as np

#: Draws per generator block (draw i uses block i // BLOCK).
BLOCK = 1024
_SCALE = 2.0**53


def uniforms(seed: int, key: str, indices) -> np.ndarray:
    """Numbers in the open interval (0, 1), one per sample index, from (seed, key, index) only."""
    indices = np.asarray(indices, dtype=np.int64)
    out = np.empty(indices.shape, dtype=float)
    key_id = zlib.crc32(key.encode("utf-8"))
    blocks = indices // BLOCK
    for b in np.unique(blocks):
        rng = np.random.default_rng([int(seed), key_id, int(b)])
        k = rng.integers(0, 2**53, size=BLOCK, dtype=np.int64)
        u = (k.astype(float) + 0.5) / _SCALE  # never 0 or 1: inverse CDFs stay finite
        mask = blocks == b
        out[mask] = u[indices[mask] % BLOCK]
    return out


def transform(how, base, u: np.ndarray) -> np.ndarray:
    """Values of the distribution ``how`` (a :class:`~hinfnn.sweep.spec.VarySpec`) at the
    quantiles ``u``; ``base`` is the key's value in the base scenario (``relative``, ``normal``
    without a mean). For a list-valued base, ``relative`` returns one row per draw."""
    d = how.distribution
    if d == "uniform":
        return how.low + (how.high - how.low) * u
    if d == "log-uniform":
        lo, hi = math.log(how.low), math.log(how.high)
        return np.exp(lo + (hi - lo) * u)
    if d == "relative":
        factor = 1.0 + (how.percent / 100.0) * (2.0 * u - 1.0)
        if isinstance(base, (tuple, list)):
            return factor[:, None] * np.asarray(base, dtype=float)[None, :]
        return base * factor
    if d == "normal":
        from scipy.special import ndtr, ndtri

        mean = how.mean if how.mean is not None else float(base)
        a = ndtr((how.low - mean) / how.std) if how.low is not None else 0.0
        b = ndtr((how.high - mean) / how.std) if how.high is not None else 1.0
        x = mean + how.std * ndtri(a + (b - a) * u)
        lo = how.low if how.low is not None else -np.inf
        hi = how.high if how.high is not None else np.inf
        return np.clip(x, lo, hi)  # rounding in far tails
    raise ValueError(f"not a distribution: {d!r}")


def draw_values(spec, samples) -> dict[str, list]:
    """{key: [value of sample i for i in samples]} for every drawn key of ``spec``."""
    samples = np.asarray(list(samples), dtype=np.int64)
    out = {}
    for v in spec.varied:
        if v.how.is_grid:
            continue
        values = transform(v.how, v.base, uniforms(spec.seed, v.key, samples))
        if v.list_valued:
            values = [list(map(float, row)) if np.ndim(row) else [float(row)] * len(v.base) for row in values]
        else:
            values = [float(x) for x in values]
        out[v.key] = values
    return out


def grid_points(spec) -> list[dict]:
    """The grid points in order (the first grid key varies slowest), each {key: value}; one
    empty point without a grid."""
    keys = [v for v in spec.varied if v.how.is_grid]
    grids = [v.how.grid() for v in keys]
    points = []
    for combo in itertools.product(*grids):
        point = {}
        for v, value in zip(keys, combo):
            if v.list_valued:
                value = [float(value)] * len(v.base)
            elif isinstance(v.base, int) and not isinstance(v.base, bool) and isinstance(value, float) \
                    and value.is_integer():
                value = int(value)
            point[v.key] = value
        points.append(point)
    return points


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """One run of a sweep: its index in the table, grid point, sample, controller and the
    scenario values it sets (every varied key, in the spec's order)."""

    run: int
    point: int
    sample: int
    controller: str
    values: dict


def runs(spec) -> list[RunSpec]:
    """Every run of the sweep, in table order: grid point (slowest), sample, controller.
    ``run`` = (point · samples + sample) · controllers + controller index."""
    points = grid_points(spec)
    drawn = draw_values(spec, range(spec.samples))
    order = [v.key for v in spec.varied]
    out = []
    n_c = len(spec.controllers)
    for p, point in enumerate(points):
        for s in range(spec.samples):
            values = {**point, **{k: vals[s] for k, vals in drawn.items()}}
            values = {k: values[k] for k in order}
            for c, kind in enumerate(spec.controllers):
                out.append(RunSpec(run=(p * spec.samples + s) * n_c + c, point=p, sample=s, controller=kind,
                                   values=values))
    return out


__all__ = ["uniforms", "transform", "draw_values", "grid_points", "runs", "RunSpec", "BLOCK"]
