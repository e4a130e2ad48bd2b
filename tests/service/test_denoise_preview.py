"""The service's live preview can show the denoised image (#20 item 3): a job with
``settings.denoise`` writes an OIDN-denoised PNG with each snapshot and at the end, served by
``GET /jobs/{id}/image?denoised=true``. Real server and workers; images read back with
OpenImageIO."""

from __future__ import annotations

import numpy as np
import pytest

from .conftest import wait_for, wait_job

pytest.importorskip("pyoidn", reason="pyoidn (illum[denoise]) is not installed")


def _pixels(data: bytes, tmp_path, name: str) -> np.ndarray:
    """(h, w, C) float values of an image file's bytes, read with OpenImageIO."""
    import OpenImageIO as oiio

    p = tmp_path / name
    p.write_bytes(data)
    inp = oiio.ImageInput.open(str(p))
    assert inp is not None, oiio.geterror()
    try:
        spec = inp.spec()
        return np.asarray(inp.read_image(0, 0, 0, spec.nchannels, "float"), dtype=np.float64), spec
    finally:
        inp.close()


def _roughness(img: np.ndarray) -> float:
    """Mean absolute difference between horizontal and vertical neighbours (noise shows here)."""
    return float(np.abs(np.diff(img, axis=0)).mean() + np.abs(np.diff(img, axis=1)).mean())


def test_live_preview_and_final_image_denoised(client, tmp_path):
    job = client.post("/jobs", json={"stage": "cornell_box.usda", "settings": {
        "resolution": [32, 32], "spp": 60000, "time_budget": 6, "denoise": True, "seed": 3}}).json()
    url = f"/jobs/{job['id']}/image"

    def live_pair():
        noisy = client.get(url, params={"format": "png"})
        den = client.get(url, params={"format": "png", "denoised": "true"})
        if den.status_code != 200 or den.headers["X-Illum-Image"] != "preview" or noisy.status_code != 200:
            return None
        return noisy, den

    noisy, den = wait_for(live_pair, 90, what="a denoised live preview")
    assert client.get(f"/jobs/{job['id']}").json()["links"]["image_denoised_png"].endswith("denoised=true")
    raw, _ = _pixels(noisy.content, tmp_path, "noisy.png")
    smooth, spec = _pixels(den.content, tmp_path, "den.png")
    assert (spec.width, spec.height) == (32, 32)
    # the same scene, less noise: OIDN smooths the early, noisy preview
    assert abs(smooth.mean() - raw.mean()) < 0.1, (smooth.mean(), raw.mean())
    assert _roughness(smooth) < 0.7 * _roughness(raw), (_roughness(smooth), _roughness(raw))

    done = wait_job(client, job["id"], timeout=120)
    assert done["state"] == "succeeded", done
    final = client.get(url, params={"format": "png", "denoised": "true"})
    assert final.status_code == 200 and final.headers["X-Illum-Image"] == "final"
    # the final denoised PNG is the EXR's denoised layer, display-encoded
    from renderer.output import display_encode

    exr, spec = _pixels(client.get(url, params={"format": "exr"}).content, tmp_path, "final.exr")
    names = list(spec.channelnames)
    layer = exr[:, :, [names.index(f"denoised.{c}") for c in "RGB"]]
    png, _ = _pixels(final.content, tmp_path, "final_den.png")
    assert np.abs(png[:, :, :3] - np.clip(display_encode(layer.astype(np.float32)), 0, 1)).max() <= 1.0 / 255 + 1e-6


def test_denoised_image_needs_a_denoising_job(client):
    job = client.post("/jobs", json={"stage": "cornell_box.usda", "settings": {"resolution": [8, 8], "spp": 1}}).json()
    r = client.get(f"/jobs/{job['id']}/image", params={"denoised": "true"})
    assert r.status_code == 404 and "does not denoise" in r.json()["message"]
    r = client.get(f"/jobs/{job['id']}/image", params={"denoised": "true", "format": "exr"})
    assert r.status_code == 422 and r.json()["message"].startswith("query.denoised: ")
    assert wait_job(client, job["id"])["links"]["image_denoised_png"] is None
