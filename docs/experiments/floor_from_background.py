"""
Can the floor of the bundled recording be fitted from stereo? (issue 16, ``st-stereo rig-pose``).

Measures, on the recording's temporal-median rectified pair (the people walk out of it):
how many of ST's points lie on the floor, the floor's texture against the simulator's fixed
pattern noise, and the rig pose from RANSAC planes (in disparity space, where a plane is
affine in the pixel coordinates) on StereoSGBM disparities of contrast-normalised images,
with the floor chosen as the plane facing the image's top (|roll| <= 45, tilt <= 80 deg).
Run: ``.venv/bin/python docs/experiments/floor_from_background.py``.
"""

import math
import warnings

import cv2
import numpy as np
from scipy import ndimage
from st_stereo.core.calibration.files import load_calibration
from st_stereo.core.config import STConfig
from st_stereo.core.matcher import StereoMatcher
from st_stereo.core.people import rectified_to_world, world_from_rectified
from st_stereo.core.rectification import StereoRectifier
from st_stereo.core.rig_pose import load_rig_pose
from st_stereo.package_data import bundled_recording
from st_stereo.sim.recording import load_ground_truth
from st_stereo.tools.eval_points import recording_pairs


def contrast_normalised(image, size=11):
    """Return ``image`` minus its local mean over its local std, as uint8."""
    mean = ndimage.uniform_filter(image, size)
    var = ndimage.uniform_filter(image * image, size) - mean * mean
    out = (image - mean) / np.sqrt(np.maximum(var, 1e-6) + 0.25)
    return np.clip(128 + 40 * out, 0, 255).astype(np.uint8)


def pose_of_disparity_plane(coef, model, rectification):
    """Height, tilt, roll of the plane ``d = a (x - cx) + b (y - cy) + c`` (rig_pose.py)."""
    v = np.array([coef[0], coef[1], coef[2] / model.fx])
    up = np.asarray(rectification).T @ (-v / np.linalg.norm(v))
    tilt = math.degrees(math.acos(max(-1.0, min(1.0, -up[2]))))
    return model.baseline / np.linalg.norm(v), tilt, math.degrees(math.atan2(-up[0], -up[1]))


def floor_plane(disparity, model, rectification, seed, threshold=0.25, tries=3000):
    """RANSAC + least squares of the floor-facing plane with most pixels within threshold."""
    ys, xs = np.nonzero(np.isfinite(disparity))
    a = np.column_stack([xs - model.cx, ys - model.cy, np.ones(len(xs))])
    d = disparity[ys, xs] - model.cx + model.cx_right
    rng, best = np.random.default_rng(seed), None
    for _ in range(tries):
        pick = rng.choice(len(d), 3, replace=False)
        try:
            coef = np.linalg.solve(a[pick], d[pick])
        except np.linalg.LinAlgError:
            continue
        _, tilt, roll = pose_of_disparity_plane(coef, model, rectification)
        inliers = np.abs(a @ coef - d) < threshold
        if tilt <= 80 and abs(roll) <= 45 and (best is None or inliers.sum() > best.sum()):
            best = inliers
    for _ in range(3):
        coef = np.linalg.lstsq(a[best], d[best], rcond=None)[0]
        best = np.abs(a @ coef - d) < threshold
    return coef


def main():
    """Print the measurements."""
    recording = bundled_recording()
    left, right = (load_calibration(recording / f'{s}.yaml') for s in ('left', 'right'))
    rectifier, pose = StereoRectifier(left, right), load_rig_pose(recording / 'rig_pose.yaml')
    model = rectifier.model
    pairs = [rectifier.rectify(l, r) for _, l, r in recording_pairs(recording)]
    median = [np.median([p[k] for p in pairs], axis=0).astype(np.float64) for k in (0, 1)]
    truth = load_ground_truth(recording)
    floor = (truth['labels'] == 0).all(axis=0)
    high_pass = median[0] - ndimage.uniform_filter(median[0], 7)
    print(f'{len(pairs)} pairs; always-floor pixels {floor.sum()}; floor texture of the median '
          f"image (7x7 high-pass std) {high_pass[floor].std():.2f} counts; the simulator's "
          'fixed pattern noise 1.5 (pixel) + 1.0 (column) counts std')
    result = StereoMatcher(STConfig(), model=model).match(
        median[0].astype(np.float32), median[1].astype(np.float32),
        **rectifier.valid_keywords())
    world = rectified_to_world(result.points, world_from_rectified(pose, left.rectification))
    print(f'ST on the median pair: {len(world)} points, {(np.abs(world[:, 2]) < 0.1).sum()} '
          'within 0.1 m of the floor')
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=16, blockSize=7, P1=392,
                                 P2=1568, uniquenessRatio=5, speckleWindowSize=0,
                                 mode=cv2.STEREO_SGBM_MODE_HH)
    disparity = sgbm.compute(*(contrast_normalised(m) for m in median)).astype(np.float64) / 16
    disparity[(median[0] <= 0) | (disparity <= 0.5)] = np.nan
    with warnings.catch_warnings():     # pixels never floor: all-NaN columns
        warnings.simplefilter('ignore', RuntimeWarning)
        true_disparity = np.nanmedian(
            np.where(truth['labels'] == 0, truth['disparity'], np.nan), axis=0)
    error = (disparity - true_disparity)[floor & np.isfinite(disparity)]
    print(f'StereoSGBM on the floor: {error.size} pixels, error median {np.median(error):+.2f} '
          f'px, IQR {np.subtract(*np.percentile(error, [75, 25])):.2f} px')
    print(f'truth: height {pose.height_m} m, tilt {pose.tilt_deg}, roll {pose.roll_deg} deg')
    print('| RANSAC seed | height m | tilt deg | roll deg |\n|---|---|---|---|')
    for seed in range(5):
        height, tilt, roll = pose_of_disparity_plane(
            floor_plane(disparity, model, left.rectification, seed), model, left.rectification)
        print(f'| {seed} | {height:.3f} | {tilt:.2f} | {roll:.2f} |')


if __name__ == '__main__':
    main()
