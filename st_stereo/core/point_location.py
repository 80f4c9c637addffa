"""
Where a match's 3-D point belongs: at the image structure its window aligned, not at its centre.

ST measures a feature's disparity with a ``W x W`` Hann-weighted POC window centred on the
feature's pixel (paper section 2.4, eq. 6). On an 80x60 image a 9-pixel window spans a whole
person, so a feature one or two pixels off a strong edge (a floor pixel beside a warm person, a
person's pixel inside their own silhouette) carries the edge's disparity: the structure that
carries the window's horizontal contrast decides the shift. ``point_location: structure``
places the point at the centroid of ``w^2 gx^2`` over the window (``w`` the POC's Hann window,
``gx`` the horizontal gradient) and triangulates it there (eq. 1 with ``u, v`` the centroid);
the disparity is untouched. The weighting is the one a windowed least-squares shift
(Lucas-Kanade) gives each pixel's local shift; POC whitens the spectrum, so for it this is an
approximation, chosen by measurement among five weightings (docs/results.md section 5), not
derived.
"""

import numpy as np

from st_stereo.core.subpixel import extract_windows, half_sample_hann


def horizontal_gradient(image):
    """Central difference ``(I[x+1] - I[x-1]) / 2`` along the rows, edges replicated."""
    image = np.asarray(image, dtype=np.float64)
    padded = np.pad(image, ((0, 0), (1, 1)), mode='edge')
    return 0.5 * (padded[:, 2:] - padded[:, :-2])


def structure_offsets(image, y, x, window):
    """
    Offset of each window's horizontal structure from its centre pixel, pixels.

    Parameters
    ----------
    image : ndarray, shape (rows, cols)
        The left rectified image the windows were taken from.
    y, x : ndarray of int, shape (n,)
        Window centres; the whole ``window x window`` square must lie inside the image.
    window : int
        Odd window size (the POC window, ``poc_window``).

    Returns
    -------
    (dx, dy) : ndarray, shape (n,) each
        The centroid of ``hann^2 * gx^2`` over each window, relative to its centre, where
        ``hann`` is the POC's half-sample Hann window and ``gx`` the horizontal gradient. A
        window without horizontal contrast keeps its centre (0, 0).

    """
    y = np.asarray(y, dtype=np.int64)
    x = np.asarray(x, dtype=np.int64)
    if len(y) == 0:
        return np.zeros(0), np.zeros(0)
    half = window // 2
    rows, cols = np.shape(image)
    if (y.min() < half or x.min() < half or y.max() >= rows - half
            or x.max() >= cols - half):
        raise ValueError(f'structure_offsets: a {window}x{window} window leaves the '
                         f'{cols}x{rows} image')
    gradient = extract_windows(horizontal_gradient(image), y, x, window)
    weight = half_sample_hann(window) ** 2 * gradient ** 2
    total = weight.sum(axis=(1, 2))
    offsets = np.arange(window) - half
    with np.errstate(invalid='ignore', divide='ignore'):
        dx = (weight * offsets[None, None, :]).sum(axis=(1, 2)) / total
        dy = (weight * offsets[None, :, None]).sum(axis=(1, 2)) / total
    flat = ~(total > 0)
    dx[flat] = 0.0
    dy[flat] = 0.0
    return dx, dy
