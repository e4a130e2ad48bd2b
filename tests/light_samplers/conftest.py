"""Fixtures for the lighting-service tests: LightSets mixing every kind, and shading points."""

from __future__ import annotations

import math

import numpy as np
import pytest

from renderer.description import LightDesc
from renderer.lights.base import ShadingContext
from renderer.lights.light_set import LightSet


def frame_to(direction) -> np.ndarray:
    """(4, 4) rotation taking local -Z (the emitting side of rect and disk lights) to direction."""
    d = np.asarray(direction, dtype=np.float64)
    z = -d / np.linalg.norm(d)
    helper = np.array([0.0, 1.0, 0.0]) if abs(z[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    m = np.eye(4)
    m[:3, 0], m[:3, 1], m[:3, 2] = x, y, z
    return m


def placed(position, direction=(0.0, -1.0, 0.0)) -> np.ndarray:
    m = frame_to(direction)
    m[:3, 3] = position
    return m


def mixed_descs(n_finite: int, seed: int = 3, infinite: bool = True, extent: float = 6.0) -> list[LightDesc]:
    """n_finite rect / disk / sphere / point lights at random places, orientations and
    intensities, plus (optionally) a distant light and a constant dome."""
    rng = np.random.default_rng(seed)
    descs = []
    for i in range(n_finite):
        kind = ("rect", "disk", "sphere", "point")[i % 4]
        pos = rng.uniform(-extent, extent, 3)
        d = rng.normal(size=3)
        m = placed(pos, d)
        inten = float(rng.uniform(0.5, 20.0))
        col = tuple(float(c) for c in rng.uniform(0.2, 1.0, 3))
        common = dict(intensity=inten, color=col)
        if kind == "rect":
            size = dict(width=float(rng.uniform(0.1, 1.5)), height=float(rng.uniform(0.1, 1.5)))
            descs.append(LightDesc(f"/L/R{i}", "rect", m, **common, **size))
        elif kind == "disk":
            descs.append(LightDesc(f"/L/D{i}", "disk", m, **common, radius=float(rng.uniform(0.05, 0.6))))
        elif kind == "sphere":
            descs.append(LightDesc(f"/L/S{i}", "sphere", m, **common, radius=float(rng.uniform(0.02, 0.4))))
        else:
            descs.append(LightDesc(f"/L/P{i}", "sphere", m, **common, radius=0.05, treat_as_point=True))
    if infinite:
        descs.append(LightDesc("/L/Sun", "distant", frame_to((0.3, -1.0, 0.2)), intensity=3.0, angle=0.53))
        descs.append(LightDesc("/L/Sky", "dome", np.eye(4), intensity=0.2))
    return descs


def light_set(descs) -> LightSet:
    return LightSet.build(descs, scene_center=(0.0, 0.0, 0.0), scene_radius=12.0)


@pytest.fixture(scope="package")
def mixed():
    """60 finite lights of every kind plus a distant and a dome light."""
    return light_set(mixed_descs(60))


@pytest.fixture(scope="package")
def finite_only():
    return light_set(mixed_descs(40, seed=11, infinite=False))


def random_context(n: int, seed: int = 0, extent: float = 7.0, with_normals: bool = True) -> ShadingContext:
    """n random points in the scene box with random unit normals (zeros when not with_normals)."""
    rng = np.random.default_rng(seed)
    p = rng.uniform(-extent, extent, (n, 3))
    if with_normals:
        nrm = rng.normal(size=(n, 3))
        nrm /= np.linalg.norm(nrm, axis=1)[:, None]
    else:
        nrm = np.zeros((n, 3))
    return ShadingContext(p, nrm, nrm.copy())


def repeat_context(ctx: ShadingContext, i: int, k: int) -> ShadingContext:
    """Row i of ctx repeated k times."""
    rows = np.full(k, i)
    return ctx.take(rows)


__all__ = ["frame_to", "placed", "mixed_descs", "light_set", "random_context", "repeat_context", "math"]
