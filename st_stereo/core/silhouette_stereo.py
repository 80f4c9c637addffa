"""
Depth of a warm silhouette as a whole: far bodies the feature matcher starves (no ROS).

A person 4.3 m and more from a ceiling rig at 80x60 rises out of the image's top edge; its
few phase-congruency features lie on its outline and in the top rows, where no matching
window fits, and in a warm room the body is only 1-4 K warmer than the wall behind it:
0-12 matches per pair (docs/people.md). The thermal image still shows its silhouette, and
both cameras see the same silhouette against the same wall: its disparity is that of the
whole shape, found by correlating the silhouette's pixels (and a ring of background around
them, which carries its outline) with the right image along the rows.

1. ``top_runs``: per column, how many rows a mask holds from the top row down.
2. ``top_silhouettes``: the shapes rising out of the top edge: 8-connected regions of a
   lower warm margin that hold a pixel of the warm mask (hysteresis, as Canny's edges),
   their columns warm for at least ``min_rows`` from the top row, split where a column's
   run is shorter than ``split`` times the tallest one's (a body standing in front of a warm
   radiator or panel reaching the top row too: the body's columns run far longer).
3. ``silhouette_disparity``: zero-mean normalised cross-correlation (ZNCC) of the
   silhouette dilated by ``ring_px`` with the right image shifted by each integer disparity,
   then by shifts ``REFINE_STEP_PX`` apart around the best one (the right image interpolated
   along the row), refined by a parabola through the finest best's neighbours;
   ``right_to_left_agrees`` searches the shape found in the right image back in the left.
   ZNCC, not a sum of absolute differences: the two cameras' offsets and gains differ (each
   its own flat-field correction) and the silhouette is faint.
"""

import numpy as np
from scipy import ndimage

EIGHT_CONNECTED = np.ones((3, 3), dtype=bool)
MIN_INSIDE_FRACTION = 0.8   # of the silhouette's pixels (with ring) inside the right image
REFINE_STEP_PX = 0.1        # the fractional shifts tried around the best integer one


def top_runs(mask):
    """Per column, the number of rows of ``mask`` (bool, rows x cols) True from row 0 down."""
    mask = np.asarray(mask, dtype=bool)
    cool = ~mask
    first_cool = np.where(cool.any(axis=0), cool.argmax(axis=0), mask.shape[0])
    return first_cool.astype(int)


def _split_columns(columns, runs, split):
    """
    Split adjacent ``columns`` into groups around their tallest runs (``top_silhouettes``).

    The tallest column's neighbours whose run is at least ``split`` times its own make a
    group; what is left of the columns is split again the same way.
    """
    groups, todo = [], [np.asarray(columns, dtype=int)]
    while todo:
        columns = todo.pop()
        if not len(columns):
            continue
        # Adjacent stretches of the columns, each split on its own.
        stretches = np.split(columns, np.flatnonzero(np.diff(columns) > 1) + 1)
        for stretch in stretches:
            peak = int(np.argmax(runs[stretch]))
            tall = runs[stretch] >= split * runs[stretch[peak]]
            low = high = peak
            while low > 0 and tall[low - 1]:
                low -= 1
            while high < len(stretch) - 1 and tall[high + 1]:
                high += 1
            groups.append(stretch[low:high + 1])
            todo.extend(part for part in (stretch[:low], stretch[high + 1:]) if len(part))
    return sorted(groups, key=lambda group: int(group[0]))


def top_silhouettes(weak, strong, min_rows=3, split=0.5, min_columns=2):
    """
    Return the silhouettes rising out of the image's top edge, as bool masks.

    ``weak``: pixels warmer than the background by the lower margin; ``strong``: the warm
    mask (higher margin). A silhouette is one group of columns (``_split_columns``) of an
    8-connected region of ``weak`` that holds a ``strong`` pixel, each column's pixels from
    row 0 down to its first cool one, where that run is at least ``min_rows`` long. A group
    narrower than ``min_columns`` is left out: a one-column sliver split off a wide warm
    thing (a radiator cut into pieces by a person in front of it) matches anywhere.
    """
    weak = np.asarray(weak, dtype=bool)
    strong = np.asarray(strong, dtype=bool) & weak
    labels, _ = ndimage.label(weak, structure=EIGHT_CONNECTED)
    seeded = np.unique(labels[strong])
    seeded = seeded[seeded > 0]
    silhouettes = []
    for label in np.unique(labels[0]):
        if label == 0 or label not in seeded:
            continue
        region = labels == label
        runs = top_runs(region)
        columns = np.flatnonzero(runs >= min_rows)
        for group in _split_columns(columns, runs, split):
            if len(group) < min_columns:
                continue
            mask = np.zeros(weak.shape, dtype=bool)
            for column in group:
                mask[:runs[column], column] = True
            silhouettes.append(mask)
    return silhouettes


def silhouette_disparity(left, right, mask, low, high, ring_px=2, valid_right=None,
                         exclude=None):
    """
    Disparity of a silhouette: ``(disparity, correlation)``, or ``(nan, nan)``.

    The pixels of ``mask`` dilated by ``ring_px`` in the rectified ``left`` image are
    correlated (ZNCC) with the pixels ``d`` columns to their left in ``right`` for every
    integer ``d`` in ``low..high`` (the disparity bounds, px; negative ones too, with a
    negative ``cx_left - cx_right``) whose shift keeps at least ``MIN_INSIDE_FRACTION`` of
    them inside the right image (and on its ``valid_right`` pixels, the ones with data); the
    best one is refined on shifts ``REFINE_STEP_PX`` apart within half a pixel of it and by
    the parabola through the finest best's neighbours' ``1 - ZNCC``. The ring leaves out the
    pixels of ``exclude`` (bool, the left image's shape): another warm thing beside the
    silhouette, at its own depth, would decide the correlation. ``correlation`` is the best
    ZNCC (-1..1). NaN when no shift is usable, the best lies on a bound or next to a shift
    not usable (the true one may lie beyond: a shape cut by the image's side, searched back)
    or the region is flat.
    """
    left = np.asarray(left, dtype=np.float64)
    right = np.asarray(right, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    region = ndimage.binary_dilation(mask, structure=EIGHT_CONNECTED, iterations=ring_px) \
        if ring_px > 0 else mask
    if exclude is not None:
        region &= mask | ~np.asarray(exclude, dtype=bool)
    region &= np.isfinite(left)
    rows, cols = np.nonzero(region)
    low, high = int(np.floor(low)), int(np.ceil(high))
    if not len(rows) or high < low:
        return float('nan'), float('nan')
    values = left[rows, cols]
    costs = _zncc_costs(values, rows, cols, right, np.arange(low, high + 1), valid_right)
    best = int(np.argmin(costs))
    if not np.isfinite(costs[best]) or best == 0 or best == len(costs) - 1 or \
            not np.isfinite(costs[best - 1]) or not np.isfinite(costs[best + 1]):
        return float('nan'), float('nan')
    # Pixel-locking: a parabola through integer shifts pulls towards them; the shifts within
    # half a pixel of the best, REFINE_STEP_PX apart (the right image interpolated linearly),
    # and the parabola through the finest best's neighbours.
    steps = low + best + np.arange(-0.5, 0.5 + 1e-9, REFINE_STEP_PX)
    fine = _zncc_costs(values, rows, cols, right, steps, valid_right)
    at = int(np.argmin(fine))
    if not np.isfinite(fine[at]):
        return float('nan'), float('nan')
    offset = 0.0
    if 0 < at < len(fine) - 1 and np.isfinite(fine[at - 1]) and np.isfinite(fine[at + 1]):
        curvature = fine[at - 1] - 2.0 * fine[at] + fine[at + 1]
        if curvature > 0:
            offset = 0.5 * (fine[at - 1] - fine[at + 1]) / curvature * REFINE_STEP_PX
    return float(steps[at]) + float(np.clip(offset, -REFINE_STEP_PX, REFINE_STEP_PX)), \
        1.0 - float(fine[at])


def _zncc_costs(values, rows, cols, right, shifts, valid_right):
    """
    Return ``1 - ZNCC`` of the left pixels with the right image, one per shift.

    ``values`` at ``(rows, cols)`` against ``right`` each of ``shifts`` columns to the left,
    all at once (pixels x shifts). A fractional shift interpolates the right image linearly
    along the row. Infinite where fewer than ``MIN_INSIDE_FRACTION`` of the pixels land
    inside the right image (on its ``valid_right`` pixels) or either side is flat.
    """
    shifts = np.asarray(shifts, dtype=np.float64)
    position = cols[:, None] - shifts[None, :]
    first = np.floor(position).astype(int)
    weight = position - first
    second = np.where(weight > 0, first + 1, first)
    inside = (first >= 0) & (second < right.shape[1])
    first_at, second_at = np.where(inside, first, 0), np.where(inside, second, 0)
    row_at = np.broadcast_to(rows[:, None], first.shape)
    if valid_right is not None:
        inside &= valid_right[row_at, first_at] & valid_right[row_at, second_at]
    b = (1.0 - weight) * right[row_at, first_at] + weight * right[row_at, second_at]
    a = np.broadcast_to(values[:, None], b.shape)
    inside &= np.isfinite(b)
    a, b = np.where(inside, a, 0.0), np.where(inside, b, 0.0)
    count = inside.sum(axis=0)
    usable = count >= MIN_INSIDE_FRACTION * len(rows)
    count = np.maximum(count, 1)
    a = np.where(inside, a - (a * inside).sum(axis=0) / count, 0.0)
    b = np.where(inside, b - (b * inside).sum(axis=0) / count, 0.0)
    norm = np.sqrt((a * a).sum(axis=0) * (b * b).sum(axis=0))
    with np.errstate(invalid='ignore', divide='ignore'):
        costs = 1.0 - (a * b).sum(axis=0) / norm
    return np.where(usable & (norm > 0), costs, np.inf)


def _shifted_left(mask, shift):
    """Return ``mask`` moved ``shift`` columns to the left (right when negative), False in."""
    moved = np.zeros_like(mask)
    width = mask.shape[1]
    if shift >= 0:
        moved[:, :width - shift] = mask[:, shift:]
    else:
        moved[:, -shift:] = mask[:, :width + shift]
    return moved


def right_to_left_agrees(left, right, mask, disparity, low, high, tolerance_px=1.0,
                         ring_px=2, valid_left=None, exclude=None):
    """
    Whether the silhouette found in the right image, searched back in the left, comes home.

    The left-right check of a match, for a whole silhouette: ``mask`` shifted ``disparity``
    columns to the left (rounded) is what the right image holds of it; that shape, searched
    in the left image (``silhouette_disparity`` with the images swapped and the shift
    reversed), must find ``disparity`` again within ``tolerance_px``. A far body's sliver
    beside a nearer body is hidden by it in the right image (the nearer one shifts more): its
    pixels there are the nearer body's, whose disparity the search back finds. False when the
    search back finds none. ``exclude`` (left image) is shifted with the mask.
    """
    shift = int(round(disparity))
    mask = np.asarray(mask, dtype=bool)
    if abs(shift) >= mask.shape[1]:
        return False
    moved = _shifted_left(mask, shift)
    if exclude is not None:
        exclude = _shifted_left(np.asarray(exclude, dtype=bool), shift)[:, ::-1]
    # Mirror both images so a shift to the right becomes one to the left.
    back, _ = silhouette_disparity(np.asarray(right)[:, ::-1], np.asarray(left)[:, ::-1],
                                   moved[:, ::-1], low, high, ring_px,
                                   None if valid_left is None else valid_left[:, ::-1],
                                   exclude)
    return bool(abs(back - disparity) <= tolerance_px)
