"""gazelight.render(backend=...): the CLI's renderer choice (`--backend`,
the application core's `gazelight_app::backend`) from Python.

The CPU pipeline is the reference: backend="gpu" renders the same frames
within the tolerances of the CLI's own GPU/CPU parity test
(crates/gazelight/tests/backend.rs `render_gpu_matches_cpu`: every frame
within 1/255, the gaze/pupil/kernel columns equal, adaptation and target
within 1e-4 relative, acuity within 1e-3 px + 1e-4 relative). Without an
adapter, backend="gpu" fails with the CLI's sentence (in Python's words)
and "auto" falls back to the CPU and says why, as the CLI does.

The GPU test needs an adapter (here and on CI: Mesa's lavapipe,
`WGPU_BACKEND=vulkan`); without one it skips, unless
`GAZELIGHT_REQUIRE_GPU=1`, which makes that a failure (the Rust tests'
rule).
"""

import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import gazelight

# The embedded demo at 96x80, one frame a second: the ground, the glance up
# at the street lamp at 3 s (adaptation up by decades, the pupil and so the
# glare kernel change) and back at 7.5 s.
DEMO = dict(size=(96, 80), fps=1.0, frames=9)

EXACT = ("gaze_u", "gaze_v", "pupil_mm", "pupil_held", "psf_pupil_mm", "psf_rebuilt")
RELATIVE = ("target_cd_m2", "adaptation_cd_m2")

# Vulkan with no driver: the loader finds no ICD, so wgpu lists no adapter
# (the CLI test's NO_ADAPTER_ENV).
NO_ADAPTER_ENV = {
    "WGPU_BACKEND": "vulkan",
    "VK_ICD_FILENAMES": "/nonexistent/icd.json",
    "VK_DRIVER_FILES": "/nonexistent/icd.json",
    "VK_ADD_DRIVER_FILES": "/nonexistent/icd.json",
}


def _gpu_render(**kw):
    """`render(backend="gpu")`, or a skip (a failure with
    GAZELIGHT_REQUIRE_GPU=1) when there is no adapter."""
    try:
        return gazelight.render(backend="gpu", **kw)
    except gazelight.GazelightError as e:
        if "no GPU adapter" not in str(e):
            raise
        if os.environ.get("GAZELIGHT_REQUIRE_GPU", "").strip() == "1":
            pytest.fail(f"GAZELIGHT_REQUIRE_GPU=1 but no GPU adapter: {e}")
        pytest.skip(f"no GPU adapter ({e}); set GAZELIGHT_REQUIRE_GPU=1 to make this a failure")


@pytest.mark.parametrize("stereo", [False, True])
def test_gpu_frames_agree_with_the_cpu_frames(stereo):
    kw = dict(DEMO, stereo=stereo)
    if stereo:
        # Both eyes' pipelines and the stereo kernel plan, over the glance.
        kw["frames"] = 5
    gpu = _gpu_render(**kw)
    cpu = gazelight.render(backend="cpu", **kw)
    assert cpu.backend == "cpu" and cpu.backend_reason == 'backend="cpu"'
    assert gpu.backend.startswith("gpu: ") and gpu.backend_reason == 'backend="gpu"', gpu.backend
    print(f"GPU: {gpu.backend}")
    cpu_frames, gpu_frames = list(cpu), list(gpu)
    assert len(cpu_frames) == len(gpu_frames) == kw["frames"]
    worst = 0
    for i, ((fc, rc), (fg, rg)) in enumerate(zip(cpu_frames, gpu_frames)):
        assert fc.shape == fg.shape == (80, 96 * (2 if stereo else 1), 4)
        diff = int(np.abs(fc.astype(np.int16) - fg.astype(np.int16)).max())
        worst = max(worst, diff)
        assert diff <= 1, f"frame {i}: GPU and CPU differ by {diff}/255"
        assert rc.keys() == rg.keys()
        for s in ("_left", "_right") if stereo else ("",):
            for c in EXACT:
                a, b = rc[c + s], rg[c + s]
                assert a == b or (math.isnan(a) and math.isnan(b)), (i, c + s, a, b)
            for c in RELATIVE:
                a, b = rc[c + s], rg[c + s]
                assert abs(a - b) <= 1e-4 * max(abs(a), 1e-12), (i, c + s, a, b)
            a, b = rc["acuity_sigma_px" + s], rg["acuity_sigma_px" + s]
            assert abs(a - b) <= 1e-3 + 1e-4 * abs(a), (i, "acuity_sigma_px" + s, a, b)
    print(f"max frame difference {worst}/255")
    # The frames covered what they are meant to: the lamp glance (the
    # adaptation up by over a decade) and kernel rebuilds after frame 0.
    col = "adaptation_cd_m2" + ("_left" if stereo else "")
    adaptation = [r[col] for _, r in cpu_frames]
    assert max(adaptation) > 10 * min(adaptation), adaptation
    rebuilt = "psf_rebuilt" + ("_left" if stereo else "")
    assert sum(r[rebuilt] for _, r in cpu_frames[1:]) >= 1


def test_retinal_images_agree_on_both_backends():
    """The retinal image (cd/m², read back from the GPU) of the first
    frames: within 1e-3 relative where the CPU's is above 1e-3 of its
    peak (f32 FFTs on both; the display's 1/255 bound is looser)."""
    kw = dict(DEMO, frames=2, retinal=True)
    gpu = _gpu_render(**kw)
    cpu = gazelight.render(backend="cpu", **kw)
    for (rc, _), (rg, _) in zip(cpu, gpu):
        assert rc.shape == rg.shape == (80, 96, 3)
        ok = np.isfinite(rc)
        assert np.array_equal(ok, np.isfinite(rg))
        peak = float(rc[ok].max())
        big = ok & (rc > 1e-3 * peak)
        rel = np.abs(rg[big] - rc[big]) / rc[big]
        assert float(rel.max()) <= 1e-3, float(rel.max())


def test_an_unknown_backend_is_a_value_error():
    with pytest.raises(ValueError, match='unknown backend "metal"'):
        gazelight.render(backend="metal", **DEMO)


def test_the_default_backend_is_the_clis_auto():
    import inspect

    assert inspect.signature(gazelight.render).parameters["backend"].default == "auto"
    # With images=False no pipeline is built: no backend.
    r = gazelight.render(images=False, **DEMO)
    assert r.backend is None and r.backend_reason is None


# Run in a fresh interpreter: the environment that hides the Vulkan driver
# must be there before the process first asks for an adapter.
NO_ADAPTER_SCRIPT = textwrap.dedent(
    """
    import json, numpy as np, gazelight
    out = {}
    try:
        gazelight.render(backend="gpu", size=(96, 80), frames=2)
        out["gpu"] = None
    except gazelight.GazelightError as e:
        out["gpu"] = str(e)
    auto = gazelight.render(backend="auto", size=(96, 80), frames=2)
    cpu = gazelight.render(backend="cpu", size=(96, 80), frames=2)
    out["auto"] = [auto.backend, auto.backend_reason]
    out["frames_equal"] = [bool(np.array_equal(a, c)) for (a, _), (c, _) in zip(auto, cpu)]
    print(json.dumps(out))
    """
)


def test_without_an_adapter_gpu_fails_clearly_and_auto_uses_the_cpu():
    import json

    env = dict(os.environ, **NO_ADAPTER_ENV)
    p = subprocess.run(
        [sys.executable, "-c", NO_ADAPTER_SCRIPT], env=env, capture_output=True, text=True, timeout=300
    )
    assert p.returncode == 0, p.stderr
    out = json.loads(p.stdout.strip().splitlines()[-1])
    gpu = out["gpu"]
    print(f"backend=\"gpu\" without an adapter: {gpu}")
    assert gpu is not None, "backend=\"gpu\" rendered without an adapter"
    # The CLI's sentence, with the choices as Python writes them.
    for needle in ['backend="gpu"', "no GPU adapter", 'backend="cpu"', 'backend="auto"']:
        assert needle in gpu, f"the error lacks {needle!r}: {gpu}"
    assert "--backend" not in gpu, gpu
    backend, reason = out["auto"]
    assert backend == "cpu", out
    assert reason.startswith("auto: no GPU adapter found"), reason
    assert out["frames_equal"] == [True, True], out
