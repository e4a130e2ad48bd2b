"""Hypothesis strategies for the stress suite (the same fields that cases.random_case draws)."""

from __future__ import annotations

import math

from hypothesis import strategies as st

from .cases import KINDS, NORMALS, PLACEMENTS, LightCase

unit_float = st.floats(min_value=0.0, max_value=1.0, exclude_max=True, allow_nan=False)
signed = st.floats(min_value=-1.0, max_value=1.0, allow_nan=False)


def log_uniform(lo_exp: float, hi_exp: float):
    """10**x for x uniform in [lo_exp, hi_exp]."""
    return st.floats(min_value=lo_exp, max_value=hi_exp, allow_nan=False).map(lambda x: 10.0 ** x)


def nonzero_vector(k: int):
    return st.tuples(*([signed] * k)).filter(lambda v: math.fsum(x * x for x in v) > 1e-2)


@st.composite
def light_cases(draw, kinds=KINDS, placements=PLACEMENTS, normals=NORMALS,
                size_exp=(-6.0, 6.0), dist_exp=(-4.0, 7.0), offset_exp=(-3.0, 3.0)) -> LightCase:
    """A light of size 1e-6..1e6 and a shading point at distance 1e-4..1e7 (by default)."""
    offset_dir = draw(nonzero_vector(3))
    offset_mag = draw(log_uniform(*offset_exp))
    norm = math.sqrt(sum(x * x for x in offset_dir))
    return LightCase(
        kind=draw(st.sampled_from(kinds)),
        size=draw(log_uniform(*size_exp)),
        aspect=draw(log_uniform(-1.0, 1.0)),
        quat=draw(nonzero_vector(4)),
        offset=tuple(offset_mag * x / norm for x in offset_dir),
        placement=draw(st.sampled_from(placements)),
        dist=draw(log_uniform(*dist_exp)),
        where=draw(st.tuples(unit_float, unit_float, unit_float)),
        direction=draw(nonzero_vector(3)),
        normal=draw(st.sampled_from(normals)),
        tilt=draw(signed),
        nrm=draw(nonzero_vector(3)),
    )
