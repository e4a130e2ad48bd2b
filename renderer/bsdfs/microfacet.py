"""GGX (Trowbridge-Reitz) microfacet building blocks, in the local shading frame (z = normal).

Everything is isotropic and vectorised over the batch axis. ``alpha`` is the GGX width
parameter (n,) (alpha = roughness^2 for UsdPreviewSurface), directions are (n, 3) unit
vectors, cosines are taken against +z.

Formulas (Heitz 2014, "Understanding the masking-shadowing function"):

* D(h) = alpha^2 / (pi * (cos^2(theta_h) * (alpha^2 - 1) + 1)^2)
* Lambda(w) = (sqrt(1 + alpha^2 tan^2 theta) - 1) / 2. We write it with
  s(w) = sqrt(cos^2 theta + alpha^2 sin^2 theta), so that 1 + Lambda = (cos + s) / (2 cos) and no
  tangent (which is infinite at grazing) is ever formed.
* G1(w) = 1 / (1 + Lambda(w)) = 2 cos / (cos + s).
* G2(wo, wi) is the *height-correlated* Smith term 1 / (1 + Lambda(wo) + Lambda(wi)); combined with
  the 1 / (4 cos_o cos_i) of the microfacet BRDF it becomes the "visibility" term
  V = G2 / (4 cos_o cos_i) = 1 / (2 (cos_i s_o + cos_o s_i)).
* Visible normals are sampled with the spherical-cap method of Dupuy & Benyoub 2023 ("Sampling
  visible GGX normals with spherical caps"), an equivalent and simpler form of Heitz 2018.
  The density of the reflected direction is pdf(wi) = G1(wo) D(h) / (4 cos_o) = D(h) / (2 (cos_o + s_o)).

The module also tabulates the directional albedo of the single-scattering GGX lobe with
Schlick's Fresnel F = F0 + (F90 - F0) w = F0 (1 - w) + F90 w, w = (1 - wo.h)^5, which is
linear in (F0, F90):

    E(mu_o, alpha, F0, F90) = F0 * A(mu_o, alpha) + F90 * B(mu_o, alpha)

with A = mean((1 - w) G2/G1) and B = mean(w G2/G1) under VNDF sampling (see
``compute_albedo_tables``; F90 = 1 gives the usual split sum F0 A + B, the factorisation
hdStorm's dome-light BRDF table also uses). A and B live in
``_ggx_albedo_data.py`` (regenerate with ``python -m renderer.bsdfs.microfacet``), and
``albedo_tables()`` interpolates them bilinearly in (sqrt(mu), log(alpha)). The cosine-weighted
hemispherical averages E_avg = 2 * integral E(mu) mu dmu are computed from the *same* piecewise-linear
interpolant, exactly, so that a lobe shaped like (1 - E(mu)) / (1 - E_avg) integrates to one against
cos/pi to rounding error. The preview-surface BSDF relies on that for its energy balance.
"""

from __future__ import annotations

import functools

import numpy as np

INV_PI = 1.0 / np.pi

# Smallest GGX alpha we use (roughness ~0.032). illum has no delta lobes, so a "mirror" is a very
# narrow GGX lobe; its peak f ~ 1 / (pi alpha^2) = 3e5 and pdf stay finite and usable for MIS.
# (hdStorm clamps roughness at 1e-3 before squaring, alpha = 1e-6, which is fine for a
# rasteriser but gives ~1e11 peaks, i.e. fireflies, in a path tracer.)
ALPHA_MIN = 1.0e-3

# Rec.709 luminance weights (linear RGB).
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def luminance(rgb: np.ndarray) -> np.ndarray:
    """(n, 3) linear Rec.709 RGB -> (n,) luminance Y."""
    return rgb @ LUMINANCE


# --------------------------------------------------------------------------------------
# Distribution, masking, Fresnel
# --------------------------------------------------------------------------------------
def ggx_d(cos_h: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """GGX normal distribution D(h), per steradian of microfacet normal. cos_h, alpha (n,) -> (n,).

    Zero for cos_h <= 0.
    """
    a2 = alpha * alpha
    c2 = cos_h * cos_h
    t = c2 * (a2 - 1.0) + 1.0  # in [alpha^2, 1] for cos_h in [0, 1]: never 0 since alpha >= ALPHA_MIN
    den = np.pi * t * t
    d = a2 / np.where(den > 0.0, den, 1.0)
    return np.where((cos_h > 0.0) & (den > 0.0), d, 0.0)


def ggx_s(cos_t: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """s(w) = sqrt(cos^2 + alpha^2 sin^2) (n,), the masking helper (1 + Lambda = (cos + s) / (2 cos))."""
    c2 = cos_t * cos_t
    return np.sqrt(np.maximum(c2 + alpha * alpha * (1.0 - c2), 0.0))


def ggx_g1(cos_t: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Smith masking G1(w) = 2 cos / (cos + s) for cos > 0, else 0. (n,) -> (n,)."""
    s = ggx_s(cos_t, alpha)
    den = cos_t + s
    ok = (cos_t > 0.0) & (den > 0.0)
    return np.where(ok, 2.0 * cos_t / np.where(ok, den, 1.0), 0.0)


def ggx_visibility(cos_o: np.ndarray, cos_i: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Height-correlated V = G2(wo, wi) / (4 cos_o cos_i) = 1 / (2 (cos_i s_o + cos_o s_i)).

    (n,) -> (n,); zero unless both cosines are positive.
    """
    den = 2.0 * (cos_i * ggx_s(cos_o, alpha) + cos_o * ggx_s(cos_i, alpha))
    ok = (cos_o > 0.0) & (cos_i > 0.0) & (den > 0.0)
    return np.where(ok, 1.0 / np.where(ok, den, 1.0), 0.0)


def schlick_weight(cos_d: np.ndarray) -> np.ndarray:
    """(1 - cos)^5, with cos clamped to [0, 1]. (n,) -> (n,)."""
    m = 1.0 - np.clip(cos_d, 0.0, 1.0)
    m2 = m * m
    return m2 * m2 * m


def fresnel_schlick(f0: np.ndarray, cos_d: np.ndarray, f90: np.ndarray | None = None) -> np.ndarray:
    """Schlick's Fresnel F = F0 + (F90 - F0)(1 - cos)^5 (F90 = 1 if None).
    f0, f90 (n, 3), cos_d (n,) -> (n, 3)."""
    w = schlick_weight(cos_d)[:, None]
    return f0 + ((1.0 if f90 is None else f90) - f0) * w


# --------------------------------------------------------------------------------------
# Visible-normal sampling
# --------------------------------------------------------------------------------------
def sample_ggx_vndf(wo: np.ndarray, alpha: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Sample a microfacet normal h from the GGX distribution of normals visible from wo.

    wo: (n, 3) local direction with wo.z > 0; alpha: (n,); u: (n, 2) uniform in [0, 1)^2.
    Returns h (n, 3), unit, with h.z >= 0. Spherical-cap construction (Dupuy & Benyoub 2023):
    stretch wo to the alpha = 1 configuration, sample the spherical cap of directions c with
    c.z >= -wo_std.z uniformly, then h_std = wo_std + c, unstretch and normalise.
    """
    a = alpha[:, None]
    v = np.stack([wo[:, 0] * alpha, wo[:, 1] * alpha, wo[:, 2]], axis=1)
    vlen = np.sqrt(np.einsum("ij,ij->i", v, v))
    v = v / np.where(vlen > 0.0, vlen, 1.0)[:, None]
    phi = 2.0 * np.pi * u[:, 0]
    z = (1.0 - u[:, 1]) * (1.0 + v[:, 2]) - v[:, 2]
    sin_t = np.sqrt(np.clip(1.0 - z * z, 0.0, 1.0))
    h = np.stack([sin_t * np.cos(phi), sin_t * np.sin(phi), z], axis=1)
    h += v
    h[:, 0:2] *= a
    h[:, 2] = np.maximum(h[:, 2], 0.0)
    hlen = np.sqrt(np.einsum("ij,ij->i", h, h))
    ok = hlen > 0.0
    h = h / np.where(ok, hlen, 1.0)[:, None]
    # A zero-length h happens only on a measure-zero set of u; fall back to the macro normal.
    h[~ok] = (0.0, 0.0, 1.0)
    return h


def reflect(wo: np.ndarray, h: np.ndarray) -> np.ndarray:
    """Mirror wo about h: wi = 2 (wo . h) h - wo. (n, 3), (n, 3) -> (n, 3)."""
    d = np.einsum("ij,ij->i", wo, h)
    return 2.0 * d[:, None] * h - wo


def half_vector(wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """h = normalize(wo + wi) and a validity mask (|wo + wi| > 0). (n, 3) -> ((n, 3), (n,) bool)."""
    h = wo + wi
    hlen = np.sqrt(np.einsum("ij,ij->i", h, h))
    ok = hlen > 1e-12
    return h / np.where(ok, hlen, 1.0)[:, None], ok


def ggx_reflection_pdf(cos_o: np.ndarray, cos_h: np.ndarray, alpha: np.ndarray) -> np.ndarray:
    """Solid-angle pdf of wi = reflect(wo, h) with h ~ VNDF(wo): G1(wo) D(h) / (4 cos_o).

    = D(h) / (2 (cos_o + s_o)). cos_o, cos_h, alpha (n,) -> (n,); 0 for cos_o <= 0.
    """
    den = 2.0 * (cos_o + ggx_s(cos_o, alpha))
    ok = (cos_o > 0.0) & (den > 0.0)
    return np.where(ok, ggx_d(cos_h, alpha) / np.where(ok, den, 1.0), 0.0)


# --------------------------------------------------------------------------------------
# Directional albedo tables
# --------------------------------------------------------------------------------------
# Table layout. Axis 0: x = sqrt(mu) at nodes i / (N_MU - 1), mu = cos(theta_o); the square root
# puts nodes close to grazing, where the albedo of a smooth lobe changes on the scale mu ~ alpha.
# Axis 1: y = log(alpha / ALPHA_MIN) / log(1 / ALPHA_MIN) at nodes j / (N_A - 1), i.e. alpha from
# ALPHA_MIN to 1 in geometric steps (near grazing E depends on alpha / mu, so log spacing is what
# resolves small alphas; at large alpha E is smooth).
N_MU = 64
N_A = 64
# The mu = 0 node is evaluated here (the albedo of an exactly grazing direction is a limit).
MU_EPS = 1.0e-6
_LOG_ALPHA_MIN = float(np.log(ALPHA_MIN))


def table_nodes() -> tuple[np.ndarray, np.ndarray]:
    """(mu nodes (N_MU,), alpha nodes (N_A,)) at which A and B are tabulated."""
    mu = np.linspace(0.0, 1.0, N_MU) ** 2
    alpha = np.exp(_LOG_ALPHA_MIN * (1.0 - np.linspace(0.0, 1.0, N_A)))
    alpha[-1] = 1.0
    return mu, alpha


def compute_albedo_tables(k: int = 128, mu=None, alpha=None) -> tuple[np.ndarray, np.ndarray]:
    """Compute A, B (len(mu), len(alpha)) by stratified VNDF quadrature with k x k midpoints.

    For wi = reflect(wo, h), h ~ VNDF: f cos / pdf = F(wo.h) G2 / G1(wo), so
    E1 = mean(G2/G1), Ew = mean((1 - wo.h)^5 G2/G1), A = E1 - Ew, B = Ew.
    Used offline to write ``_ggx_albedo_data.py`` and by the tests to check it.
    """
    if mu is None or alpha is None:
        mu_n, alpha_n = table_nodes()
        mu = mu_n if mu is None else mu
        alpha = alpha_n if alpha is None else alpha
    mu = np.maximum(np.asarray(mu, dtype=np.float64), MU_EPS)
    alpha = np.asarray(alpha, dtype=np.float64)
    g = (np.arange(k) + 0.5) / k
    uu = np.stack(np.meshgrid(g, g, indexing="ij"), axis=-1).reshape(-1, 2)
    m = uu.shape[0]
    a_tab = np.zeros((mu.size, alpha.size))
    b_tab = np.zeros((mu.size, alpha.size))
    for i, c in enumerate(mu):
        wo1 = np.array([np.sqrt(max(0.0, 1.0 - c * c)), 0.0, c])
        for j, a in enumerate(alpha):
            wo = np.broadcast_to(wo1, (m, 3))
            al = np.full(m, a)
            h = sample_ggx_vndf(wo, al, uu)
            wi = reflect(wo, h)
            cos_i = wi[:, 2]
            cos_d = h @ wo1
            # G2 / G1(wo) = (cos_o + s_o) * cos_i / (cos_i s_o + cos_o s_i) (height-correlated).
            s_o = ggx_s(np.full(m, c), al)
            s_i = ggx_s(cos_i, al)
            den = cos_i * s_o + c * s_i
            ok = (cos_i > 0.0) & (den > 0.0)
            ratio = np.where(ok, (c + s_o) * cos_i / np.where(ok, den, 1.0), 0.0)
            w = schlick_weight(cos_d)
            e1 = ratio.mean()
            ew = (ratio * w).mean()
            a_tab[i, j] = e1 - ew
            b_tab[i, j] = ew
    return a_tab, b_tab


def _mu_average_weights(n: int) -> np.ndarray:
    """Weights w (n,) with sum(w * y) = 2 * integral_0^1 y(mu) mu dmu for the interpolant y that
    is piecewise linear in x = sqrt(mu) on the nodes x_i = i / (n - 1).

    With mu = x^2 the integral is integral y(x) 4 x^3 dx: per segment a polynomial of degree 4,
    integrated exactly by 4-point Gauss-Legendre.
    """
    x = np.linspace(0.0, 1.0, n)
    gx, gw = np.polynomial.legendre.leggauss(4)
    w = np.zeros(n)
    for i in range(n - 1):
        a, b = x[i], x[i + 1]
        h = b - a
        xs = a + 0.5 * h * (gx + 1.0)
        ws = 0.5 * h * gw * 4.0 * xs**3
        t = (xs - a) / h
        w[i] += np.sum(ws * (1.0 - t))
        w[i + 1] += np.sum(ws * t)
    return w


@functools.lru_cache(maxsize=1)
def albedo_tables() -> "AlbedoTables":
    """The shared, read-only albedo tables (loaded once per process)."""
    from renderer.bsdfs import _ggx_albedo_data as data

    a = np.asarray(data.A, dtype=np.float64).reshape(N_MU, N_A)
    b = np.asarray(data.B, dtype=np.float64).reshape(N_MU, N_A)
    # Quadrature noise must not break the invariants 0 <= B, 0 <= A, A + B <= 1 (so E <= 1 for
    # any F0 in [0, 1], and 1 - E >= 0); bilinear interpolation then keeps them everywhere.
    b = np.clip(b, 0.0, 1.0)
    a = np.clip(a, 0.0, 1.0 - b)
    w = _mu_average_weights(N_MU)
    return AlbedoTables(a=a, b=b, a_avg=w @ a, b_avg=w @ b)


class AlbedoTables:
    """Bilinear lookups of the single-scattering GGX+Schlick albedo E = F0 A + F90 B.

    a, b: (N_MU, N_A) nodal values; a_avg, b_avg: (N_A,) exact cosine-weighted averages of the
    mu-interpolants (2 integral A(mu) mu dmu). Interpolation is bilinear in (sqrt(mu), log(alpha)).
    """

    def __init__(self, a: np.ndarray, b: np.ndarray, a_avg: np.ndarray, b_avg: np.ndarray):
        self.a = a
        self.b = b
        self.a_avg = a_avg
        self.b_avg = b_avg
        for arr in (a, b, a_avg, b_avg):
            arr.setflags(write=False)

    @staticmethod
    def _r_coord(alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        la = np.log(np.clip(alpha, ALPHA_MIN, 1.0))
        y = (1.0 - la / _LOG_ALPHA_MIN) * (N_A - 1)
        j0 = np.clip(y.astype(np.int64), 0, N_A - 2)
        return j0, np.clip(y - j0, 0.0, 1.0)

    def lookup(self, mu: np.ndarray, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(A, B) at (mu (n,), alpha (n,)) -> ((n,), (n,)); mu is clamped to [0, 1]."""
        x = np.sqrt(np.clip(mu, 0.0, 1.0)) * (N_MU - 1)
        i0 = np.minimum(x.astype(np.int64), N_MU - 2)
        fx = x - i0
        j0, fy = self._r_coord(alpha)
        w00 = (1.0 - fx) * (1.0 - fy)
        w10 = fx * (1.0 - fy)
        w01 = (1.0 - fx) * fy
        w11 = fx * fy
        out = []
        for t in (self.a, self.b):
            out.append(
                t[i0, j0] * w00 + t[i0 + 1, j0] * w10 + t[i0, j0 + 1] * w01 + t[i0 + 1, j0 + 1] * w11
            )
        return out[0], out[1]

    def lookup_avg(self, alpha: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(A_avg, B_avg) at alpha (n,), interpolated in log(alpha) exactly like ``lookup``."""
        j0, fy = self._r_coord(alpha)
        return (
            self.a_avg[j0] * (1.0 - fy) + self.a_avg[j0 + 1] * fy,
            self.b_avg[j0] * (1.0 - fy) + self.b_avg[j0 + 1] * fy,
        )

    def albedo(self, f0: np.ndarray, mu: np.ndarray, alpha: np.ndarray, f90: np.ndarray | None = None) -> np.ndarray:
        """E(mu) = F0 A + F90 B: (n, 3) directional albedo of the GGX lobe (no cosine inside);
        f0, f90 (n, 3) (F90 = 1 if None), mu, alpha (n,)."""
        a, b = self.lookup(mu, alpha)
        return f0 * a[:, None] + (1.0 if f90 is None else f90) * b[:, None]

    def albedo_avg(self, f0: np.ndarray, alpha: np.ndarray, f90: np.ndarray | None = None) -> np.ndarray:
        """E_avg = F0 A_avg + F90 B_avg: (n, 3) cosine-weighted hemispherical average of E."""
        a, b = self.lookup_avg(alpha)
        return f0 * a[:, None] + (1.0 if f90 is None else f90) * b[:, None]


def _write_table_module(path: str, k: int = 512) -> None:
    """Regenerate the stored tables (about six CPU-minutes at k = 512: 64 x 64 nodes, 262k rays each)."""
    a, b = compute_albedo_tables(k)

    def fmt(arr: np.ndarray) -> str:
        vals = [f"{v:.7e}" for v in arr.ravel()]
        lines = [", ".join(vals[i : i + 6]) for i in range(0, len(vals), 6)]
        return "(\n    " + ",\n    ".join(lines) + ",\n)"

    text = (
        '"""Generated by ``python -m renderer.bsdfs.microfacet`` (do not edit).\n\n'
        f"Single-scattering GGX albedo split E = F0 A + B on a {N_MU} (sqrt mu) x {N_A} (log alpha) grid,\n"
        f"row-major, stratified VNDF quadrature with {k}x{k} midpoints per node.\n"
        '"""\n\n'
        f"A = {fmt(a)}\n\nB = {fmt(b)}\n"
    )
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(text)


if __name__ == "__main__":  # pragma: no cover - offline generator
    import os

    _write_table_module(os.path.join(os.path.dirname(__file__), "_ggx_albedo_data.py"))
