"""
Scoring published 3-D points against a rendered ground truth, every point, per surface.

What a tracker receives is every point of a cloud, so every point is scored, at every depth and
on every surface, with three criteria:

- **3-D** (the headline): a point is an outlier when it lies farther than 0.3 m from every true
  surface point of its pixel and of the pixel's 8 neighbours. The true surface points of a pixel
  are taken on the ray through its centre at three depths: the centre's, and the nearest and
  farthest its area holds (``fx B / d`` at the ends of its disparity range), so a pixel on a
  depth edge offers both sides but not the air between them. The lateral spread over one pixel
  (Z / fx, 4 cm at 3.4 m) is small next to 0.3 m.
- **strict**: its depth is more than 0.3 m outside the depth range of its own pixel.
- **disparity range**: its disparity (less the principal-point offset) is outside the
  pixel's true disparity range by more than 1 px, and by more than 0.25 px.

A point hidden from the right camera is scored like any other (a tracker receives it too) and
also counted as occluded.
"""

import dataclasses

import numpy as np

OUTLIER_M = 0.3
PERSON_LABEL_BASE = 100


def pixel_rays(model, u, v):
    """Directions ``((u - cx) / fx, (v - cy) / fy, 1)`` of rectified-left pixels, shape (n, 3)."""
    u = np.asarray(u, dtype=np.float64)
    v = np.asarray(v, dtype=np.float64)
    return np.stack(((u - model.cx) / model.fx, (v - model.cy) / model.fy, np.ones_like(u)),
                    axis=-1)


def distance_to_candidates(points, rays, depths):
    """
    Distance of each point to its nearest candidate ``depth * ray``.

    Parameters
    ----------
    points : ndarray, shape (n, 3)
        The points, metres.
    rays : ndarray, shape (n, k, 3)
        k candidate rays per point (direction with z = 1, so the factor is the depth).
    depths : ndarray, shape (n, k, m)
        m candidate depths on each ray (inf: none).

    Returns
    -------
    ndarray, shape (n,): the smallest distance over the k m candidates.

    """
    finite = np.isfinite(depths)
    candidates = np.where(finite, depths, 0.0)[..., None] * rays[:, :, None, :]
    distance = np.linalg.norm(points[:, None, None, :] - candidates, axis=-1)
    return np.where(finite, distance, np.inf).reshape(len(points), -1).min(axis=1)


def surface_distance(model, truth, x_left, y, points):
    """
    3-D distance (m) of each point to the true surface of its pixel and its 8 neighbours.

    ``x_left``, ``y`` are the points' left pixel positions (rounded to the pixel grid). Each
    pixel contributes the points at its centre depth and at the nearest and farthest depths
    its area holds (a pixel on a depth edge holds both sides, not the air between them).
    """
    rows, cols = truth.depth.shape
    fxb = model.fx * model.baseline
    u = np.clip(np.rint(x_left).astype(int), 0, cols - 1)
    v = np.clip(np.rint(y).astype(int), 0, rows - 1)
    offsets = np.array([(du, dv) for dv in (-1, 0, 1) for du in (-1, 0, 1)])
    uu = np.clip(u[:, None] + offsets[None, :, 0], 0, cols - 1)
    vv = np.clip(v[:, None] + offsets[None, :, 1], 0, rows - 1)
    with np.errstate(divide='ignore'):
        depths = np.stack((fxb / truth.disparity_max[vv, uu], truth.depth[vv, uu],
                           fxb / truth.disparity_min[vv, uu]), axis=-1)
    return distance_to_candidates(np.asarray(points, dtype=np.float64),
                                  pixel_rays(model, uu, vv), depths)


def score_points(model, truth, x_left, y, disparity, points):
    """
    Score one cloud's points (see the module docstring).

    Returns
    -------
    dict of ndarray, one entry per point: ``label``, ``distance_3d`` (m), ``strict_error``
    (m), ``disparity_error`` (px), ``z``, ``z_true``, ``occluded``.

    """
    rows, cols = truth.depth.shape
    points = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    u = np.clip(np.rint(x_left).astype(int), 0, cols - 1)
    v = np.clip(np.rint(y).astype(int), 0, rows - 1)
    fxb = model.fx * model.baseline
    z = points[:, 2]
    finite = np.isfinite(z)
    z_safe = np.where(finite, z, 1e9)
    points_safe = np.where(finite[:, None], points, np.array([0.0, 0.0, 1e9]))
    low, high = truth.disparity_min[v, u], truth.disparity_max[v, u]
    with np.errstate(divide='ignore'):
        z_near = fxb / high
        z_far = np.where(low > 0, fxb / np.maximum(low, 1e-12), np.inf)
    own = np.asarray(disparity, dtype=np.float64) - model.disparity_offset
    return {
        'label': truth.labels[v, u].astype(np.int32),
        'distance_3d': surface_distance(model, truth, x_left, y, points_safe),
        'strict_error': np.maximum(np.maximum(z_near - z_safe, z_safe - z_far), 0.0),
        'disparity_error': np.maximum(np.maximum(low - own, own - high), 0.0),
        'z': z_safe,
        'z_true': truth.depth[v, u],
        'occluded': ~truth.visible_right[v, u],
    }


@dataclasses.dataclass
class PointTally:
    """Scores of every point of a sequence's clouds, accumulated frame by frame."""

    frames: int = 0
    columns: dict = dataclasses.field(default_factory=dict)

    def add(self, scores):
        """Add one frame's ``score_points`` result."""
        self.frames += 1
        for key, values in scores.items():
            self.columns.setdefault(key, []).append(values)

    def arrays(self):
        """Return the per-point columns as arrays."""
        keys = ('label', 'distance_3d', 'strict_error', 'disparity_error', 'z', 'z_true',
                'occluded')
        return {key: np.concatenate(self.columns[key]) if self.columns.get(key) else
                np.zeros(0) for key in keys}

    def rows(self, label_names):
        """
        Return one summary per surface: all points, people, then each label.

        Returns
        -------
        list of dict: ``surface``, ``points``, ``outliers_3d``, ``outliers_strict``,
        ``disparity_over_1px``, ``disparity_over_quarter_px`` (fractions),
        ``relative_error_median``, ``relative_error_p90`` (|Z - Z_true| / Z_true, Z_true the
        depth at the pixel centre; NaN points count as infinitely wrong),
        ``correct_per_frame`` (3-D criterion), ``occluded``.

        """
        a = self.arrays()
        label = a['label']
        groups = [('all', np.ones(len(label), dtype=bool)),
                  ('people', label >= PERSON_LABEL_BASE)]
        for value in sorted(set(label.tolist())):
            groups.append((label_names.get(int(value), str(value)), label == value))
        frames = max(self.frames, 1)
        out = []
        for name, mask in groups:
            n = int(mask.sum())
            relative = np.abs(a['z'][mask] - a['z_true'][mask]) / np.maximum(
                a['z_true'][mask], 1e-9)

            def share(values):
                return float(np.mean(values)) if n else float('nan')
            out.append({
                'surface': name, 'points': n,
                'outliers_3d': share(a['distance_3d'][mask] > OUTLIER_M),
                'outliers_strict': share(a['strict_error'][mask] > OUTLIER_M),
                'disparity_over_1px': share(a['disparity_error'][mask] > 1.0),
                'disparity_over_quarter_px': share(a['disparity_error'][mask] > 0.25),
                'relative_error_median': float(np.median(relative)) if n else float('nan'),
                'relative_error_p90': float(np.percentile(relative, 90)) if n else float('nan'),
                'correct_per_frame': int((a['distance_3d'][mask] <= OUTLIER_M).sum()) / frames,
                'occluded': int(a['occluded'][mask].sum()),
            })
        return out


def markdown_surface_table(rows):
    """Return the per-surface rows as a Markdown table."""
    lines = ['| surface | points | outliers 3-D | strict | disparity > 1 px | > 0.25 px | '
             'median abs dZ/Z | p90 abs dZ/Z | correct / frame |',
             '|---|---:|---:|---:|---:|---:|---:|---:|---:|']
    for row in rows:
        lines.append(
            f'| {row["surface"]} | {row["points"]} | {100 * row["outliers_3d"]:.1f} % | '
            f'{100 * row["outliers_strict"]:.1f} % | {100 * row["disparity_over_1px"]:.1f} % | '
            f'{100 * row["disparity_over_quarter_px"]:.1f} % | '
            f'{100 * row["relative_error_median"]:.2f} % | '
            f'{100 * row["relative_error_p90"]:.2f} % | {row["correct_per_frame"]:.1f} |')
    return '\n'.join(lines)


# --- disparity error on moving people, by camera skew and image speed ---------------------------
SPEED_BINS_PX_S = ((0.0, 10.0), (10.0, 25.0), (25.0, np.inf))    # head speed in the image
# Pair skew bins (ms), edges away from the simulated sequences' own skews (-45 .. +40 ms).
SKEW_BINS_MS = ((-60.0, -50.0), (-50.0, -35.0), (-35.0, -25.0), (-25.0, -15.0), (-15.0, -5.0),
                (-5.0, 5.0), (5.0, 15.0), (15.0, 25.0), (25.0, 35.0), (35.0, 50.0), (50.0, 60.0))


def match_pixels(truth, x_left, y):
    """Return the ground-truth pixel (column, row) of each match: rounded, clipped."""
    rows, cols = truth.labels.shape
    return (np.clip(np.rint(x_left).astype(int), 0, cols - 1),
            np.clip(np.rint(y).astype(int), 0, rows - 1))


def people_disparity_errors(model, truth, x_left, y, disparity, head_speeds,
                            with_index=False):
    """
    Signed disparity errors of the matches on people (visible to the right camera).

    Returns ``(error, speed)``: the match's disparity less the principal-point offset minus the
    true disparity at its left pixel (the scene at the left camera's instant), and the image
    speed (px/s) of the person it lies on (``head_speeds[i]`` for label
    ``PERSON_LABEL_BASE + i``). With ``with_index``, also the indices of those matches.
    """
    u, v = match_pixels(truth, x_left, y)
    label = truth.labels[v, u]
    on_person = (label >= PERSON_LABEL_BASE) & truth.visible_right[v, u]
    own = np.asarray(disparity, dtype=np.float64) - model.disparity_offset
    error = own - truth.disparity[v, u]
    speeds = np.abs(np.asarray(head_speeds, dtype=np.float64))
    person = label[on_person] - PERSON_LABEL_BASE
    speed = speeds[person] if len(speeds) else np.zeros(len(person))
    if with_index:
        return error[on_person], speed, np.flatnonzero(on_person)
    return error[on_person], speed


@dataclasses.dataclass
class MotionTally:
    """People's disparity errors with their pair's skew (ms) and their image speed (px/s)."""

    errors: list = dataclasses.field(default_factory=list)
    speeds: list = dataclasses.field(default_factory=list)
    skews: list = dataclasses.field(default_factory=list)

    def add(self, errors, speeds, skew_ms):
        """Add one pair's errors and speeds, taken at skew ``skew_ms``."""
        self.errors.append(np.asarray(errors, dtype=np.float64))
        self.speeds.append(np.asarray(speeds, dtype=np.float64))
        self.skews.append(np.full(len(errors), float(skew_ms)))

    def rows(self):
        """One row per (skew bin, speed bin) holding matches: n, median, median and p90 |e|."""
        if not self.errors:
            return []
        error, speed, skew = (np.concatenate(v) for v in (self.errors, self.speeds, self.skews))
        out = []
        for skew_low, skew_high in SKEW_BINS_MS:
            for low, high in SPEED_BINS_PX_S + ((0.0, np.inf),):
                pick = (skew >= skew_low) & (skew < skew_high) & (speed >= low) & (speed < high)
                if not pick.any():
                    continue
                out.append({'skew_ms': (skew_low, skew_high), 'speed_px_s': (low, high),
                            'matches': int(pick.sum()),
                            'median': float(np.median(error[pick])),
                            'median_abs': float(np.median(np.abs(error[pick]))),
                            'p90_abs': float(np.percentile(np.abs(error[pick]), 90))})
        return out


def markdown_motion_table(rows):
    """Markdown table of ``MotionTally.rows``."""
    lines = ['| pair skew (ms) | head speed (px/s) | matches on people | median error (px) | '
             'median abs (px) | p90 abs (px) |', '|---|---|---:|---:|---:|---:|']
    for row in rows:
        low, high = row['speed_px_s']
        speed = 'all' if (low, high) == (0.0, np.inf) else \
            f'>= {low:.0f}' if high == np.inf else f'{low:.0f}-{high:.0f}'
        lines.append(f'| {row["skew_ms"][0]:+.0f} to {row["skew_ms"][1]:+.0f} | {speed} | '
                     f'{row["matches"]} | {row["median"]:+.3f} | {row["median_abs"]:.3f} | '
                     f'{row["p90_abs"]:.3f} |')
    return '\n'.join(lines)
