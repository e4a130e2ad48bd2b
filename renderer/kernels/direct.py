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
