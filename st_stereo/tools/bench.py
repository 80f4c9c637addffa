"""
Speed benchmark: ST per stage vs OpenCV StereoSGBM and ORB + BFMatcher KNN, one table.

Single-threaded: OMP / OpenBLAS / MKL threads = 1 (the process re-executes itself with them
set if needed), ``cv2.setNumThreads(1)``, and every FFT of the core runs with ``workers=1``.
Pairs are a real frame resized (pixel-area) to each size and shifted by the rig's disparity
at 3.35 m, with the realistic noise / gain / offset difference.
"""

import dataclasses
import os
import subprocess
import sys
import time

import numpy as np

THREAD_VARIABLES = ('OMP_NUM_THREADS', 'OPENBLAS_NUM_THREADS', 'MKL_NUM_THREADS')


def _ensure_single_thread():
    if all(os.environ.get(name) == '1' for name in THREAD_VARIABLES):
        return None
    env = dict(os.environ, **dict.fromkeys(THREAD_VARIABLES, '1'))
    return subprocess.run([sys.executable, '-m', 'st_stereo', *sys.argv[1:]],
                          env=env).returncode


def rig_shift(width):
    """Disparity of the rig at 3.35 m (fx B / Z), scaled with the image width, pixels."""
    return 13.82 * width / 80.0


def make_pair(frame, width, height, seed=0):
    """Make a realistic synthetic pair of the given size from a frame (module docstring)."""
    from st_stereo.core.image_io import resize_area
    from st_stereo.tools.eval_subpixel import make_shifted_pair

    image = resize_area(frame, width, height)
    return make_shifted_pair(image, rig_shift(width), np.random.default_rng(seed),
                             realistic=True)


def config_for_width(base, width):
    """
    Return the config a user would run at this width: search +-20 % around the rig's disparity.

    (The default 0..40 px range is for 80x60; a dense range 0..320 at 640x512 would not fit.)
    """
    if width <= 80:
        return base
    shift = rig_shift(width)
    return dataclasses.replace(base, disparity_min=int(0.8 * shift),
                               disparity_max=int(np.ceil(1.2 * shift)))


def to_u8(image):
    """8-bit contrast-stretched copy, as SGBM and ORB require."""
    from st_stereo.core.image_io import contrast_stretch_u8
    return contrast_stretch_u8(image)


def time_sgbm(left, right, width):
    """Milliseconds of one StereoSGBM disparity map (8-bit conversion included)."""
    import cv2
    max_disparity = int(np.ceil(width / 2 / 16.0)) * 16
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=max_disparity, blockSize=5)
    start = time.perf_counter()
    sgbm.compute(to_u8(left), to_u8(right))
    return (time.perf_counter() - start) * 1e3


def time_orb_knn(left, right):
    """Milliseconds of ORB detection on both images + BFMatcher KNN (k = 2) + ratio test."""
    import cv2
    orb = cv2.ORB_create(nfeatures=500, edgeThreshold=5, patchSize=9)
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING)
    start = time.perf_counter()
    _, left_desc = orb.detectAndCompute(to_u8(left), None)
    _, right_desc = orb.detectAndCompute(to_u8(right), None)
    if left_desc is not None and right_desc is not None and len(right_desc) >= 2:
        pairs = matcher.knnMatch(left_desc, right_desc, k=2)
        [m for m in pairs if len(m) == 2 and m[0].distance < 0.75 * m[1].distance]
    return (time.perf_counter() - start) * 1e3


def _stats(values):
    values = np.asarray(values)
    return float(np.median(values)), float(np.percentile(values, 90))


def benchmark_size(matchers, frame, width, height, pairs, progress):
    """
    Per-stage ST timings of each matcher and the peers' timings over ``pairs`` pairs.

    ``matchers``: ``{name: StereoMatcher}`` (the implementations), timed in turn on every
    pair so that a machine's drift during the run affects them alike. Returns
    ``{name: row}``; the peers' timings are the same in every row.
    """
    from st_stereo.core.fourier import fourier_shift_image_x
    from st_stereo.core.matcher import StereoMatcher
    from st_stereo.core.skew import compensation_options, SkewCompensator
    matchers = {name: StereoMatcher(config_for_width(matcher.config, width))
                for name, matcher in matchers.items()}
    left, right = make_pair(frame, width, height)
    for matcher in matchers.values():
        matcher.match(left, right)   # warm the filter-bank caches
    stages = {name: {} for name in matchers}
    matches = {name: [] for name in matchers}
    sgbm, orb = [], []
    # The camera skew correction of a moving scene (both cameras' previous frames 2 px away,
    # the right one exposing 30 ms after the left: every feature moves, the worst case), as
    # the matcher node calls it: its own row, not part of ST's total.
    previous_left = fourier_shift_image_x(left, 2.0)
    previous_right = fourier_shift_image_x(right, 2.0)
    for _ in range(pairs):
        for name, matcher in matchers.items():
            result = matcher.match(left, right)
            for key, value in result.timings_ms.items():
                stages[name].setdefault(key, []).append(value)
            compensator = SkewCompensator()
            compensator.remember(previous_left, 0.0, previous_right, 0.03)
            tick = time.perf_counter()
            compensator.correct(result, left, 1.0 / 8.7, 0.03, right=right,
                                **compensation_options(matcher.config))
            stages[name].setdefault('skew compensation (not in total)', []).append(
                1e3 * (time.perf_counter() - tick))
            matches[name].append(len(result))
            progress.update(1)
        sgbm.append(time_sgbm(left, right, width))
        orb.append(time_orb_knn(left, right))
    return {name: {'stages': {k: _stats(v) for k, v in stages[name].items()},
                   'sgbm': _stats(sgbm), 'orb_knn': _stats(orb),
                   'matches': float(np.median(matches[name])), 'pairs': pairs}
            for name in matchers}


def memory_run(matcher, frame, pairs, progress):
    """RSS (MiB) after a warm-up and after ``pairs`` pairs at 80x60: flat means no leak."""
    import psutil
    process = psutil.Process()
    left, right = make_pair(frame, 80, 60)
    warmup = min(500, pairs // 10)
    for _ in range(warmup):
        matcher.match(left, right)
        progress.update(1)
    start = process.memory_info().rss / 2 ** 20
    for _ in range(pairs - warmup):
        matcher.match(left, right)
        progress.update(1)
    end = process.memory_info().rss / 2 ** 20
    return start, end


def print_table(rows):
    """
    Print the benchmark tables (Markdown).

    ``rows``: ``{size: {implementation: row}}``; the stage table has one column pair per
    implementation (numpy, the reference, and compiled) measured in the same run.
    """
    implementations = list(next(iter(rows.values())))
    header = ' | '.join(f'{name} median ms | {name} p90 ms' for name in implementations)
    ratio = len(implementations) > 1
    print(f'| size | stage | {header} |' + (' numpy / compiled |' if ratio else ''))
    print('|---|---|' + '---|' * (2 * len(implementations) + ratio))
    for size, by_implementation in rows.items():
        stages = by_implementation[implementations[0]]['stages']
        for stage in stages:
            cells = []
            for name in implementations:
                median, p90 = by_implementation[name]['stages'][stage]
                cells += [f'{median:.2f}', f'{p90:.2f}']
            line = f'| {size} | {stage} | ' + ' | '.join(cells) + ' |'
            if ratio:
                compiled = by_implementation['compiled']['stages'][stage][0]
                numpy_ms = by_implementation['numpy']['stages'][stage][0]
                line += f' {numpy_ms / compiled:.2f} |' if compiled > 0 else ' - |'
            print(line)
    print()
    print('| size | implementation | pairs | ST total median ms | StereoSGBM median ms | '
          'ORB+KNN median ms | ST / SGBM | ST / ORB+KNN | ST matches |')
    print('|---|---|---|---|---|---|---|---|---|')
    for size, by_implementation in rows.items():
        for name, row in by_implementation.items():
            total = row['stages']['total'][0]
            print(f'| {size} | {name} | {row.get("pairs", "")} | {total:.2f} | '
                  f'{row["sgbm"][0]:.2f} | {row["orb_knn"][0]:.2f} | '
                  f'{total / row["sgbm"][0]:.2f} | {total / row["orb_knn"][0]:.2f} | '
                  f'{row["matches"]:.0f} |')


def main(args):
    """Run the benchmark described by the parsed ``st-stereo bench`` arguments."""
    code = _ensure_single_thread()
    if code is not None:
        return code
    import cv2
    from tqdm import tqdm

    from st_stereo.core.config import config_from_assignments
    from st_stereo.core.image_io import read_thermal_image
    from st_stereo.core.kernels import numba_available, warm_up
    from st_stereo.core.matcher import StereoMatcher
    from st_stereo.package_data import shared_frame

    cv2.setNumThreads(1)
    frame = read_thermal_image(args.image or shared_frame()).astype(np.float64)
    matcher = StereoMatcher(config_from_assignments(args.set))
    sizes = []
    for text in args.sizes.split(','):
        width, _, height = text.partition('x')
        sizes.append((int(width), int(height)))
    # Fewer pairs at large sizes (same order of total time per size).
    counts = [max(5, int(args.pairs * min(1.0, 4800.0 * 4 / (w * h)))) for w, h in sizes]
    # Both implementations side by side, unless --set kernels=... chose one.
    chosen = any(assignment.split('=', 1)[0].strip() == 'kernels'
                 for assignment in args.set or [])
    implementations = [matcher.config.kernels] if chosen else \
        ['numpy'] + (['compiled'] if numba_available() else [])
    if not chosen and len(implementations) == 1:
        print('kernels: numpy only (numba is not importable)')
    elif not chosen:
        print(f'kernels: numpy (the reference) and compiled (numba {numba_available()})')
    print(f'compiled kernels warm-up (compile or cache load): {warm_up():.2f} s')
    rows = {}
    with tqdm(total=sum(counts) * len(implementations), desc='timing',
              unit='pair') as progress:
        matchers = {name: StereoMatcher(dataclasses.replace(matcher.config, kernels=name))
                    for name in implementations}
        for (width, height), count in zip(sizes, counts):
            rows[f'{width}x{height}'] = benchmark_size(matchers, frame, width, height, count,
                                                       progress)
    print_table(rows)
    if args.memory_pairs:
        with tqdm(total=args.memory_pairs, desc='memory', unit='pair') as progress:
            start, end = memory_run(matcher, frame, args.memory_pairs, progress)
        print(f'\nmemory over {args.memory_pairs} pairs at 80x60: RSS {start:.1f} MiB after '
              f'warm-up, {end:.1f} MiB at the end ({end - start:+.1f} MiB)')
    return 0
