"""
The main job until the node suite exists: ST on a simulated ceiling-rig sequence.

A real thermal frame is the scene texture; each frame places it at a known depth between 3
and 4.5 m (disparity fx B / Z of the default rig), with independent sensor noise and a gain /
offset difference between the two cameras. ST matches every pair and triangulates; the demo
prints one status line per frame and a summary comparing the recovered depth with the truth.
"""

import time

import numpy as np

from st_stereo.core.image_io import read_thermal_image, resize_area
from st_stereo.core.matcher import StereoMatcher
from st_stereo.core.triangulation import StereoModel
from st_stereo.tools.eval_subpixel import make_shifted_pair


def depth_sequence(frames):
    """Return the true depth of each frame: from 3.0 to 4.5 m and back, metres."""
    phase = np.linspace(0.0, 2.0 * np.pi, frames, endpoint=False)
    return 3.75 - 0.75 * np.cos(phase)


def main(args):
    """Run the demo sequence; returns the exit code."""
    from st_stereo.core.config import config_from_assignments
    from st_stereo.package_data import shared_frame

    if args.frames < 1:
        raise ValueError(f'--frames must be at least 1, got {args.frames}')
    path = args.image or shared_frame()
    frame = resize_area(read_thermal_image(path), 80, 60)
    model = StereoModel.default_lepton_rig()
    matcher = StereoMatcher(config_from_assignments(args.set), model)
    rng = np.random.default_rng(0)
    print(f'st-stereo demo: {args.frames} simulated 80x60 pairs textured with {path}; rig fx = '
          f'{model.fx:.1f} px, baseline = {model.baseline:.3f} m')
    errors, totals, match_counts = [], [], []
    for index, depth in enumerate(depth_sequence(args.frames)):
        disparity = float(model.disparity_of_depth(depth))
        left, right = make_shifted_pair(frame, disparity, rng, realistic=True)
        started = time.perf_counter()
        result = matcher.match(left, right)
        totals.append((time.perf_counter() - started) * 1e3)
        match_counts.append(len(result))
        z = result.points[:, 2] if len(result) else np.zeros(0)
        z_median = float(np.median(z)) if len(z) else float('nan')
        errors.append(np.abs(z - depth))
        print(f'frame {index:3d}: true Z {depth:.3f} m, disparity {disparity:6.3f} px | '
              f'{result.counts["features"]:4d} features, {len(result):4d} matches, median Z '
              f'{z_median:.3f} m, {totals[-1]:.1f} ms', flush=True)
    all_errors = np.concatenate(errors) if errors else np.zeros(0)
    print('\nsummary')
    print(f'  pairs: {args.frames}, matches per pair: median {np.median(match_counts):.0f}')
    if len(all_errors):
        print(f'  |Z - Z_true|: median {np.median(all_errors) * 1e3:.1f} mm, p90 '
              f'{np.percentile(all_errors, 90) * 1e3:.1f} mm, points beyond 300 mm: '
              f'{100.0 * np.mean(all_errors > 0.3):.2f} %')
    print(f'  time per pair: median {np.median(totals):.2f} ms, p90 '
          f'{np.percentile(totals, 90):.2f} ms')
    return 0
