"""
Feature detectors at 80x60 (paper Table 1, Fig. 5), robustness to brightness (Figs. 6-7).

Phase congruency (the ST features: ``M > gamma``, paper section 2.2) at gamma = 0.3, 0.1 and 0.01
against OpenCV's ORB, BRISK, FAST, GFTT / Shi-Tomasi, AGAST, KAZE and SIFT. SURF is patented and
left out of OpenCV's non-free-disabled builds (the PyPI wheels): it is reported as unavailable,
not guessed. The OpenCV detectors take 8-bit images: each frame is contrast-stretched to 8 bits
(1st-99.5th percentile); phase congruency runs on the same 8-bit image so every method sees the
same input. ORB's default 31-pixel patch and edge leave almost nothing of an 80x60 image, so it
runs with a 9-pixel patch and a 5-pixel edge (as the ORB + KNN baseline); every other detector
uses OpenCV's defaults.

Illumination (paper eq. 16): ``g = alpha f + beta`` on the 8-bit image with alpha = 1 and beta =
0..100, clipped to 0..255 as an 8-bit camera would. The re-detection rate is the share of the
beta = 0 features found again within 1 pixel.
"""

import time

import cv2
import numpy as np

from st_stereo.core.config import STConfig
from st_stereo.core.image_io import contrast_stretch_u8, read_thermal_image, resize_area
from st_stereo.core.phase_congruency import feature_strength

PC_GAMMAS = (0.3, 0.1, 0.01)
OPENCV_DETECTORS = ('ORB', 'BRISK', 'FAST', 'GFTT / Shi-Tomasi', 'AGAST', 'KAZE', 'SIFT', 'SURF')
BETAS = tuple(range(0, 101, 10))


def _factory(name):
    """Return an OpenCV detector by name; OpenCV 4 has them in cv2, OpenCV 5 in xfeatures2d."""
    contrib = getattr(cv2, 'xfeatures2d', None)

    def first(*names):
        for module in (cv2, contrib):
            for candidate in names:
                if module is not None and hasattr(module, candidate):
                    return getattr(module, candidate)
        raise RuntimeError(f'{name}: not in this OpenCV build ({cv2.__version__})')
    if name == 'ORB':
        return lambda: first('ORB_create')(nfeatures=500, edgeThreshold=5, patchSize=9)
    if name == 'GFTT / Shi-Tomasi':
        return lambda: first('GFTTDetector_create')(maxCorners=1000, qualityLevel=0.01,
                                                    minDistance=1)
    constructor = {'BRISK': 'BRISK_create', 'FAST': 'FastFeatureDetector_create',
                   'AGAST': 'AgastFeatureDetector_create', 'KAZE': 'KAZE_create',
                   'SIFT': 'SIFT_create', 'SURF': 'SURF_create'}[name]
    if name == 'SURF':
        return lambda: first(constructor)(hessianThreshold=300)
    return lambda: first(constructor)()


def opencv_detector(name):
    """Return an OpenCV detector; a RuntimeError says why one is unavailable (SURF: non-free)."""
    try:
        detector = _factory(name)()
        detector.detect(np.zeros((8, 8), np.uint8))
        return detector
    except cv2.error as error:
        reason = str(error).strip().splitlines()[-1]
        if 'patented' in reason:
            reason = 'patented (non-free), excluded from this build (OPENCV_ENABLE_NONFREE off)'
        raise RuntimeError(f'{name}: unavailable in OpenCV {cv2.__version__}: {reason}') \
            from None


def to_u8(image):
    """Contrast-stretch a thermal frame to 8 bits (1st-99.5th percentile)."""
    return contrast_stretch_u8(image, 1.0, 99.5)


def pc_features(image_u8, gamma, config=None):
    """Phase-congruency feature positions (n, 2) as (x, y): pixels with ``M > gamma``."""
    moments = feature_strength(np.asarray(image_u8, dtype=np.float64), config or STConfig())
    rows, cols = np.nonzero(moments > gamma)
    return np.column_stack([cols, rows]).astype(np.float64)


def detect(method, image_u8, detectors):
    """Feature positions (n, 2) of a method: ``PhaseCong(g)`` or an OpenCV detector name."""
    if method.startswith('PhaseCong('):
        return pc_features(image_u8, float(method[len('PhaseCong('):-1]))
    keypoints = detectors[method].detect(image_u8, None)
    return np.array([k.pt for k in keypoints], dtype=np.float64).reshape(-1, 2)


def methods_and_detectors():
    """All method names, the available OpenCV detectors, and why the others are missing."""
    detectors, missing = {}, {}
    for name in OPENCV_DETECTORS:
        try:
            detectors[name] = opencv_detector(name)
        except RuntimeError as error:
            missing[name] = str(error)
    methods = [f'PhaseCong({g})' for g in PC_GAMMAS] + list(detectors)
    return methods, detectors, missing


def frames_80x60(paths):
    """Read and area-resize frames to 80x60 (raw counts)."""
    return [resize_area(read_thermal_image(path), 80, 60) for path in paths]


def feature_table(images, repeats=100, progress=None):
    """
    Features per image and detection time (mean +- std over ``repeats`` runs) per method.

    Returns ``(rows, missing)``: rows are dicts with method, features (mean over images),
    per-image counts, microseconds mean and std.
    """
    methods, detectors, missing = methods_and_detectors()
    images_u8 = [to_u8(image) for image in images]
    rows = []
    for method in methods:
        counts, times = [], []
        for image in images_u8:
            counts.append(len(detect(method, image, detectors)))
            for _ in range(repeats):
                start = time.perf_counter()
                detect(method, image, detectors)
                times.append((time.perf_counter() - start) * 1e6)
        rows.append({'method': method, 'features': float(np.mean(counts)),
                     'counts': counts, 'us_mean': float(np.mean(times)),
                     'us_std': float(np.std(times))})
        if progress is not None:
            progress()
    return rows, missing


def redetection_rate(reference, found, radius=1.0):
    """Share of reference positions (n, 2) with a found position (m, 2) within ``radius``."""
    if not len(reference):
        return float('nan')
    if not len(found):
        return 0.0
    distance = np.hypot(reference[:, None, 0] - found[None, :, 0],
                        reference[:, None, 1] - found[None, :, 1])
    return float((distance.min(axis=1) <= radius).mean())


def illumination_curves(images, betas=BETAS, methods=None, progress=None):
    """
    Feature count and re-detection rate vs beta (``g = f + beta``, clipped), mean over images.

    Returns ``{method: {'count': [...], 'redetection': [...]}}`` over ``betas``.
    """
    all_methods, detectors, _ = methods_and_detectors()
    methods = methods or ['PhaseCong(0.1)'] + [
        m for m in all_methods if not m.startswith('PhaseCong')]
    curves = {}
    for method in methods:
        counts = np.zeros((len(images), len(betas)))
        rates = np.zeros((len(images), len(betas)))
        for i, image in enumerate(images):
            base = to_u8(image)
            reference = detect(method, base, detectors)
            for j, beta in enumerate(betas):
                shifted = np.clip(base.astype(np.int32) + beta, 0, 255).astype(np.uint8)
                found = detect(method, shifted, detectors)
                counts[i, j] = len(found)
                rates[i, j] = redetection_rate(reference, found)
        curves[method] = {'count': np.nanmean(counts, axis=0).tolist(),
                          'redetection': np.nanmean(rates, axis=0).tolist()}
        if progress is not None:
            progress()
    return curves


def overlay_figure(image, path, scale=4):
    """Fig. 5: the frame and every method's features drawn on it, one panel each."""
    methods, detectors, _ = methods_and_detectors()
    base_u8 = to_u8(image)
    panels = []
    big = cv2.resize(base_u8, None, fx=scale, fy=scale, interpolation=cv2.INTER_NEAREST)
    for method in ['original'] + methods:
        panel = cv2.cvtColor(big, cv2.COLOR_GRAY2BGR)
        label = method
        if method != 'original':
            features = detect(method, base_u8, detectors)
            for x, y in features:
                cv2.circle(panel, (int(x * scale + scale / 2), int(y * scale + scale / 2)),
                           max(1, scale // 3), (0, 0, 255), -1)
            label = f'{method}: {len(features)}'
        cv2.rectangle(panel, (0, 0), (panel.shape[1], 14), (0, 0, 0), -1)
        cv2.putText(panel, label, (2, 11), cv2.FONT_HERSHEY_SIMPLEX, 0.38, (255, 255, 255), 1,
                    cv2.LINE_AA)
        panels.append(panel)
    columns = 4
    while len(panels) % columns:
        panels.append(np.zeros_like(panels[0]))
    grid = np.vstack([np.hstack(panels[i:i + columns]) for i in range(0, len(panels), columns)])
    if not cv2.imwrite(str(path), grid):
        raise ValueError(f'{path}: could not write the figure')


def plot_illumination(curves, path, betas=BETAS):
    """Figs. 6-7: feature count and re-detection rate vs beta."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt
    figure, (left, right) = plt.subplots(1, 2, figsize=(10, 3.8))
    for method, curve in curves.items():
        style = '-' if method.startswith('PhaseCong') else '--'
        left.plot(betas, curve['count'], style, marker='o', markersize=3, label=method)
        right.plot(betas, np.asarray(curve['redetection']) * 100, style, marker='o',
                   markersize=3, label=method)
    left.set_xlabel('brightness change beta (8-bit levels)')
    left.set_ylabel('features per image')
    left.set_yscale('log')
    right.set_xlabel('brightness change beta (8-bit levels)')
    right.set_ylabel('re-detection rate (%)')
    for axis in (left, right):
        axis.grid(alpha=0.3)
    right.legend(fontsize=7, loc='lower left')
    figure.tight_layout()
    figure.savefig(path, dpi=110)
    plt.close(figure)


def feature_markdown(rows, missing, image_names):
    """Table 1 as Markdown."""
    lines = [f'Images: {", ".join(image_names)} (80x60, 8-bit stretched).', '',
             '| method | features per image (mean) | per image | time per image (us) |',
             '|---|---:|---|---:|']
    for row in rows:
        lines.append(f'| {row["method"]} | {row["features"]:.1f} | '
                     f'{", ".join(str(c) for c in row["counts"])} | '
                     f'{row["us_mean"]:.0f} +- {row["us_std"]:.0f} |')
    for name, reason in missing.items():
        lines.append(f'| {name} | not measured | {reason} | |')
    return '\n'.join(lines) + '\n'


def illumination_markdown(curves, betas=BETAS):
    """Figs. 6-7 as a Markdown table (count / re-detection at each beta)."""
    shown = [b for b in betas if b in (0, 20, 40, 60, 80, 100)]
    index = [betas.index(b) for b in shown]
    head = ' | '.join(f'beta {b}' for b in shown)
    lines = [f'| method | {head} |', '|---|' + '---:|' * len(shown)]
    for method, curve in curves.items():
        cells = ' | '.join(f'{curve["count"][i]:.0f} / {curve["redetection"][i] * 100:.0f} %'
                           for i in index)
        lines.append(f'| {method} | {cells} |')
    return '\n'.join(lines) + '\n'
