"""``smooth_field`` by strips of rows and columns of the half spectrum equals the 2-D transforms, to the bit.

The field (:func:`sensor_models.simulate.radiometry.smooth_field`) is ``irfft2(rfft2(noise) *
filt)``, normalised; it is computed one axis at a time by strips so that no whole noise, product
or inverse array is held beside the spectrum. Checked against the 2-D formula on random shapes
(1 to 600 rows and columns, odd and even), scales (0.5 to 50 pixels) and strip sizes down to one
value, and its peak traced memory against the formula's.
"""

from __future__ import annotations

import tracemalloc

import numpy as np
import pytest

from sensor_models.simulate import radiometry
from sensor_models.simulate.radiometry import smooth_field


def _two_d(shape, scale_px, seed_seq):
    """The field by whole-array 2-D transforms (its defining formula)."""
    noise = np.random.default_rng(seed_seq).standard_normal(shape)
    k = np.hypot(np.fft.fftfreq(shape[0])[:, None], np.fft.rfftfreq(shape[1])[None, :]) * 2.0 * np.pi
    filt = np.exp(-0.5 * (k * scale_px) ** 2) + 0.15 / (1.0 + (k * scale_px) ** 2)
    field = np.fft.irfft2(np.fft.rfft2(noise) * filt, s=shape)
    field -= field.mean()
    field /= max(field.std(), 1e-12)
    return field.astype(np.float32)


@pytest.mark.parametrize("seed", range(8))
def test_smooth_field_by_strips_is_the_two_d_transform(monkeypatch, seed):
    rng = np.random.default_rng([seed, 5])
    shape = (int(rng.integers(1, 600)), int(rng.integers(1, 600)))
    scale = float(np.exp(rng.uniform(np.log(0.5), np.log(50.0))))
    expected = _two_d(shape, scale, np.random.SeedSequence([seed, 6]))
    for strip in (1 << 20, int(rng.integers(1, 2000)), 1):
        monkeypatch.setattr(radiometry, "_FFT_STRIP_VALUES", strip)
        np.testing.assert_array_equal(smooth_field(shape, scale, np.random.SeedSequence([seed, 6])), expected)


def test_smooth_field_holds_less_than_the_two_d_transform(monkeypatch):
    # strips of 2^16 values (1 MiB): small beside the 1.8 M pixel field, as 2^20 is beside a large field
    monkeypatch.setattr(radiometry, "_FFT_STRIP_VALUES", 1 << 16)

    def peak(f):
        tracemalloc.start()
        f((1200, 1500), 4.0, np.random.SeedSequence(3))
        out = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
        return out

    n = 1200 * 1500
    assert peak(smooth_field) < 20 * n < peak(_two_d)  # bytes a field pixel: about 16 against about 40
