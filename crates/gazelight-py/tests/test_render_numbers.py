"""gazelight.render(..., images=False): the rows without the image
pipeline (issue 47, `gazelight_render::analysis`, the CLI's `--no-frames`
path). The image pipeline is the reference: the same render with images
gives every row's values, and the rows without images must equal them
exactly (the same arithmetic in the same order), the stage timings NaN
(no stage ran) instead of the image pipeline's wall-clock times."""

import math

import pytest

import gazelight

TIMINGS = ("pooling_ms", "temporal_ms", "psf_ms", "glare_ms", "acuity_ms", "tone_colour_encode_ms", "total_ms")


def _is_timing(column: str) -> bool:
    return any(column == t or column in (t + "_left", t + "_right") for t in TIMINGS)


def _rows(images: bool, **kw):
    r = gazelight.render(images=images, **kw)
    out = []
    for frame, row in r:
        if images:
            assert frame is not None and frame.ndim == 3
        else:
            assert frame is None
        out.append(row)
    return out


def _same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == b


@pytest.mark.parametrize("stereo", [False, True])
def test_rows_without_images_equal_the_pipelines(data_dir, stereo):
    kw = dict(
        trace_or_recording=data_dir / "eye/neon-demo",
        stereo=stereo,
        size=(96, 104),
        fps=60.0,
        secs=2.0,
    )
    fast, full = _rows(False, **kw), _rows(True, **kw)
    assert len(fast) == len(full) >= 120
    compared = 0
    for i, (a, b) in enumerate(zip(fast, full)):
        assert a.keys() == b.keys()
        for k in a:
            if _is_timing(k):
                assert math.isnan(a[k]), (i, k, a[k])
                assert b[k] >= 0.0, (i, k, b[k])
            else:
                assert _same(a[k], b[k]), (i, k, a[k], b[k])
                compared += 1
    # The light model's columns were among them.
    assert any(k.startswith("pupil_light_mm") for k in fast[0])
    # Per view the 12 timeline columns that are not timings and the two
    # light columns; t_secs and frame once.
    assert compared == len(fast) * ((2 if stereo else 1) * 14 + 2)


def test_images_false_refuses_retinal():
    with pytest.raises(gazelight.GazelightError, match="retinal"):
        gazelight.render(images=False, retinal=True)
