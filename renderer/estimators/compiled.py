"""The per-light direct-lighting estimators of this package, compiled: one function per
estimator over one (shading point, light) pair's samples, for the fast path's vertex kernel
(renderer/integrators/_vertex_kernels.py, which draws the samples and traces their shadow rays).

The numpy estimators (light_sampling.py, bsdf_sampling.py, mis.py, control_variates.py, ratio.py)
see each sample's visibility before they combine; the compiled path learns it only after the
kernel returns (embree runs between). So each function here turns the pair's samples into what
the estimate is *given* the visibilities v_i:

    Ld = Σ_i c_i v_i  +  D(F, X, v, covered)

c_i (3) the linear coefficient of sample i (its MIS, light- or BSDF-sampling term, already
divided by its pdf and N), and D the control variate's or ratio estimator's diffuse lobe
(kernels/direct.diffuse_combine_row, the formula the numpy estimators call too), given per
light sample X_i = f_i / p_i and whether the sample is covered (control_variates.covered_samples).
The functions return D's mode (kernels.direct.CV_* or RATIO), or NO_GROUP where the estimate is
linear (D = 0).

Sample records (SMP (N, NSMP) float64, one row per sample, the same columns for light and BSDF
samples): S_WI world direction, S_DIST distance to the light (inf for infinite lights), S_PL the
light pdf of the direction (inf for delta lights, as estimators.base.light_samples has it; for a
BSDF sample, 0 unless it reaches the light), S_PB the BSDF pdf, S_FD the control lobe g times
|cos| L, S_FS the residual f - g times |cos| L (estimators.base.split_integrand), S_TR 1.0 where
the general path traces the sample's shadow ray (a usable sample with some positive channel).
Outputs COEF (N, NC): C_C the coefficient c_i (3), C_X (3) X_i, C_COV 1.0 where covered.
"""

from __future__ import annotations

import math

from numba import njit

from renderer.bsdfs._preview_kernels import _mis_weight
from renderer.estimators import ALPHAS, TOKENS
from renderer.kernels import guard_cache, module_dispatchers
from renderer.kernels.direct import CV_ONE, RATIO

S_WI = 0
S_DIST = 3
S_PL = 4
S_PB = 5
S_FD = 6
S_FS = 9
S_TR = 12
NSMP = 13
C_C = 0
C_X = 3
C_COV = 6
NC = 7
NO_GROUP = -1

T_MIS = TOKENS.index("mis")
T_LIGHT = TOKENS.index("lightSampling")
T_BSDF = TOKENS.index("bsdfSampling")
T_CV = TOKENS.index("controlVariate")
T_RATIO = TOKENS.index("ratio")
# The control variate's α tokens are kernels.direct's CV modes, in the same order.
assert ALPHAS.index("one") == CV_ONE


@njit(cache=True, nogil=True)
def needs(tok):
    """(light samples, BSDF samples) the estimator ``tok`` draws (every control variate and ratio
    row takes BSDF samples too: the preview surface always has a residual lobe,
    control_variates.residual_rows)."""
    return tok != T_BSDF, tok != T_LIGHT


@njit(cache=True, nogil=True)
def _inv(p):
    """1 / p, 0 where p is 0 or not finite (sampling.safe_div)."""
    return 1.0 / p if (p > 0.0 and p < math.inf) else 0.0


@njit(cache=True, nogil=True)
def _put(out, i, smp, k, whole, x, cov):
    """out[i]: coefficient k times the sample's whole integrand (whole) or its residual alone,
    X = x and the covered flag."""
    for c in range(3):
        out[i, C_C + c] = k * ((smp[i, S_FD + c] if whole else 0.0) + smp[i, S_FS + c])
        out[i, C_X + c] = x * smp[i, S_FD + c]
    out[i, C_COV] = cov


@njit(cache=True, nogil=True)
def light_sampling(N, ls, bs, power, exact, alpha, cl, cb):
    """(1/N) Σ f_i v_i / p_i over light samples (delta lights: p = 1)."""
    for i in range(N):
        p = 1.0 if ls[i, S_PL] == math.inf else ls[i, S_PL]
        _put(cl, i, ls, _inv(p) / N, True, 0.0, 0.0)
    return NO_GROUP


@njit(cache=True, nogil=True)
def bsdf_sampling(N, ls, bs, power, exact, alpha, cl, cb):
    """(1/N) Σ f_i v_i / p_b,i over BSDF samples that reach the light."""
    for i in range(N):
        _put(cb, i, bs, _inv(bs[i, S_PB]) / N, True, 0.0, 0.0)
    return NO_GROUP


@njit(cache=True, nogil=True)
def _mis(N, ls, bs, power, whole, cl, cb):
    """MIS of the whole integrand (whole) or of its residual alone (estimators.mis.mis_parts),
    with the power (power) or balance heuristic."""
    for i in range(N):
        p = 1.0 if ls[i, S_PL] == math.inf else ls[i, S_PL]
        _put(cl, i, ls, _mis_weight(ls[i, S_PL], ls[i, S_PB], power) * _inv(p) / N, whole, 0.0, 0.0)
        _put(cb, i, bs, _mis_weight(bs[i, S_PB], bs[i, S_PL], power) * _inv(bs[i, S_PB]) / N, whole, 0.0, 0.0)


@njit(cache=True, nogil=True)
def mis(N, ls, bs, power, exact, alpha, cl, cb):
    """N light and N BSDF samples, balance or power heuristic (estimators/mis.py)."""
    _mis(N, ls, bs, power, True, cl, cb)
    return NO_GROUP


@njit(cache=True, nogil=True)
def _diffuse_on_light_samples(N, ls, cl):
    """X_i = f_i / p_i of the control lobe and the covered flags into cl (the residual's MIS
    coefficients already there are kept)."""
    for i in range(N):
        x = _inv(ls[i, S_PL])
        cov = ls[i, S_PL] > 0.0 and (ls[i, S_FD] > 0.0 or ls[i, S_FD + 1] > 0.0 or ls[i, S_FD + 2] > 0.0)
        for c in range(3):
            cl[i, C_X + c] = x * ls[i, S_FD + c]
        cl[i, C_COV] = 1.0 if cov else 0.0


@njit(cache=True, nogil=True)
def control_variate(N, ls, bs, power, exact, alpha, cl, cb):
    """The control variate with α = alpha (estimators/control_variates.py): the diffuse lobe
    on the analytic F, its residual by MIS; MIS over the whole BSDF where F is not exact."""
    _mis(N, ls, bs, power, not exact, cl, cb)
    if not exact:
        return NO_GROUP
    _diffuse_on_light_samples(N, ls, cl)
    return alpha if N >= 2 else CV_ONE


@njit(cache=True, nogil=True)
def ratio(N, ls, bs, power, exact, alpha, cl, cb):
    """The ratio estimator (estimators/ratio.py): F Σ X_i v_i / Σ X_i for the diffuse lobe, its
    residual by MIS; MIS over the whole BSDF where F is not exact."""
    _mis(N, ls, bs, power, not exact, cl, cb)
    if not exact:
        return NO_GROUP
    _diffuse_on_light_samples(N, ls, cl)
    return RATIO


@njit(cache=True, nogil=True, _nrt=False)
def estimate(tok, N, ls, bs, power, exact, alpha, cl, cb):
    """The estimator of token index ``tok`` (TOKENS) on the pair's N light samples ls and N BSDF
    samples bs (records as in the module docstring; the ones it does not need are ignored):
    fills cl, cb (N, NC) and returns the diffuse combination's mode or NO_GROUP. power: the MIS
    heuristic is the power one; exact: the light's F is exact here; alpha: the α token index."""
    if tok == T_LIGHT:
        return light_sampling(N, ls, bs, power, exact, alpha, cl, cb)
    if tok == T_BSDF:
        return bsdf_sampling(N, ls, bs, power, exact, alpha, cl, cb)
    if tok == T_CV:
        return control_variate(N, ls, bs, power, exact, alpha, cl, cb)
    if tok == T_RATIO:
        return ratio(N, ls, bs, power, exact, alpha, cl, cb)
    return mis(N, ls, bs, power, exact, alpha, cl, cb)


guard_cache(__name__, module_dispatchers(globals()),
            ["renderer/bsdfs/_preview_kernels.py", "renderer/kernels/direct.py", "renderer/kernels/vmath.py"])
