"""Fixtures for the preconvolve tests (issue #6).

Every test gets its own irradiance cache directory (ILLUM_CACHE_DIR), so cache hits and misses
are the test's own. usd_schemas is imported first so the illum schema plugin is registered
before any stage is opened.
"""

import usd_schemas  # noqa: F401  (isort: skip)

import numpy as np
import OpenImageIO as oiio
import pytest


@pytest.fixture(autouse=True)
def cache_dir(tmp_path, monkeypatch):
    d = tmp_path / "irradiance-cache"
    monkeypatch.setenv("ILLUM_CACHE_DIR", str(d))
    return d


def write_image(path, img, fmt=None) -> str:
    """Write img (H, W, C) as float32 (or fmt) to path; returns the path."""
    buf = oiio.ImageBuf(np.ascontiguousarray(img, dtype=np.float32))
    ok = buf.write(str(path), fmt) if fmt is not None else buf.write(str(path))
    assert ok, buf.geterror()
    return str(path)


def random_normals(n: int, seed: int = 0) -> np.ndarray:
    """(n + 6, 3) random unit vectors plus the six axes."""
    v = np.random.default_rng(seed).normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1)[:, None]
    return np.vstack([v, np.eye(3), -np.eye(3)])
