"""The UsdPreviewSurface BSDF: a diffuse lobe plus a GGX microfacet specular lobe.

All directions are in the local shading frame (z = shading normal), (n, 3) float64, unit length.
Reflection only: every function returns 0 when wo.z <= 0 or wi.z <= 0 (the integrator flips the
shading frame so that wo.z > 0 before calling). f excludes the cosine term; pdfs are per steradian.

Parameters (from ``SurfaceParams``, see ``from_params``)
---------------------------------------------------------
* alpha = max(roughness^2, ALPHA_MIN = 1e-3) (roughness clamped to [0, 1]). The floor keeps the
  lobe a finite density (no delta lobes in illum); hdStorm clamps roughness at 1e-3 instead,
  which is a thinner floor (alpha 1e-6), but our float64 pdfs and float32 film are happier at
  alpha = 1e-3, which is visually a mirror.
* metallic workflow (useSpecularWorkflow = 0), as the UsdPreviewSurface spec defines it ("If
  metallic is 1, then both F0 [...] and edge F90 reflectivity will simply be the Albedo. If
  metallic is 0, then Albedo is ignored [...]; F0 is derived from ior via ((1-ior)/(1+ior))^2
  and F90 is white. In between, we interpolate."):
      F0  = lerp(((1 - ior) / (1 + ior))^2, diffuseColor, metallic)   (dielectric F0 is achromatic)
      F90 = lerp(1, diffuseColor, metallic)
      rho_d = diffuseColor * (1 - metallic)
  specular workflow: F0 = specularColor, F90 = 1, rho_d = diffuseColor.
  Colours, metallic and ior are clamped to their physical ranges ([0, 1], [0, 1], >= 0).
  hdStorm (previewSurface.glslfx) has the same F90 and endpoints, but interpolates F0 as
  lerp(R^2 s, s, metallic) with s = lerp(1, diffuseColor, metallic), i.e. quadratically in
  metallic; we keep the spec's plain interpolation (identical at metallic 0 and 1).
* Fresnel: Schlick on the microfacet half-vector, F = F0 + (F90 - F0)(1 - wo.h)^5. A metal's
  grazing reflection is thus tinted by its albedo (F90 < 1). A physical conductor's Fresnel
  whitens toward grazing, but the spec prescribes the tint, and hdStorm and MaterialX's
  UsdPreviewSurface graph (since MaterialX PR #1187) follow it; so do we, for interchange.

The lobes
---------
    f_specular(wo, wi) = F(wo.h) D(h) G2(wo, wi) / (4 cos_o cos_i)
with GGX D and the *height-correlated* Smith G2 (see ``microfacet.py``).

    f_diffuse(wo, wi) = rho_d / pi * (1 - E(wo)) (1 - E(wi)) / (1 - E_avg)

where E(w) = F0 A(cos, alpha) + F90 B(cos, alpha) (per RGB channel) is the directional albedo of
the specular lobe (tabulated, ``microfacet.albedo_tables``) and E_avg = 2 integral E(mu) mu dmu its
cosine-weighted average (computed exactly from the same interpolant). This is the
Kelemen & Szirmay-Kalos (2001) coupling, the form Kulla & Conty (2017) use for energy
compensation. It is

* reciprocal: symmetric in (wo, wi) (and so is the specular lobe: wo.h = wi.h);
* energy conserving and, for a white base, energy *preserving*: the diffuse albedo is exactly
  integral f_diffuse cos dwi = rho_d (1 - E(wo)), so the total albedo is
  E(wo) + rho_d (1 - E(wo)) <= 1 for every rho_d, F0, F90 <= 1, roughness and angle (up to the
  table's interpolation error: <= 1e-3 in E down to 89 degrees, a few 1e-3 within a degree of
  grazing). White diffuse under a dielectric coat passes the furnace test (measured 0.999..1.001).

Why not the simpler alternatives
--------------------------------
* hdStorm's previewSurface.glslfx scales the diffuse by (1 - F(wo.h)) on the half-vector. That is
  reciprocal but not energy conserving: at 85 degrees a smooth (roughness 0.05) dielectric
  reflects 0.65 of the light specularly, while that diffuse lobe (whose h is far from wo) keeps
  0.94, so a white material returns 1.59 times the incident energy (1.29 at roughness 0.3). Our (1 - E(wo)) plays the same role ("grazing
  angles have less diffuse") with the *integrated* Fresnel/masking, which is what conserves energy.
* A diffuse lobe that is constant in wi for a given wo *and* reciprocal must be constant in both
  directions, c rho_d / pi. Energy conservation then needs rho_d c <= 1 - sup_wo E(wo), and
  sup E -> 1 at grazing for smooth surfaces, so c would have to be ~0: no diffuse at all. So a
  principled lobe cannot be constant in wi; we give up that (not reciprocity or energy).

For control variates
--------------------
f_diffuse factors as ``diffuse_constant(wo) * diffuse_factor_wi(wi)``, with
diffuse_constant(wo) = rho_d (1 - E(wo)) / pi (n, 3), constant in wi, and
diffuse_factor_wi(wi) = (1 - E(wi)) / (1 - E_avg), whose cosine-weighted hemispherical mean is
exactly 1. A control variate g(wi) = diffuse_constant(wo) L(wi) cos has the same hemispherical
integral as the true diffuse lobe under uniform illumination and an analytic integral for any
light whose unshadowed irradiance is known; the estimator stays unbiased as long as its Monte
Carlo residual is f(wo, wi) - diffuse_constant(wo) (NOT f_specular alone). The factor is close to 1
except toward grazing wi (0.82..1.02 for F0 = 0.04, roughness 0.5).

Sampling
--------
Lobe selection with u_lobe in proportion to each lobe's exact albedo for wo:
P_d = lum(rho_d (1 - E(wo))) / (lum(rho_d (1 - E(wo))) + lum(E(wo))), P_s = 1 - P_d
(0.5 / 0.5 if both vanish). The diffuse lobe is sampled with a cosine-weighted hemisphere, the
specular lobe with GGX visible normals (spherical caps, Dupuy & Benyoub 2023) reflected about h.
pdf() is the exact mixture P_d cos_i / pi + P_s G1(wo) D(h) / (4 cos_o), so MIS works.

Implementation
--------------
f, pdf, f_pdf, f_parts, f_diffuse, f_specular, diffuse_constant, lobe_probabilities and sample_f
run as numba kernels (``_preview_kernels.py``, single-threaded, GIL released);
``reference_f_pdf`` / ``reference_sample_f`` and the per-lobe samplers are the numpy versions the
tests hold the kernels to. The per-point parameters are packed in one (n, K) array (``_P``), so
``take`` is a single gather; ``rho_d``, ``f0``, ``f90`` and ``alpha`` are views into it.

wo terms: everything a vertex asks of the BSDF needs E(wo) (a table lookup) and the lobe
probability. ``bind_wo(wo)`` computes them once and stores them with the cosine they belong
to; every later call (on this BSDF or on ``take(rows)`` of it, which carries them along) whose
wo has the same wo.z on a row reuses them. The check is per row and by value, so results never
depend on whether or with what a BSDF was bound: binding only saves work. A caller that needs
f, f_diffuse and pdf for the same (wo, wi) should call ``f_parts`` (one pass) rather than three
methods.

Not modelled: clearcoat, normal maps, displacement, occlusion, refraction (opacity is handled as
presence by the material table), multiple scattering between microfacets: the single-scattering
specular lobe loses energy as roughness grows (a white metal reflects 0.99 at roughness 0.3,
0.92 at 0.5, 0.56 at 0.8 and 0.31 at roughness 1, at normal incidence). Kulla-Conty compensation
would reuse the E / E_avg tables already here; hdStorm does not compensate either.
"""

from __future__ import annotations

import numpy as np

from renderer.bsdfs import _preview_kernels as kernels
from renderer.bsdfs.base import BSDFSample
from renderer.bsdfs.microfacet import (
    ALPHA_MIN,
    INV_PI,
    albedo_tables,
    fresnel_schlick,
    ggx_d,
    ggx_reflection_pdf,
    ggx_visibility,
    half_vector,
    luminance,
    reflect,
    sample_ggx_vndf,
)
from renderer.sampling import sample_cosine_hemisphere

LOBE_DIFFUSE = 0
LOBE_SPECULAR = 1


def dielectric_f0(ior) -> np.ndarray:
    """Normal-incidence Fresnel reflectance ((ior - 1) / (ior + 1))^2 of a dielectric, the
    metallic workflow's F0 at metallic 0 (ior clamped to >= 0). ior: float or (n,) array."""
    eta = np.maximum(np.asarray(ior, dtype=np.float64), 0.0)
    r = (eta - 1.0) / (eta + 1.0)  # eta + 1 >= 1
    return r * r


class PreviewSurfaceBSDF:
    """UsdPreviewSurface (diffuse + GGX specular) for n shading points.

    rho_d: (n, 3) diffuse base albedo in [0, 1] (``diffuse_albedo()``);
    f0: (n, 3) specular reflectance at normal incidence in [0, 1];
    alpha: (n,) GGX width, >= ALPHA_MIN;
    f90: (n, 3) specular reflectance at grazing incidence in [0, 1] (None: 1, white).
    Use ``from_params`` (or ``renderer.materials.make_bsdf``) to build one from UsdPreviewSurface
    inputs. At a path vertex: ``bsdf.bind_wo(wo)`` once (optional, saves the E(wo) work of every
    later call), then ``f_parts`` for light samples and ``sample_f`` for BSDF samples.
    """

    def __init__(self, rho_d: np.ndarray, f0: np.ndarray, alpha: np.ndarray, f90: np.ndarray | None = None):
        rho_d = np.asarray(rho_d, dtype=np.float64)
        alpha = np.maximum(np.asarray(alpha, dtype=np.float64), ALPHA_MIN)
        P = np.empty((alpha.shape[0], kernels.K))
        P[:, kernels.RHO : kernels.RHO + 3] = rho_d
        P[:, kernels.F0 : kernels.F0 + 3] = np.asarray(f0, dtype=np.float64)
        P[:, kernels.F90 : kernels.F90 + 3] = 1.0 if f90 is None else np.asarray(f90, dtype=np.float64)
        P[:, kernels.ALPHA] = alpha
        self._tables = albedo_tables()
        # Per-point constants of the diffuse lobe: k_d = rho_d / (pi (1 - E_avg)), 1 / (1 - E_avg),
        # and the table coordinate of alpha.
        kernels.init_kernel(P, self._tables.a_avg, self._tables.b_avg)
        self._set_packed(P)

    def _set_packed(self, P: np.ndarray) -> None:
        self._P = P
        # Views into P (read-only by convention; the kernels read P).
        self.rho_d = P[:, kernels.RHO : kernels.RHO + 3]
        self.f0 = P[:, kernels.F0 : kernels.F0 + 3]
        self.f90 = P[:, kernels.F90 : kernels.F90 + 3]
        self.alpha = P[:, kernels.ALPHA]
        self._k_d = P[:, kernels.KD : kernels.KD + 3]
        self._inv_one_minus_avg = P[:, kernels.INV_OMA : kernels.INV_OMA + 3]

    # ----------------------------------------------------------------------------------
    # Construction
    # ----------------------------------------------------------------------------------
    @classmethod
    def from_packed(cls, P: np.ndarray) -> "PreviewSurfaceBSDF":
        """Wrap packed rows (n, kernels.K) taken from another BSDF's ``packed`` (no copy)."""
        out = cls.__new__(cls)
        out._tables = albedo_tables()
        out._set_packed(P)
        return out

    @property
    def packed(self) -> np.ndarray:
        """The packed per-point rows (n, kernels.K): inputs and wo-independent constants."""
        return self._P

    @classmethod
    def from_params(cls, params) -> "PreviewSurfaceBSDF":
        """Build from a ``SurfaceParams``-like object (diffuse, specular_color,
        use_specular_workflow, metallic, roughness, ior; arrays with batch axis first)."""
        return cls.from_inputs(
            params.diffuse,
            params.specular_color,
            params.use_specular_workflow,
            params.metallic,
            params.roughness,
            params.ior,
        )

    @classmethod
    def from_inputs(
        cls,
        diffuse_color: np.ndarray,
        specular_color: np.ndarray,
        use_specular_workflow: np.ndarray,
        metallic: np.ndarray,
        roughness: np.ndarray,
        ior: np.ndarray,
    ) -> "PreviewSurfaceBSDF":
        """UsdPreviewSurface inputs -> (rho_d, F0, F90, alpha). Shapes: colours (n, 3), the rest (n,)."""
        cols = [np.ascontiguousarray(diffuse_color, dtype=np.float64),
                np.ascontiguousarray(specular_color, dtype=np.float64)]
        rows = [np.ascontiguousarray(use_specular_workflow, dtype=bool),
                np.ascontiguousarray(metallic, dtype=np.float64),
                np.ascontiguousarray(roughness, dtype=np.float64),
                np.ascontiguousarray(ior, dtype=np.float64)]
        n = cols[0].shape[0] if cols[0].ndim == 2 else -1
        if all(c.shape == (n, 3) for c in cols) and all(r.shape == (n,) for r in rows):
            # One pass (numba) for the mapping below and the derived per-point constants.
            out = cls.__new__(cls)
            out._tables = albedo_tables()
            P = np.empty((n, kernels.K))
            kernels.inputs_kernel(*cols, *rows, P)
            kernels.init_kernel(P, out._tables.a_avg, out._tables.b_avg)
            out._set_packed(P)
            return out
        diffuse = np.clip(np.asarray(diffuse_color, dtype=np.float64), 0.0, 1.0)
        spec = np.clip(np.asarray(specular_color, dtype=np.float64), 0.0, 1.0)
        m = np.clip(np.asarray(metallic, dtype=np.float64), 0.0, 1.0)[:, None]
        f0_dielectric = dielectric_f0(ior)[:, None]
        use_spec = np.asarray(use_specular_workflow, dtype=bool)[:, None]
        f0 = np.where(use_spec, spec, f0_dielectric * (1.0 - m) + diffuse * m)
        f90 = np.where(use_spec, 1.0, (1.0 - m) + diffuse * m)
        rho_d = np.where(use_spec, diffuse, diffuse * (1.0 - m))
        rough = np.clip(np.asarray(roughness, dtype=np.float64), 0.0, 1.0)
        return cls(rho_d, f0, np.maximum(rough * rough, ALPHA_MIN), f90)

    def __len__(self) -> int:
        return self.alpha.shape[0]

    def take(self, rows: np.ndarray) -> "PreviewSurfaceBSDF":
        """The BSDF of a subset of the shading points (rows: index array or boolean mask).

        Bound wo terms (``bind_wo``) come along with their rows."""
        out = PreviewSurfaceBSDF.__new__(PreviewSurfaceBSDF)
        out._tables = self._tables
        rows = np.asarray(rows)
        # np.take on an index array: one gather of the packed rows (faster than P[rows]).
        out._set_packed(self._P[rows] if rows.dtype == bool else np.take(self._P, rows, axis=0))
        return out

    def bind_wo(self, wo: np.ndarray) -> "PreviewSurfaceBSDF":
        """Precompute the wo terms (E(wo) table lookup, lobe probability) for wo (n, 3) and keep
        them for later calls; returns self.

        Optional, purely an optimisation: any later call whose wo has, on a row, the wo.z the
        terms were computed from uses them instead of recomputing them (identical results);
        other rows compute their own. ``take(rows)`` carries the bound terms of its rows, so
        ``bsdf.take(r).f_parts(wo[r], wi)`` benefits too. Binding again replaces the terms.
        Not to be called while another thread evaluates this same object.
        """
        wo = kernels.as_rows(wo, 3)
        if wo.shape[0] != len(self):
            raise ValueError(f"bind_wo: wo has {wo.shape[0]} rows, the BSDF {len(self)}")
        kernels.bind_kernel(wo, self._P, self._tables.a, self._tables.b)
        return self

    # ----------------------------------------------------------------------------------
    # Fused path-vertex steps (optional BSDF methods the path tracer uses when present; the
    # unfused f_pdf / sample_f route gives the same numbers, one numpy pass at a time)
    # ----------------------------------------------------------------------------------
    def path_light_half(self, wo, s, t, ns, ng, wi, L, pdf_l, delta, pmf, power, beta) -> np.ndarray:
        """beta · h(pmf p_l, p_b) f(wo, wi) |cos| L / (p_l pmf) per row, (n, 3): the light half
        of continuation MIS (estimators.mis.mis_light_half), before visibility. Shapes and
        meaning: _preview_kernels.light_half_kernel; wo local, the rest world-space."""
        n = len(self)
        out = np.empty((n, 3))
        c = np.ascontiguousarray
        kernels.light_half_kernel(
            kernels.as_rows(wo, 3), kernels.as_rows(s, 3), kernels.as_rows(t, 3), kernels.as_rows(ns, 3),
            kernels.as_rows(ng, 3), kernels.as_rows(wi, 3), kernels.as_rows(L, 3), c(pdf_l, dtype=np.float64),
            c(delta, dtype=np.bool_), c(pmf, dtype=np.float64), c(power, dtype=np.bool_), kernels.as_rows(beta, 3),
            self._P, self._tables.a, self._tables.b, out)
        return out

    def path_scatter(self, wo, s, t, ns, ng, beta, u_lobe, u, u_rr, rr):
        """sample_f fused with the path update: (wi world (n, 3), beta' (n, 3), pdf (n,), ok (n,))
        with Russian roulette where rr (see _preview_kernels.scatter_kernel)."""
        n = len(self)
        wi, beta_out, pdf, ok = np.empty((n, 3)), np.empty((n, 3)), np.empty(n), np.empty(n, dtype=np.bool_)
        c = np.ascontiguousarray
        kernels.scatter_kernel(
            kernels.as_rows(wo, 3), kernels.as_rows(s, 3), kernels.as_rows(t, 3), kernels.as_rows(ns, 3),
            kernels.as_rows(ng, 3), kernels.as_rows(beta, 3), c(u_lobe, dtype=np.float64), kernels.as_rows(u, 2),
            c(u_rr, dtype=np.float64), c(rr, dtype=np.bool_), self._P, self._tables.a, self._tables.b,
            wi, beta_out, pdf, ok)
        return wi, beta_out, pdf, ok

    # ----------------------------------------------------------------------------------
    # Albedos and lobe weights
    # ----------------------------------------------------------------------------------
    def diffuse_albedo(self) -> np.ndarray:
        """(n, 3) rho_d, the diffuse base albedo (diffuseColor, times 1 - metallic in the metallic
        workflow). The diffuse lobe's directional albedo is rho_d (1 - specular_albedo(wo))."""
        return self.rho_d

    def specular_albedo(self, wo: np.ndarray) -> np.ndarray:
        """(n, 3) E(wo) = integral f_specular cos dwi (tabulated; 0 for wo.z <= 0)."""
        cos_o = wo[:, 2]
        e = self._tables.albedo(self.f0, cos_o, self.alpha, self.f90)
        return np.where((cos_o > 0.0)[:, None], e, 0.0)

    def diffuse_constant(self, wo: np.ndarray) -> np.ndarray:
        """(n, 3) rho_d (1 - E(wo)) / pi: the constant-in-wi lobe whose hemispherical integral
        against cos equals the diffuse lobe's (its directional albedo / pi). 0 for wo.z <= 0."""
        wo = kernels.as_rows(wo, 3)
        out = np.empty((wo.shape[0], 3))
        kernels.wo_kernel(wo, self._P, self._tables.a, self._tables.b, out, np.empty(0))
        return out

    def has_residual(self) -> np.ndarray:
        """(n,) bool: f differs from the control lobe diffuse_constant(wo). True on every row: the
        specular lobe vanishes only for F0 = F90 = 0 (a black metal), which this overlooks at the
        cost of a few wasted BSDF samples."""
        return np.ones(len(self), dtype=bool)

    def diffuse_factor_wi(self, wi: np.ndarray) -> np.ndarray:
        """(n, 3) (1 - E(wi)) / (1 - E_avg) for wi.z > 0, else 0, so that
        f_diffuse(wo, wi) == diffuse_constant(wo) * diffuse_factor_wi(wi). Its cosine-weighted
        mean over the hemisphere is 1."""
        cos_i = wi[:, 2]
        c_i = 1.0 - self._tables.albedo(self.f0, cos_i, self.alpha, self.f90)
        return np.where((cos_i > 0.0)[:, None], c_i * self._inv_one_minus_avg, 0.0)

    def _wo_terms(self, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(cos_o (n,), c_o = 1 - E(wo) (n, 3), P_d (n,)) for the lobe mixture."""
        cos_o = wo[:, 2]
        e_o = self._tables.albedo(self.f0, cos_o, self.alpha, self.f90)
        c_o = 1.0 - e_o
        w_d = luminance(self.rho_d * c_o)
        w_s = luminance(e_o)
        tot = w_d + w_s
        p_d = np.where(tot > 0.0, w_d / np.where(tot > 0.0, tot, 1.0), 0.5)
        return cos_o, c_o, p_d

    def lobe_probabilities(self, wo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P_diffuse (n,), P_specular (n,)) used by sample_f for this wo."""
        wo = kernels.as_rows(wo, 3)
        p_d = np.empty(wo.shape[0])
        kernels.wo_kernel(wo, self._P, self._tables.a, self._tables.b, np.empty((0, 3)), p_d)
        return p_d, 1.0 - p_d

    # ----------------------------------------------------------------------------------
    # Evaluation
    # ----------------------------------------------------------------------------------
    def _eval(
        self, wo: np.ndarray, wi: np.ndarray, cos_o: np.ndarray, c_o: np.ndarray, p_d: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(f_diffuse (n, 3), f_specular (n, 3), pdf (n,)) given the wo terms."""
        cos_i = wi[:, 2]
        h, h_ok = half_vector(wo, wi)
        ok = (cos_o > 0.0) & (cos_i > 0.0) & h_ok
        cos_h = h[:, 2]
        cos_d = np.einsum("ij,ij->i", wo, h)
        # Diffuse: k_d (1 - E(wo)) (1 - E(wi)).
        c_i = 1.0 - self._tables.albedo(self.f0, cos_i, self.alpha, self.f90)
        f_d = self._k_d * c_o * c_i
        # Specular: F D V.
        d = ggx_d(cos_h, self.alpha)
        dv = d * ggx_visibility(cos_o, cos_i, self.alpha)
        f_s = fresnel_schlick(self.f0, cos_d, self.f90) * dv[:, None]
        pdf = p_d * cos_i * INV_PI + (1.0 - p_d) * ggx_reflection_pdf(cos_o, cos_h, self.alpha)
        okc = ok[:, None]
        return np.where(okc, f_d, 0.0), np.where(okc, f_s, 0.0), np.where(ok, pdf, 0.0)

    def _evaluate(self, wo, wi, f=False, fd=False, fs=False, pdf=False):
        """Run the evaluation kernel; returns the wanted arrays (f, f_diffuse, f_specular, pdf)
        in that order, an empty array in place of each one not wanted."""
        wo = kernels.as_rows(wo, 3)
        wi = kernels.as_rows(wi, 3)
        n = wo.shape[0]
        out_f = np.empty((n if f else 0, 3))
        out_fd = np.empty((n if fd else 0, 3))
        out_fs = np.empty((n if fs else 0, 3))
        out_pdf = np.empty(n if pdf else 0)
        kernels.eval_kernel(wo, wi, self._P, self._tables.a, self._tables.b, out_f, out_fd, out_fs, out_pdf)
        return out_f, out_fd, out_fs, out_pdf

    def f_parts(self, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(f (n, 3), f_diffuse (n, 3), pdf (n,)) in one pass: what a light sample's integrand
        split (control lobe / residual) and its MIS weight need. Same values as f, f_diffuse
        and pdf."""
        f, fd, _, pdf = self._evaluate(wo, wi, f=True, fd=True, pdf=True)
        return f, fd, pdf

    def f_pdf(self, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(f (n, 3), pdf (n,)) in one pass (numba kernel): what MIS on a light sample needs."""
        f, _, _, pdf = self._evaluate(wo, wi, f=True, pdf=True)
        return f, pdf

    def f(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n, 3) f_diffuse + f_specular (no cosine)."""
        return self._evaluate(wo, wi, f=True)[0]

    def f_diffuse(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n, 3) rho_d / pi (1 - E(wo)) (1 - E(wi)) / (1 - E_avg); see the module docstring."""
        return self._evaluate(wo, wi, fd=True)[1]

    def f_specular(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n, 3) F(wo.h) D(h) G2(wo, wi) / (4 cos_o cos_i)."""
        return self._evaluate(wo, wi, fs=True)[2]

    def pdf(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n,) solid-angle pdf of sample_f producing wi: P_d pdf_diffuse + P_s pdf_specular."""
        return self._evaluate(wo, wi, pdf=True)[3]

    def reference_f_pdf(self, wo: np.ndarray, wi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """numpy version of ``f_pdf`` (readable reference for the numba kernel; tests compare)."""
        cos_o, c_o, p_d = self._wo_terms(wo)
        f_d, f_s, pdf = self._eval(wo, wi, cos_o, c_o, p_d)
        return f_d + f_s, pdf

    # ----------------------------------------------------------------------------------
    # Single-lobe samplers (used by sample_f; public for tests and for lobe-specific MIS)
    # ----------------------------------------------------------------------------------
    def pdf_diffuse(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n,) cos_i / pi where both directions are above the surface, else 0."""
        ok = (wo[:, 2] > 0.0) & (wi[:, 2] > 0.0)
        return np.where(ok, wi[:, 2] * INV_PI, 0.0)

    def sample_diffuse(self, wo: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Cosine-weighted wi (n, 3) and its pdf (n,) (0 where wo.z <= 0)."""
        wi = sample_cosine_hemisphere(u)
        return wi, self.pdf_diffuse(wo, wi)

    def pdf_specular(self, wo: np.ndarray, wi: np.ndarray) -> np.ndarray:
        """(n,) G1(wo) D(h) / (4 cos_o) for reflections above the surface, else 0."""
        cos_o, cos_i = wo[:, 2], wi[:, 2]
        h, h_ok = half_vector(wo, wi)
        ok = (cos_o > 0.0) & (cos_i > 0.0) & h_ok
        return np.where(ok, ggx_reflection_pdf(cos_o, h[:, 2], self.alpha), 0.0)

    def sample_specular(self, wo: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """VNDF-sampled reflection wi (n, 3) and its specular-lobe pdf (n,) (0 = failed: the
        reflected direction went below the surface, or wo.z <= 0)."""
        wi = self._sample_specular_dirs(wo, self.alpha, u)
        return wi, self.pdf_specular(wo, wi)

    @staticmethod
    def _sample_specular_dirs(wo: np.ndarray, alpha: np.ndarray, u: np.ndarray) -> np.ndarray:
        # VNDF sampling needs wo.z > 0; evaluate with a harmless +z for the others (their pdf is 0).
        wo_up = np.where((wo[:, 2] > 0.0)[:, None], wo, np.array([0.0, 0.0, 1.0]))
        h = sample_ggx_vndf(wo_up, alpha, u)
        wi = reflect(wo_up, h)
        n = np.sqrt(np.einsum("ij,ij->i", wi, wi))
        return wi / np.where(n > 0.0, n, 1.0)[:, None]

    # ----------------------------------------------------------------------------------
    # The mixture sampler
    # ----------------------------------------------------------------------------------
    def sample_f(self, wo: np.ndarray, u_lobe: np.ndarray, u: np.ndarray) -> BSDFSample:
        """Pick the diffuse lobe if u_lobe < P_d(wo), else the specular lobe, and sample it with u.

        wo: (n, 3); u_lobe: (n,); u: (n, 2). Returns BSDFSample with f = f(wo, wi), pdf = the
        mixture pdf(wo, wi) (0 marks a failed sample: wo below the surface or wi below it) and
        lobe (0 diffuse, 1 specular). numba kernel; ``reference_sample_f`` is the numpy version.
        """
        wo = kernels.as_rows(wo, 3)
        n = wo.shape[0]
        u_lobe = np.ascontiguousarray(u_lobe, dtype=np.float64).reshape(n)
        u = kernels.as_rows(u, 2)
        wi = np.zeros((n, 3))
        f = np.zeros((n, 3))
        pdf = np.zeros(n)
        lobe = np.zeros(n, dtype=np.int8)
        kernels.sample_kernel(wo, u_lobe, u, self._P, self._tables.a, self._tables.b, wi, f, pdf, lobe)
        return BSDFSample(f=f, wi=wi, pdf=pdf, lobe=lobe)

    def reference_sample_f(self, wo: np.ndarray, u_lobe: np.ndarray, u: np.ndarray) -> BSDFSample:
        """numpy version of ``sample_f`` (same warps, same random-number use)."""
        cos_o, c_o, p_d = self._wo_terms(wo)
        n = wo.shape[0]
        valid = cos_o > 0.0
        pick_d = np.asarray(u_lobe) < p_d
        wi = np.zeros((n, 3))
        wi[:, 2] = 1.0
        rows_d = np.nonzero(pick_d & valid)[0]
        rows_s = np.nonzero(~pick_d & valid)[0]
        if rows_d.size:
            wi[rows_d] = sample_cosine_hemisphere(u[rows_d])
        if rows_s.size:
            wi[rows_s] = self._sample_specular_dirs(wo[rows_s], self.alpha[rows_s], u[rows_s])
        f_d, f_s, pdf = self._eval(wo, wi, cos_o, c_o, p_d)
        f = f_d + f_s  # already 0 wherever wo or wi is below the surface
        lobe = np.where(pick_d, LOBE_DIFFUSE, LOBE_SPECULAR).astype(np.int8)
        return BSDFSample(f=f, wi=wi, pdf=pdf, lobe=lobe)
