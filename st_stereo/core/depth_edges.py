"""
Features beside a depth edge that carry the other side's disparity (issue 12).

Phase congruency is contrast-invariant: a weakly textured pixel one or two pixels beside a
strong intensity edge (the floor next to a warm person) is a feature whose Lades window (eq. 9)
and POC window (eqs. 10-11) are both decided by that edge. An occluding edge moves with the
object in front, so such a pixel takes the front object's disparity although its own pixel
sees the background: a point floating in the room. On the bundled recording most floor and desk
matches with more than 1 px of error are such pixels, on the cooler side of a person's
silhouette (docs/results.md).

The check asks the side the pixel sees whether it carries the disparity by itself:

1. The pixel's position across its edge, from the smoothed intensity ``I`` read
   ``SIDE_PROBE_PX`` pixels along and against the intensity gradient ``g``:
   ``position = (I(p) - I(p - 2 g^)) / (I(p + 2 g^) - I(p - 2 g^))``, 0 on the cool side, 1 on
   the warm side (``edge_position``).
2. A feature on the cool side (``position < COOL_SIDE_POSITION``) of an edge stronger than
   ``MIN_EDGE_CONTRAST`` times the image noise is re-measured with a POC window centred
   half a window plus one pixel into its own side (``side_window_centres``: 5 px for W = 9, so
   the window leaves out an edge the feature is a pixel or more away from), started at the
   match's integer disparity. It is rejected when that window fails, peaks lower than
   ``MIN_SIDE_PEAK`` (noise alone peaks anywhere) or finds a disparity more than the
   tolerance (``depth_edge_tolerance``, 1 px) away: a cool object in front of a warm one (its
   side carries the edge's disparity) keeps its features; weakly textured background beside a
   warm person does not. The side windows run on the intensity images whatever
   ``poc_source`` says (the thresholds were measured there).
3. A side that cannot be measured keeps its match, counted in ``depth_edge_unchecked``: its
   right window would not lie wholly in the right image, either window would reach pixels
   without data (the rectified images' invalid border), or the image border pushed the
   centre back towards the edge.

A 9 x 9 window of weak texture cannot always prove its own disparity, and on a pure shift
(the sub-pixel protocol of docs/accuracy.md) the same test rejects correct matches in flat
regions beside edges. The tolerance and the unchecked rule were chosen so that the protocol
stays within 0.5 points of the matcher without the check (panel frame, shifts of 0.25 px: a
0.5 px tolerance that also rejected unmeasurable sides lost 0.83 points, 1 px 0.14); on a
warm box in front of a wall (test_trusted_points.py) 86 % of the wall matches that carried
the box's disparity are then removed, not all. Asking more of the side window (its peak the
highest over the whole disparity range, by a margin) removed more of them there but,
measured on the sequences, dropped 3-6 % of all points, nearly all correct, for 0.1-0.3
points fewer outliers.

The check assumes the nearer object is the warmer one (people in a room). In front of a
warmer background (a person before a radiator or a sunlit wall, a cold object) the background
pixels are on the warm side and keep the foreground's disparity: measured on the box scene
with the box 400 counts cooler, the check removes none of them.

The warm side is not checked: there the feature's own pixel sees the object whose edge it
matched (a person's silhouette seen from the person's side), and a window moved into a
person's body measures its curved surface, up to a pixel off (measured: checking both sides
cost 18 % of the correct points on people for no fewer outliers).
"""

import numpy as np
from scipy import ndimage

EDGE_SMOOTHING_SIGMA = 0.7     # Gaussian sigma (px) before the intensity gradient
SIDE_PROBE_PX = 2.0            # where the two sides' intensities are read
MIN_EDGE_CONTRAST = 5.0        # edge contrast, in units of the image noise (image_noise)
COOL_SIDE_POSITION = 0.25      # position below which a pixel is on the cool side
MIN_SIDE_PEAK = 0.35           # POC peak height (eq. 11) the side's own window must reach


def image_noise(image):
    """Noise scale of an image: median absolute difference of horizontal neighbours."""
    image = np.asarray(image, dtype=np.float64)
    return max(float(np.median(np.abs(np.diff(image, axis=1)))), 1e-6)


def _nearest_pixels(y, x, shape, margin=0):
    rows, cols = shape
    return (np.clip(np.rint(y).astype(int), margin, rows - 1 - margin),
            np.clip(np.rint(x).astype(int), margin, cols - 1 - margin))


def edge_position(image, y, x, sigma=EDGE_SMOOTHING_SIGMA, probe=SIDE_PROBE_PX):
    """
    Where pixels (y, x) lie across their intensity edge, and how strong the edge is.

    Returns
    -------
    position : ndarray (n,)
        ``(I(p) - I_cool) / (I_warm - I_cool)`` with ``I_warm = I(p + probe g^)`` and
        ``I_cool = I(p - probe g^)`` (nearest pixels, ``g^`` the unit gradient of the
        smoothed image at p): 0 = the pixel sees the cool side, 1 = the warm side.
    contrast : ndarray (n,)
        ``(I_warm - I_cool) / image_noise(image)``.
    normal : ndarray (n, 2)
        ``g^`` as (dy, dx), pointing to the warm side (zero where the image is flat).

    """
    smooth = ndimage.gaussian_filter(np.asarray(image, dtype=np.float64), sigma)
    grad_y, grad_x = np.gradient(smooth)
    y = np.asarray(y, dtype=int)
    x = np.asarray(x, dtype=int)
    magnitude = np.hypot(grad_y[y, x], grad_x[y, x])
    scale = np.where(magnitude > 0, 1.0 / np.maximum(magnitude, 1e-300), 0.0)
    normal = np.stack((grad_y[y, x] * scale, grad_x[y, x] * scale), axis=-1)
    warm = smooth[_nearest_pixels(y + probe * normal[:, 0], x + probe * normal[:, 1],
                                  smooth.shape)]
    cool = smooth[_nearest_pixels(y - probe * normal[:, 0], x - probe * normal[:, 1],
                                  smooth.shape)]
    spread = warm - cool
    position = (smooth[y, x] - cool) / np.maximum(spread, 1e-9)
    return position, spread / image_noise(image), normal


def cool_side_features(position, contrast, max_position=COOL_SIDE_POSITION,
                       min_contrast=MIN_EDGE_CONTRAST):
    """Features on the cool side of an edge stronger than ``min_contrast`` noise units."""
    return (np.asarray(position) < max_position) & (np.asarray(contrast) > min_contrast)


def side_window_centres(y, x, normal, shape, half_window):
    """
    Centres of windows moved into the cool side: ``p - (half_window + 1) g^``.

    Rounded to pixels and kept ``half_window`` pixels inside the image. Returns the rows, the
    columns, and whether each centre lies where it was meant to (within a pixel): one pushed
    back by the image border may cover the edge again, so it proves nothing.
    """
    offset = half_window + 1.0
    wanted_y = np.asarray(y) - offset * normal[:, 0]
    wanted_x = np.asarray(x) - offset * normal[:, 1]
    rows, cols = _nearest_pixels(wanted_y, wanted_x, shape, half_window)
    in_place = (np.abs(rows - wanted_y) <= 1.0) & (np.abs(cols - wanted_x) <= 1.0)
    return rows, cols, in_place


def side_agrees(side, disparity, tolerance, min_peak=MIN_SIDE_PEAK):
    """
    Whether each side window (a ``SubpixelResult``) confirms its feature's disparity.

    It must be accepted, peak at least ``min_peak`` high (a window of noise alone peaks
    anywhere, lower) and lie within ``tolerance`` of the feature's disparity.
    """
    return side.accepted & (side.peak_value >= min_peak) & \
        (np.abs(side.disparity - np.asarray(disparity)) <= tolerance)
