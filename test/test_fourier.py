"""Fourier helpers: exact shifts of band-limited signals, the periodic-plus-smooth FFT."""

import numpy as np
import pytest
import scipy.fft as sfft

from st_stereo.core.fourier import fourier_shift_image_x, fourier_shift_rows, periodic_fft2


def test_fourier_shift_of_a_sinusoid_is_accurate_in_the_interior():
    x = np.arange(80)
    image = np.tile(np.sin(2 * np.pi * x / 16.0), (10, 1))
    shifted = fourier_shift_image_x(image, 2.3)
    expected = np.sin(2 * np.pi * (x + 2.3) / 16.0)
    assert np.abs(shifted[:, 20:60] - expected[20:60]).max() < 1e-2


def test_fourier_shift_moves_content_left_for_positive_shift(people_80x60):
    shifted = fourier_shift_image_x(people_80x60, 5.0)
    assert np.allclose(shifted[:, :70], people_80x60[:, 5:75], atol=1e-6 * people_80x60.max())


def test_fourier_shift_never_wraps_the_opposite_border_in():
    image = np.zeros((8, 64))
    image[:, :6] = 100.0           # bright left border
    shifted = fourier_shift_image_x(image, -10.0)   # move right by 10
    assert np.abs(shifted[:, 40:]).max() < 1.0      # nothing bright appears at the right


def test_shift_rows_of_a_linear_ramp_is_exact():
    strips = np.tile(np.arange(21, dtype=float) * 3.0 + 7.0, (2, 9, 1))
    out = fourier_shift_rows(strips, np.array([0.4, -0.7]))
    assert np.allclose(out[0], strips[0] + 1.2)
    assert np.allclose(out[1], strips[1] - 2.1)


def test_no_boundary_jump_means_no_smooth_component():
    y, x = np.mgrid[0:60, 0:80]
    image = np.cos(2 * np.pi * x / 79.0) + np.cos(2 * np.pi * y / 59.0)   # first == last
    assert np.allclose(periodic_fft2(image), sfft.fft2(image), atol=1e-8)


@pytest.mark.parametrize('shape', [(60, 80), (17, 23)])
def test_smooth_component_is_harmonic_inside(shape, rng):
    # Moisan: u = p + s with s harmonic in the interior (its Laplacian lives on the border).
    image = np.cumsum(rng.normal(size=shape), axis=1)
    smooth = image - sfft.ifft2(periodic_fft2(image)).real
    laplacian = (smooth[1:-1, :-2] + smooth[1:-1, 2:] + smooth[:-2, 1:-1] + smooth[2:, 1:-1]
                 - 4.0 * smooth[1:-1, 1:-1])
    assert np.abs(smooth).max() > 0.1
    assert np.abs(laplacian).max() < 1e-9
