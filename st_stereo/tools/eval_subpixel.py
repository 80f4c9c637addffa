"""
The paper's sub-pixel accuracy protocol (section 3.4, Figs. 8-10), with the peers beside ST.

A real frame is the left image; the right image is the same frame moved left by Delta
(Fourier shift of a mirror-padded frame, so nothing wraps into the frame), optionally with
independent noise and a gain / offset difference. ST matches the pair; the error of every
left feature is ``estimated disparity - Delta``. A feature counts when its true match lies in
the right frame with its whole window; a feature that is not matched (or rejected at any
stage) is a miss: it stays in the denominator.

Every peer refines the same rough matches from raw-intensity windows of the same size, so the
comparison isolates the sub-pixel estimator; ST's own variants (M windows instead of
intensity, the paper's single fit instead of the recentred one) run the same way, and the
paper's whole configuration (5x5 similarity, M windows, single fit) runs as a full pipeline.
"""

import dataclasses
import json

import numpy as np

from st_stereo.core.config import STConfig
from st_stereo.core.fourier import fourier_shift_image_x
from st_stereo.core.image_io import read_thermal_image, resize_area
from st_stereo.core.matcher import feature_mask, StereoMatcher
from st_stereo.core.subpixel import refine_subpixel_poc
from st_stereo.tools.peers import PEERS

TOLERANCES = (0.5, 0.25, 0.1, 0.05)

# The paper's own configuration, reproduced as a whole pipeline.
PAPER_OVERRIDES = {'similarity_window': 5, 'poc_source': 'moments',
                   'poc_estimator': 'nagashima', 'poc_max_shift': 1.0}

# Sub-pixel variants of ST refined on the same rough matches as the peers.
ST_VARIANTS = {
    'ST_M_recentred': {'poc_source': 'moments', 'poc_estimator': 'recentred'},
    'ST_M_nagashima': {'poc_source': 'moments', 'poc_estimator': 'nagashima'},
    'ST_intensity_nagashima': {'poc_source': 'intensity', 'poc_estimator': 'nagashima'},
}


@dataclasses.dataclass(frozen=True)
class SubpixelProtocol:
    """What to evaluate: one frame, sizes, windows, thresholds, shifts, degradations."""

    image_path: str
    size: tuple = (80, 60)
    windows: tuple = (7, 9, 11, 13)
    gammas: tuple = (0.3, 0.1, 0.01)
    shifts: tuple = tuple(np.arange(0.0, 30.0 + 1e-9, 0.125))
    noise_counts: float = 0.0
    realistic: bool = False
    peers: bool = True
    seed: int = 0


def parse_shifts(text):
    """Parse ``start:stop:step`` (stop included) or a comma list into a tuple of shifts."""
    if ':' in text:
        parts = text.split(':')
        if len(parts) != 3:
            raise ValueError(f'--shifts: expected start:stop:step, got {text!r}')
        start, stop, step = (float(p) for p in parts)
        if step <= 0 or stop < start:
            raise ValueError(f'--shifts: need step > 0 and stop >= start, got {text!r}')
        return tuple(np.arange(start, stop + step * 1e-6, step))
    return tuple(float(v) for v in text.split(','))


def load_frame(path, size):
    """Read a frame and resize it (pixel-area averaging) to ``size = (width, height)``."""
    frame = read_thermal_image(path).astype(np.float64)
    if size is not None and (frame.shape[1], frame.shape[0]) != tuple(size):
        frame = resize_area(frame, *size)
    return frame


def make_shifted_pair(frame, shift, rng, noise_counts=0.0, realistic=False):
    """
    Left = frame, right = frame moved left by ``shift``; optional degradations.

    ``realistic``: independent noise of 1 % of the frame's standard deviation on each image,
    and right = 1.05 x shifted + 2 % of the frame's range, as two uncooled cameras differ.
    ``noise_counts``: additional independent Gaussian noise (standard deviation in counts).
    """
    left = frame.copy()
    right = fourier_shift_image_x(frame, shift)
    sigma = float(noise_counts)
    if realistic:
        right = 1.05 * right + 0.02 * float(np.ptp(frame))
        sigma = float(np.hypot(sigma, 0.01 * frame.std()))
    if sigma > 0:
        left = left + rng.normal(0.0, sigma, left.shape)
        right = right + rng.normal(0.0, sigma, right.shape)
    return left, right


def make_layered_pair(frame, front, front_shift, back_shift, rng, noise_counts=3.0,
                      gain_right=1.03, offset_right=37.0):
    """
    Left = frame, right = its ``front`` pixels moved by ``front_shift``, the rest by another.

    Two depths from one real frame: the ``front`` pixels (bool mask: the warm bodies) move
    left by ``front_shift`` and occlude the background, which moves by ``back_shift``; the
    background the bodies hid in the left image (shown beside them in the right one) is
    filled, row by row, by linear interpolation between the background pixels either side.
    Both images get independent Gaussian noise of ``noise_counts``; the right one the other
    camera's gain and offset. Returns ``(left, right)`` float64.
    """
    frame = np.asarray(frame, dtype=np.float64)
    front = np.asarray(front, dtype=bool)
    if front.shape != frame.shape:
        raise ValueError(f'front: expected the frame shape {frame.shape}, got {front.shape}')
    background = frame.copy()
    columns = np.arange(frame.shape[1])
    for row in range(frame.shape[0]):
        hidden = front[row]
        if hidden.any() and not hidden.all():
            background[row, hidden] = np.interp(columns[hidden], columns[~hidden],
                                                frame[row, ~hidden])
    moved_front = fourier_shift_image_x(front.astype(np.float64), front_shift) > 0.5
    right = np.where(moved_front, fourier_shift_image_x(frame, front_shift),
                     fourier_shift_image_x(background, back_shift))
    right = gain_right * right + offset_right + rng.normal(0.0, noise_counts, frame.shape)
    left = frame + rng.normal(0.0, noise_counts, frame.shape)
    return left, right


def layered_bodies_pair(bodies, wall_disparity, seed=0, shape=(60, 80), margin=40):
    """
    Left and right images of textured bodies over a textured wall, some beyond the left image.

    ``bodies``: ``(first column, last column + 1, rows from the top, counts over the wall,
    disparity)`` in the left image's columns, which may lie outside it (up to ``margin``).
    The right image at column ``x`` shows, of the bodies covering world column ``x + d``, the
    one of largest ``d`` (the nearest), else the wall at ``x + wall_disparity``: a body the
    left camera does not see can show in the right image. The right camera's gain (1.03) and
    offset (+37 counts), 3 counts of noise on both. Returns ``(left, right)`` float64.
    """
    rows, width = shape
    rng = np.random.default_rng(seed)
    world = np.arange(-margin, width + margin, dtype=np.float64)
    wall = 8000.0 + 3.0 * rng.standard_normal((rows, len(world))).cumsum(axis=1)
    texture = rng.normal(0.0, 0.15, (len(bodies), rows, len(world)))
    columns = np.arange(width, dtype=np.float64)

    def render(shift_of):
        image = np.array([np.interp(columns + shift_of(wall_disparity), world, wall[row])
                          for row in range(rows)])
        background, nearest = image.copy(), np.full(shape, -np.inf)
        for k, (first, end, height, counts, disparity) in enumerate(bodies):
            at = columns + shift_of(disparity)
            covered = (at >= first) & (at < end)
            for row in range(min(height, rows)):
                on = covered & (disparity > nearest[row])     # the nearest one shows
                image[row, on] = background[row, on] + counts * (
                    1.0 + np.interp(at[on], world, texture[k, row]))
                nearest[row, on] = disparity
        return image

    left = render(lambda d: 0.0) + rng.normal(0.0, 3.0, shape)
    right = 1.03 * render(lambda d: d) + 37.0 + rng.normal(0.0, 3.0, shape)
    return left, right


def evaluable_features(moments, gamma, window, shift):
    """Left features whose true right match lies in the frame with its whole window."""
    half = window // 2
    features, _ = feature_mask(moments, gamma, half)
    cols = moments.shape[1]
    x_true = np.arange(cols) - shift
    inside = (x_true >= half) & (x_true <= cols - 1 - half)
    return features & inside[None, :]


class Tally:
    """Accumulates errors of one method over all shifts; misses stay in the denominator."""

    def __init__(self):
        self.errors = []
        self.total = 0

    def add(self, errors, total):
        """Add the errors of the features a method estimated, out of ``total`` evaluable."""
        errors = np.asarray(errors, dtype=np.float64)
        self.errors.append(errors[np.isfinite(errors)])
        self.total += int(total)

    def summary(self):
        """Rates within each tolerance (% of evaluable features), RMSD, failures."""
        errors = np.concatenate(self.errors) if self.errors else np.zeros(0)
        total = max(self.total, 1)
        out = {f'within_{tol}': 100.0 * float((np.abs(errors) <= tol).sum()) / total
               for tol in TOLERANCES}
        out['rmsd'] = float(np.sqrt(np.mean(errors ** 2))) if len(errors) else float('nan')
        out['estimates'] = int(len(errors))
        out['failures'] = int(self.total - len(errors))
        out['features'] = int(self.total)
        return out


def _errors_of(x_left, y, estimate, evaluable, shift):
    on = evaluable[y, x_left]
    return estimate[on] - shift


def evaluate_setting(frame, protocol, window, gamma, progress=None):
    """Evaluate every method at one (W, gamma) over all shifts; returns name -> summary."""
    base = STConfig(poc_window=window, gamma=gamma)
    matcher = StereoMatcher(base)
    paper = StereoMatcher(dataclasses.replace(base, **PAPER_OVERRIDES))
    variants = {name: dataclasses.replace(base, **changes)
                for name, changes in ST_VARIANTS.items()}
    tallies = {name: Tally() for name in ['ST', 'ST_paper', *variants,
                                          *(PEERS if protocol.peers else ())]}
    rng = np.random.default_rng(protocol.seed)
    for shift in protocol.shifts:
        left, right = make_shifted_pair(frame, shift, rng, protocol.noise_counts,
                                        protocol.realistic)
        result = matcher.match(left, right)
        evaluable = evaluable_features(result.feature_images[0], gamma, window, shift)
        total = int(evaluable.sum())
        tallies['ST'].add(_errors_of(result.x_left, result.y, result.disparity, evaluable,
                                     shift), total)
        paper_result = paper.match(left, right)
        tallies['ST_paper'].add(_errors_of(paper_result.x_left, paper_result.y,
                                           paper_result.disparity, evaluable, shift), total)
        rough = result.rough
        moments = result.feature_images
        for name, config in variants.items():
            source = moments if config.poc_source == 'moments' else (left, right)
            refined = refine_subpixel_poc(source[0], source[1], rough.y, rough.x_left,
                                          rough.disparity, config)
            ok = refined.accepted
            tallies[name].add(_errors_of(rough.x_left[ok], rough.y[ok],
                                         refined.disparity[ok], evaluable, shift), total)
        if protocol.peers:
            for name, peer in PEERS.items():
                estimate = peer(left, right, rough.y, rough.x_left, rough.disparity, window)
                tallies[name].add(_errors_of(rough.x_left, rough.y, estimate, evaluable,
                                             shift), total)
        if progress is not None:
            progress.update(1)
    return {name: tally.summary() for name, tally in tallies.items()}


def evaluate(protocol, progress_factory=None):
    """Run the protocol over every window and gamma; returns a JSON-ready dict."""
    frame = load_frame(protocol.image_path, protocol.size)
    settings = [(w, g) for w in protocol.windows for g in protocol.gammas]
    progress = None
    if progress_factory is not None:
        progress = progress_factory(total=len(settings) * len(protocol.shifts))
    rows = []
    try:
        for window, gamma in settings:
            methods = evaluate_setting(frame, protocol, window, gamma, progress)
            rows.append({'window': window, 'gamma': gamma, 'methods': methods})
    finally:
        if progress is not None:
            progress.close()
    return {'image': str(protocol.image_path), 'size': list(frame.shape[::-1]),
            'shifts': {'first': protocol.shifts[0], 'last': protocol.shifts[-1],
                       'count': len(protocol.shifts)},
            'noise_counts': protocol.noise_counts, 'realistic': protocol.realistic,
            'tolerances': list(TOLERANCES), 'results': rows}


def write_json(report, path):
    """Write a report as indented JSON."""
    with open(path, 'w', encoding='utf-8') as stream:
        json.dump(report, stream, indent=1)


def markdown_table(report, window=None, gamma=None):
    """One Markdown table: methods as rows, rates / RMSD / failures as columns."""
    rows = [r for r in report['results'] if (window is None or r['window'] == window)
            and (gamma is None or r['gamma'] == gamma)]
    lines = []
    for row in rows:
        lines.append(f'W = {row["window"]}, gamma = {row["gamma"]}, '
                     f'{next(iter(row["methods"].values()))["features"]} evaluable features')
        lines.append('')
        lines.append('| method | <= 0.5 px | <= 0.25 px | <= 0.1 px | <= 0.05 px | RMSD px | '
                     'failures |')
        lines.append('|---|---|---|---|---|---|---|')
        for name, m in row['methods'].items():
            lines.append(f'| {name} | {m["within_0.5"]:.2f} | {m["within_0.25"]:.2f} | '
                         f'{m["within_0.1"]:.2f} | {m["within_0.05"]:.2f} | {m["rmsd"]:.3f} | '
                         f'{m["failures"]} |')
        lines.append('')
    return '\n'.join(lines)


def plot_report(report, path):
    """
    Plot rates vs window size per tolerance, one curve per gamma (paper Figs. 8-9 style).

    The other methods appear as dashed curves at gamma = 0.1 (or the largest gamma).
    """
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    results = report['results']
    windows = sorted({r['window'] for r in results})
    gammas = sorted({r['gamma'] for r in results}, reverse=True)
    figure, axes = plt.subplots(2, 2, figsize=(11, 8), sharex=True)
    for axis, tol in zip(axes.ravel(), TOLERANCES):
        key = f'within_{tol}'
        for gamma in gammas:
            values = [next(r for r in results if r['window'] == w and r['gamma'] == gamma)
                      ['methods']['ST'][key] for w in windows]
            axis.plot(windows, values, marker='o', label=f'ST, gamma={gamma}')
        first = gammas[0] if 0.1 not in gammas else 0.1
        methods = next(r for r in results if r['gamma'] == first)['methods']
        for name in methods:
            if name == 'ST':
                continue
            values = [next(r for r in results if r['window'] == w and r['gamma'] == first)
                      ['methods'][name][key] for w in windows]
            axis.plot(windows, values, linestyle='--', marker='.', label=f'{name} ({first})')
        axis.set_title(f'error <= {tol} px')
        axis.set_ylabel('% of features')
        axis.grid(True, alpha=0.3)
    for axis in axes[-1]:
        axis.set_xlabel('window size W (pixels)')
    handles, labels = axes[0, 0].get_legend_handles_labels()
    figure.legend(handles, labels, loc='lower center', ncol=3, fontsize=8)
    variant = 'realistic' if report['realistic'] else 'noise-free'
    figure.suptitle(f'Sub-pixel matching rate, {report["image"].split("/")[-1]} '
                    f'{report["size"][0]}x{report["size"][1]}, {variant}')
    figure.tight_layout(rect=(0, 0.12, 1, 0.96))
    figure.savefig(path, dpi=110)
    plt.close(figure)
