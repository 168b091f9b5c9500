"""The coarse stage's reduction factor keeps a usable strip for wide swaths over few lines.

Reduced by its longest side alone, a scene of seed 003's full width (21 800 detectors) over 512
lines becomes 1557 x 36 px and SIFT finds no consistent set there. The realistic demo fixture
(512 x 768 px) with a small ``target_px`` reproduces the case: reduced 7 times (73 x 109 px)
the coarse stage fails, with the shorter side kept at ``MIN_REDUCED_SIDE_PX`` it matches.
"""

from __future__ import annotations


import pytest

import gcpmatch.coarse as coarse
from gcpmatch.coarse import MIN_REDUCED_SIDE_PX, CoarseMatchError, coarse_match, reduction_factor



@pytest.mark.parametrize(
    "shape, target, expected",
    [((512, 21800), 1600, 2),  # the full-width strip: 256 x 10900 px, not 36 x 1557
     ((8192, 21800), 1600, 14),  # the full-size scene: unchanged (longest side rule)
     ((6000, 8192), 1600, 6),  # a usual scene: unchanged
     ((512, 768), 1600, 1),  # the demo: no reduction
     ((200, 30000), 1600, 1),  # fewer lines than the minimum: not reduced at all
     ((512, 768), 120, 2)],  # the demo fixture with a small target (the test below)
)
def test_reduction_factor(shape, target, expected):
    assert reduction_factor(*shape, target) == expected
    small = (shape[0] // expected, shape[1] // expected)
    assert min(small) >= min(MIN_REDUCED_SIDE_PX, min(shape))


def test_a_strip_reduced_by_its_longest_side_fails_and_matches_with_the_minimum_side(realistic_demo_inputs, monkeypatch):
    scene, model, dem, dom, band, _ = realistic_demo_inputs
    result = coarse_match(scene, model, dem, dom, band=band, target_px=120)
    assert result.factor == 2 and result.n_inliers >= 30
    assert result.rms_m < 300.0  # profile realistic, 30 m pixels: within the pre-correction's reach
    monkeypatch.setattr(coarse, "MIN_REDUCED_SIDE_PX", 1)  # the former rule: longest side only
    with pytest.raises(CoarseMatchError):
        coarse_match(scene, model, dem, dom, band=band, target_px=120)
