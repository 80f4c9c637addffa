"""
Fourier-domain helpers shared by phase congruency, POC and the evaluation tools.

Everything here is a pure function of numpy arrays. FFTs go through ``scipy.fft`` with
``workers=1`` so the hot path stays single-threaded and deterministic.
"""

import functools

import numpy as np
import scipy.fft as sfft


def frequency_grid(rows, cols):
    """
    Return normalised frequency coordinates of an FFT grid, in FFT (unshifted) order.

    Parameters
    ----------
    rows, cols : int
        Image size.

    Returns
    -------
    radius, u1, u2 : ndarray, shape (rows, cols)
        ``u1`` is the horizontal and ``u2`` the vertical frequency in cycles per pixel, in
        [-0.5, 0.5); ``radius = hypot(u1, u2)`` with ``radius[0, 0]`` set to 1 so it can be
        divided by (Kovesi's ``filtergrid``).

    """
    u1 = sfft.fftfreq(cols)
    u2 = sfft.fftfreq(rows)
    # Kovesi's filtergrid spans [-0.5, 0.5) for even sizes, as fftfreq does; for odd sizes
    # fftfreq gives the exact DFT frequencies.
    u1, u2 = np.meshgrid(u1, u2)
    radius = np.hypot(u1, u2)
    radius[0, 0] = 1.0
    return radius, u1, u2


def butterworth_lowpass(radius, cutoff=0.45, order=15):
    """Butterworth low-pass ``1 / (1 + (radius / cutoff)^(2 order))`` (Kovesi lowpassfilter)."""
    return 1.0 / (1.0 + (radius / cutoff) ** (2 * order))


@functools.lru_cache(maxsize=16)
def _periodic_smooth_denominator(rows, cols):
    cx = 2.0 * np.pi * np.arange(cols) / cols
    cy = 2.0 * np.pi * np.arange(rows) / rows
    denom = 2.0 * (2.0 - np.cos(cx)[None, :] - np.cos(cy)[:, None])
    denom[0, 0] = 1.0
    denom.setflags(write=False)
    return denom


def periodic_fft2(image):
    """
    FFT of the periodic component of an image (Moisan's periodic-plus-smooth split).

    The boundary discontinuities of a non-periodic image leak across the whole spectrum of a
    plain FFT; at 80x60 this changes phase congruency at the borders by up to 0.5. Moisan's
    decomposition ``u = p + s`` removes the smooth component ``s`` whose Laplacian equals the
    boundary jump, leaving a periodic ``p`` with the same content (Kovesi ``perfft2``).

    Parameters
    ----------
    image : ndarray, shape (..., rows, cols)
        Real image(s); leading axes are batched.

    Returns
    -------
    ndarray, complex
        ``fft2`` of the periodic component, same shape as ``image``.

    References
    ----------
    L. Moisan, "Periodic plus smooth image decomposition", J. Math. Imaging Vis. 39 (2011).

    """
    image = np.asarray(image, dtype=np.float64)
    rows, cols = image.shape[-2:]
    boundary = np.zeros_like(image)
    boundary[..., 0, :] = image[..., 0, :] - image[..., -1, :]
    boundary[..., -1, :] = -boundary[..., 0, :]
    boundary[..., :, 0] += image[..., :, 0] - image[..., :, -1]
    boundary[..., :, -1] -= image[..., :, 0] - image[..., :, -1]
    smooth = sfft.fft2(boundary, workers=1) / _periodic_smooth_denominator(rows, cols)
    smooth[..., 0, 0] = 0.0
    return sfft.fft2(image, workers=1) - smooth


def fourier_shift_rows(strips, shifts):
    """
    Shift each strip along its last axis by a real amount, band-limited (Fourier) interpolation.

    A linear ramp that makes every row continuous across the periodic seam is removed first and
    shifted analytically, so the seam does not ring through the strip.

    Parameters
    ----------
    strips : ndarray, shape (n, rows, width)
        Real strips, one per item.
    shifts : ndarray, shape (n,)
        Shift of each strip in pixels; the output satisfies ``out(x) = strip(x + shift)``.

    Returns
    -------
    ndarray, shape (n, rows, width)

    """
    return RowShifter(strips).shift(shifts)


class RowShifter:
    """
    Strips prepared once for many Fourier shifts (see ``fourier_shift_rows``).

    The de-ramped spectrum is computed once; each ``shift`` call costs one inverse FFT.
    ``compiled``: the phase ramp and the ramp's return by numba kernels
    (``st_stereo.core.kernels``, float32 only, the same arithmetic). ``deramped``: the
    strips' ``(periodic, first, slope)`` when already computed (``kernels.deramped_strips``).
    """

    def __init__(self, strips, dtype=np.float64, compiled=False, deramped=None):
        strips = np.asarray(strips, dtype=dtype)
        self.compiled = compiled and strips.dtype == np.float32
        self.width = strips.shape[-1]
        self.x = np.arange(self.width, dtype=dtype)
        if deramped is None:
            self.first = strips[..., :1]
            self.slope = (strips[..., -1:] - self.first) / (self.width - 1)
            periodic = strips - (self.first + self.slope * self.x)
        else:
            periodic, self.first, self.slope = deramped
        self.spectrum = sfft.rfft(periodic, axis=-1, workers=1)
        self.freqs = sfft.rfftfreq(self.width)

    def shift(self, shifts, columns=None):
        """Return ``out(x) = strip(x + shift)``, optionally only the given column slice."""
        shifts = np.asarray(shifts, dtype=self.x.dtype).reshape(-1, 1, 1)
        omega = (2j * np.pi * self.freqs).astype(self.spectrum.dtype)
        if self.compiled:
            import st_stereo.core.kernels as kernels
            phase = kernels.shift_phases(omega.imag, shifts)[:, None, :]
        else:
            phase = np.exp(omega * shifts)
        shifted = sfft.irfft(self.spectrum * phase, n=self.width, axis=-1, workers=1)
        if self.compiled and columns is not None:
            return kernels.reramped_columns(shifted, self.first, self.slope, shifts, columns)
        x = self.x
        if columns is not None:
            shifted, x = shifted[..., columns], x[columns]
        return shifted + self.first + self.slope * (x + shifts)


def fourier_shift_image_x(image, shift, pad=None):
    """
    Translate an image along x by ``shift`` pixels, ``out(x, y) = image(x + shift, y)``.

    The image is padded by edge reflection before the Fourier shift, so nothing wraps around
    into the frame: content that enters at the border comes from the mirrored extension, never
    from the opposite side of the image.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        Real image.
    shift : float
        Positive values move the content to the left (as the right image of a stereo pair).
    pad : int, optional
        Padding on each side; default ``ceil(|shift|) + 16``.

    """
    image = np.asarray(image, dtype=np.float64)
    if pad is None:
        pad = int(np.ceil(abs(shift))) + 16
    padded = np.pad(image, ((0, 0), (pad, pad)), mode='symmetric')
    width = padded.shape[1]
    freqs = sfft.fftfreq(width)
    spectrum = sfft.fft(padded, axis=1, workers=1) * np.exp(2j * np.pi * freqs * shift)
    # Taking the real part treats the Nyquist bin of an even length as cos(pi (x + shift)).
    shifted = sfft.ifft(spectrum, axis=1, workers=1).real
    return shifted[:, pad:pad + image.shape[1]]
