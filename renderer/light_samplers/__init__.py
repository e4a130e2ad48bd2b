"""Lighting services (light samplers), chosen by name.

``make_light_sampler(name, lights)`` builds one over a LightSet. With name '' or 'auto' the
choice follows the light count (finite and infinite lights together):

* up to EXHAUSTIVE_MAX_LIGHTS (8) lights: ``exhaustive``, every light at every vertex; a few
  more shadow rays cost less than the variance of picking;
* above that: ``bvh``, the light BVH. Its importance (power, distance, orientation, horizon)
  beats power-proportional picking as soon as the lights are spread out in space, which is
  why a scene has many of them. Measured (bench/results/light_samplers/results.md: the
  stages' own 480x270, 30 CPU seconds per render, median of 3 seeds, relMSE over the whole
  image): 5.75x lower than uniform and 3.91x lower than power on stages/fireflies (5000
  sphere lights; 23x and 15x over the pixels that see no light directly), 8.6x and 2.0x on
  stages/city_lights (293 rect and disk lights), although a pick costs ~0.5 us (a descent of
  ~13 levels) against ~0.02 us for the power sampler's alias table. (At 160x90 the
  whole-image margins on fireflies are only 2.7x and 2.0x: there the anti-aliasing noise of
  the fireflies seen directly, which no lighting service touches, is most of the error; see
  that file's README.) Just above the threshold
  it still wins: with 9 / 16 / 32 mixed lights at random points the relative variance of the
  pick (unshadowed) was 1.8 / 2.3 / 4.3 for bvh, 5.5 / 8.7 / 13 for uniform and 34 / 17 / 18
  for power (measured before the distance clamp became r^2/3; at the stages' first hits that
  change moved bvh's pick variance from 9.6 to 2.4 on fireflies and from 3.5 to 3.8 on
  city_lights, ``bench_light_samplers.py pick``). The build is ~0.06 s for 5000 lights,
  ~1 s for 100k.

``pick_tables(sampler, lights)`` hands a sampler's tables to the compiled per-row service
(renderer/kernels/light_pick.py) that the fast path's vertex kernel runs: the same picks and
pmfs, one row at a time.
"""

from __future__ import annotations

import numpy as np

from ..errors import SettingsError
from .bvh import BVHLightSampler, light_bounds
from .exhaustive import ExhaustiveLightSampler
from .power import PowerLightSampler
from .uniform import UniformLightSampler

SAMPLERS = {
    "exhaustive": ExhaustiveLightSampler,
    "uniform": UniformLightSampler,
    "power": PowerLightSampler,
    "bvh": BVHLightSampler,
}

# Up to this many lights, every light is estimated at every vertex (each with its own
# estimator and N): the variance of picking is worse than the cost of a few more shadow rays.
EXHAUSTIVE_MAX_LIGHTS = 8

__all__ = [
    "SAMPLERS",
    "EXHAUSTIVE_MAX_LIGHTS",
    "make_light_sampler",
    "default_sampler_name",
    "pick_tables",
    "BVHLightSampler",
    "ExhaustiveLightSampler",
    "PowerLightSampler",
    "UniformLightSampler",
]


def default_sampler_name(light_count: int) -> str:
    """The 'auto' choice for a scene with light_count lights (see the module docstring)."""
    return "exhaustive" if light_count <= EXHAUSTIVE_MAX_LIGHTS else "bvh"


def make_light_sampler(name: str, lights):
    """Build the named sampler over a LightSet (or None for a scene without lights).

    The BVH sampler reads the lights' geometry; the others only their powers ``lights.phi()``.
    'auto' / '' choose by light count (default_sampler_name).
    """
    count = 0 if lights is None else int(lights.count)
    if name in ("", "auto"):
        name = default_sampler_name(count)
    if name not in SAMPLERS:
        raise SettingsError(f"unknown light sampler {name!r}; choose from {sorted(SAMPLERS)}",
                            attribute="light_sampler")
    if name == "bvh":
        return BVHLightSampler(lights)
    phi = lights.phi() if count else np.zeros(0)
    return SAMPLERS[name](phi)


def pick_tables(sampler, lights) -> tuple:
    """The sampler's tables as the one record the compiled per-row service takes
    (renderer/kernels/light_pick.py, which lists its fields). The light BVH's traversal tables
    are filled for the picking services: the bvh service's own tree, and for uniform and power a
    tree built over the same lights (~0.06 s for 5000) that only finds the lights a ray crosses
    (light_pick.crossed_row). The exhaustive service gets empty ones (its integrator visits
    every light)."""
    from ..kernels.light_pick import MODES

    count = int(lights.count)
    f64, i64 = np.float64, np.int64
    mode = MODES[sampler.name]
    cand = np.zeros(0, i64)
    pmf = np.zeros(count)
    alias_q, alias_i = np.zeros(0), np.zeros(0, i64)
    if sampler.name == "uniform":
        cand = np.ascontiguousarray(sampler.candidates, dtype=i64)
        pmf = np.ascontiguousarray(sampler._pmf, dtype=f64)
    elif sampler.name == "power" and sampler.table is not None and not sampler.empty:
        pmf = np.ascontiguousarray(sampler.table.pmf, dtype=f64)
        alias_q = np.ascontiguousarray(sampler.table.q, dtype=f64)
        alias_i = np.ascontiguousarray(sampler.table.alias, dtype=i64)
    if sampler.name == "exhaustive":
        # No tree (a scene of a few lights builds none): empty tables of the same types.
        f32, i32 = np.float32, np.int32
        return (mode, cand, pmf, alias_q, alias_i, 0.0, np.zeros(0, i64), np.zeros(count, bool),
                np.full(count, -1, i32), np.zeros(0, i32), np.zeros((0, 1), np.uint64), np.zeros((0, 2), i32), -1,
                np.zeros((1, 1, 3)), np.zeros((1, 1, 8), f32), np.zeros((0, 2, 3)), np.zeros((0, 2, 8), f32),
                np.zeros((0, 2, 6)))
    tree = sampler if sampler.name == "bvh" else BVHLightSampler(lights)
    return (mode, cand, pmf, alias_q, alias_i, float(tree.p_infinite), np.ascontiguousarray(tree.infinite, dtype=i64),
            np.ascontiguousarray(tree._is_inf), tree.slot, tree.depth, np.ascontiguousarray(tree.trail),
            tree.pair_next, int(tree.root_light), tree.root_c, tree.root_b, tree.pair_c, tree.pair_b,
            node_boxes(tree, lights))


def node_boxes(tree, lights) -> np.ndarray:
    """(P, 2, 6) float64 AABBs (lo, hi) of the nodes of a BVHLightSampler's sibling pairs, for
    finding the lights a ray crosses (renderer/kernels/light_bvh.py bvh_crossed_row): its
    lights' bounds (bvh.light_bounds) unioned bottom-up, each padded outward by 1e-9 of its
    extent and scale so rounding in the slab test never drops a light the ray crosses."""
    from ..kernels.light_bvh import node_boxes_kernel

    P = tree.pair_next.shape[0]
    out = np.zeros((P, 2, 6))
    if P == 0:
        return out
    b = light_bounds(lights)
    lo = np.zeros((int(lights.count), 3))
    hi = np.zeros((int(lights.count), 3))
    lo[b.light], hi[b.light] = b.lo, b.hi
    node_boxes_kernel(tree.pair_next, lo, hi, out)
    pad = 1e-9 * (np.abs(out[..., 0:3]) + np.abs(out[..., 3:6]) + (out[..., 3:6] - out[..., 0:3])) + 1e-12
    out[..., 0:3] -= pad
    out[..., 3:6] += pad
    return out
