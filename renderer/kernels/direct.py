"""numba kernels of the direct-lighting estimators' shared sampling stage (estimators/base.py).

Conventions as in renderer/kernels/__init__.py: cached, GIL released, IEEE semantics, one loop
over rows, no functions imported from other modules.
"""

from __future__ import annotations

from numba import njit


@njit(cache=True, nogil=True)
def split_kernel(f_all, f_d, control, wo_z, wi_z, sd, ss, weight, out_g, out_res):
    """estimators.base.split_integrand's arithmetic, row by row (m rows, (m, 3) colours):

        up = wi_z > 0 and wo_z > 0;  g = control * up
        out_g = g * sd * weight;  out_res = ((f_d - g) * sd + (f_all - f_d) * ss) * weight

    sd, ss: (m,) the light's diffuse / specular multipliers of each row.
    """
    for r in range(f_all.shape[0]):
        up = wi_z[r] > 0.0 and wo_z[r] > 0.0
        for k in range(3):
            g = control[r, k] if up else 0.0
            w = weight[r, k]
            out_g[r, k] = g * sd[r] * w
            out_res[r, k] = ((f_d[r, k] - g) * sd[r] + (f_all[r, k] - f_d[r, k]) * ss[r]) * w


@njit(cache=True, nogil=True)
def shadowed_row(v, c):
    """UsdLux ShadowAPI shadow:color: what one channel of shadow colour c sees of a sample of
    visibility v in [0, 1], the shadowed fraction 1 - v showing c: v + (1 - v) c. The one formula
    of both routes (tint_rows_kernel for the general path's estimators, the fast path's
    _vertex_kernels.add_visible_kernel)."""
    return v + (1.0 - v) * c


@njit(cache=True, nogil=True)
def tint_rows_kernel(k, v, c, fd, fs):
    """estimators.base.tint_shadows' arithmetic: for the rows k (m,) with shadow colours c
    (m, 3), fd[k] and fs[k] ((rows, 3)) *= shadowed_row(v[k], c) per channel, then v[k] = 1."""
    for i in range(k.shape[0]):
        r = k[i]
        for ch in range(3):
            t = shadowed_row(v[r], c[i, ch])
            fd[r, ch] *= t
            fs[r, ch] *= t
        v[r] = 1.0


# The diffuse-lobe combinations of the control variate and the ratio estimator, one per
# estimator mode: the control variate's α in ALPHAS order (estimators/__init__.py), then ratio.
CV_ONE = 0
CV_AVERAGE = 1
CV_UNBIASED = 2
RATIO = 3


@njit(cache=True, nogil=True)
def diffuse_combine_row(F0, F1, F2, X, v, cov, lo, hi, N, mode):
    """The control-variate (modes CV_*) or ratio (RATIO) estimate of one row's diffuse lobe,
    ∫ g L v cos⁺ dω, as a 3-tuple: the formulas of estimators/control_variates.cv_diffuse and
    estimators/ratio (their docstrings), written once for the numpy estimators and the compiled
    path.

    F0..F2: F (the exact unshadowed integral); samples lo..hi of X (m, 3) = f_i / p_i, v (m,)
    visibility in [0, 1] and cov (m,) 1.0 where the sample is covered (covered_samples), else
    0.0; N the row's light-sample count. Samples not in lo..hi count as uncovered with X = 0
    (the compiled path lists only the samples it traced), so N may exceed hi - lo; uncovered
    samples must have X = 0 there, as they do wherever F integrates nothing. CV modes with N < 2
    use α = 1."""
    if mode == RATIO:
        n0 = 0.0
        n1 = 0.0
        n2 = 0.0
        d0 = 0.0
        d1 = 0.0
        d2 = 0.0
        for i in range(lo, hi):
            n0 += X[i, 0] * v[i]
            n1 += X[i, 1] * v[i]
            n2 += X[i, 2] * v[i]
            d0 += X[i, 0]
            d1 += X[i, 1]
            d2 += X[i, 2]
        # No sample where F integrates: taken as visible (estimators/ratio.py).
        return (F0 * (n0 / d0 if d0 > 0.0 else 1.0), F1 * (n1 / d1 if d1 > 0.0 else 1.0),
                F2 * (n2 / d2 if d2 > 0.0 else 1.0))
    if mode == CV_ONE or N < 2:
        s0 = 0.0
        s1 = 0.0
        s2 = 0.0
        for i in range(lo, hi):
            s0 += X[i, 0] * (v[i] - 1.0)
            s1 += X[i, 1] * (v[i] - 1.0)
            s2 += X[i, 2] * (v[i] - 1.0)
        return F0 + s0 / N, F1 + s1 / N, F2 + s2 / N
    M = 0.0
    S = 0.0
    for i in range(lo, hi):
        M += cov[i]
        S += cov[i] * v[i]
    # α of an uncovered sample: the mean visibility of the covered ones (1 where there is none).
    a_nc = S / M if M > 0.0 else 1.0
    a_sum = (N - M) * a_nc
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    for i in range(lo, hi):
        if mode == CV_AVERAGE:
            a = a_nc
        elif cov[i] > 0.0:
            # Leave-one-out: the other covered samples' mean visibility.
            m_i = M - cov[i]
            a = (S - cov[i] * v[i]) / m_i if m_i > 0.0 else 1.0
            a_sum += a
        else:
            a = a_nc
        s0 += X[i, 0] * (v[i] - a)
        s1 += X[i, 1] * (v[i] - a)
        s2 += X[i, 2] * (v[i] - a)
    alpha = a_nc if mode == CV_AVERAGE else a_sum / N
    return alpha * F0 + s0 / N, alpha * F1 + s1 / N, alpha * F2 + s2 / N


@njit(cache=True, nogil=True)
def diffuse_combine_kernel(F, X, v, cov, mode, out):
    """diffuse_combine_row for n rows of N samples each: F (n, 3), X (n * N, 3), v and cov
    (n * N,) with row r's samples at r N .. r N + N; out (n, 3)."""
    n = F.shape[0]
    N = v.shape[0] // n if n > 0 else 1
    for r in range(n):
        e = diffuse_combine_row(F[r, 0], F[r, 1], F[r, 2], X, v, cov, r * N, r * N + N, N, mode)
        out[r, 0] = e[0]
        out[r, 1] = e[1]
        out[r, 2] = e[2]
