"""Direct-lighting estimators, keyed by the IllumLightAPI `illum:estimator` token."""

from __future__ import annotations

from .base import DirectQuery, DirectRandom, DirectResult
from .bsdf_sampling import BSDFSamplingEstimator
from .control_variates import ControlVariateEstimator
from .light_sampling import LightSamplingEstimator
from .mis import MISEstimator
from .ratio import RatioEstimator

REGISTRY = {
    e.token: e()
    for e in (LightSamplingEstimator, BSDFSamplingEstimator, MISEstimator, ControlVariateEstimator, RatioEstimator)
}
TOKENS = ("mis", "lightSampling", "bsdfSampling", "controlVariate", "ratio", "auto")
ALPHAS = ("one", "averageVisibility", "averageVisibilityUnbiased")
HEURISTICS = ("power", "balance")

__all__ = ["REGISTRY", "TOKENS", "ALPHAS", "HEURISTICS", "DirectQuery", "DirectRandom", "DirectResult"]
