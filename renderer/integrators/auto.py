"""The ``auto`` estimator: a pilot picks, per light, the technique with the least error per second.

For every light whose IllumLightAPI says ``auto``, a pilot traces a coarse grid of camera rays
(PILOT_GRID points, fixed seed), and at every first surface hit runs each candidate estimator
for that light alone, PILOT_REPEATS times with independent random numbers and the light's own
N, timing each call (candidates interleaved, so they share whatever load the machine has).
Per candidate c it forms, with the same metric as ``illum bench``,

    V_c = Σ_points s² mse_c(point) / ((s·m(point))² + 0.01)      (relMSE of one sample)
    T_c = seconds per pilot pass of c, plus the pass's base cost (camera rays, hits, materials)

where s is the camera's exposure scale, mse_c(point) the mean squared deviation of c's runs
from the light's consensus mean at the point (the median of the candidates' means: all are
unbiased, and the median ignores one that has not found the light yet, so a BSDF sampler that
never hits a tiny light scores its missed signal, not a zero variance), and m(point) the pixel
value the auto lights give the point (the consensus means summed over the lights); it picks the smallest V_c · T_c: the lowest relMSE at equal time, since relMSE falls
as variance / samples and samples grow as time / T_c.

Candidates: lightSampling, bsdfSampling and mis always; controlVariate (α = v̄ with the
unbiased 1/(N−1) rescaling) where the light has an exact F and N ≥ 2. ``ratio`` is biased and
the α = 1 control variate goes negative, so auto never picks them. Delta lights can only be
light-sampled. Lights with no pilot signal (not seen from any pilot point) get ``mis``.

Because T_c is measured, two candidates within timing noise of each other may swap between
runs (either is then as good); the stats JSON lists each light's choice and scores, so a TD who
needs bit-identical re-renders authors the chosen token. The pilot judges the first scattering
vertex, where each light takes its own N; deeper vertices run the same technique with N = 1.
"""

from __future__ import annotations

import time

import numpy as np

from ..estimators import REGISTRY, DirectQuery, DirectRandom
from ..geometry import coordinate_frame, to_local
from ..lights.base import ShadingContext
from ..materials import make_bsdf

PILOT_GRID = (40, 30)
PILOT_REPEATS = 6
PILOT_SEED = 0xA070
# The bench's relMSE floor: pixel values are scene-referred, about 1 for a well-exposed image.
RELMSE_FLOOR = 0.01


def candidates(lights, i: int, N: int) -> list[str]:
    if lights.delta[i]:
        return ["lightSampling"]
    out = ["lightSampling", "bsdfSampling", "mis"]
    if lights.has_exact_integral[i] and N >= 2:
        out.append("controlVariate")
    return out


def pilot_points(integ):
    """First surface hits of a coarse grid of camera rays: (ctx, s, t, wo_l, bsdf, eps, mesh) or None."""
    scene, cam = integ.scene, integ.camera
    gx, gy = PILOT_GRID
    rng = np.random.default_rng(PILOT_SEED)
    px, py = np.meshgrid(np.linspace(0, cam.width - 1, gx).astype(np.int64),
                         np.linspace(0, cam.height - 1, gy).astype(np.int64))
    px, py = px.ravel(), py.ravel()
    rays = cam.generate(px, py, rng.random((px.size, 2)), rng.random((px.size, 2)))
    o = rays.o + rays.d * rays.tmin[:, None]
    hits = scene.accel.intersect(o, rays.d, rays.tmax - rays.tmin)
    k = np.nonzero(hits.hit)[0]
    if not k.size:
        return None
    si = integ._interaction(hits.prim[k], hits.b1[k], hits.b2[k], rays.d[k])
    params = scene.materials.evaluate(si.mat, si.st)
    bsdf = make_bsdf(params)
    s, t = coordinate_frame(si.ns)
    wo_l = to_local(si.wo, s, t, si.ns)
    bsdf.bind_wo(wo_l)
    return ShadingContext(si.p, si.ng, si.ns), s, t, wo_l, bsdf, scene.accel.ray_epsilon(si.p), si.mesh


def choose(integ, light_indices: list[int], settings: list[dict]) -> dict[int, dict]:
    """Pilot every auto light; returns {light: {"estimator": token, "scores": {token: V·T}}}."""
    out: dict[int, dict] = {}
    t0 = time.perf_counter()
    pts = pilot_points(integ) if light_indices else None
    # What every pixel sample costs whatever the estimator (camera ray, hit, material): part of
    # each candidate's time per sample, so it dampens differences in the estimators' own cost.
    base = time.perf_counter() - t0
    lights = integ.lights
    rng = np.random.default_rng(PILOT_SEED + 1)
    runs: dict[int, tuple] = {}
    for i in light_indices:
        N = int(settings[i]["samples"])
        cands = candidates(lights, i, N)
        if len(cands) == 1 or pts is None:
            out[i] = {"estimator": cands[0] if len(cands) == 1 else "mis", "scores": {}}
            continue
        ctx, s, t, wo_l, bsdf, eps, mesh = pts
        rows = np.arange(ctx.p.shape[0])
        if integ.scene.illuminates is not None:
            rows = rows[integ.scene.illuminates[i, mesh]]
        if not rows.size:
            out[i] = {"estimator": "mis", "scores": {}}
            continue
        b = bsdf.take(rows)
        q = DirectQuery(ctx.take(rows), s[rows], t[rows], wo_l[rows], b,
                        np.full(rows.size, i, dtype=np.int64), eps[rows], b.diffuse_constant(wo_l[rows]))
        group = int(integ.scene.shadow_group[i]) if integ.scene.shadow_group is not None else -1
        trace = integ._tracer_for(group)
        est = {c: np.zeros((PILOT_REPEATS, rows.size)) for c in cands}
        seconds = dict.fromkeys(cands, 0.0)
        for r in range(PILOT_REPEATS):
            for c in cands:
                u = DirectRandom.draw(rng, rows.size, N)
                t0 = time.perf_counter()
                res = REGISTRY[c].estimate(q, lights, trace, N, u,
                                           settings[i]["cv_alpha"] if c == "controlVariate" else "one",
                                           settings[i]["mis_heuristic"])
                seconds[c] += time.perf_counter() - t0
                est[c][r] = res.Ld.sum(axis=1) / 3.0
        runs[i] = (rows, est, seconds)
    if not runs:
        return out
    # The pixel value the auto lights give each pilot point (all candidates are unbiased).
    n_pts = pts[0].p.shape[0]
    total = np.zeros(n_pts)
    means = {}
    for i, (rows, est, _) in runs.items():
        # The median over candidates: robust to one that has not found the light yet (a BSDF
        # sampler that never hits a tiny light returns 0 with zero variance).
        means[i] = np.median([e.mean(axis=0) for e in est.values()], axis=0)
        total[rows] += means[i]
    s2 = float(integ.camera.desc.exposure_scale) ** 2
    for i, (rows, est, seconds) in runs.items():
        den = s2 * total[rows] ** 2 + RELMSE_FLOOR
        t_base = base * rows.size / n_pts
        # Mean squared error about the consensus mean, not the variance: that also charges a
        # candidate for the signal it misses.
        mse = {c: ((e - means[i]) ** 2).mean(axis=0) for c, e in est.items()}
        scores = {c: float((s2 * mse[c] / den).sum() * (t_base + seconds[c] / PILOT_REPEATS))
                  for c, e in est.items()}
        out[i] = {"estimator": min(scores, key=scores.get), "scores": scores}
    return out
