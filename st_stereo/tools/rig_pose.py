"""
``st-stereo rig-pose``: the rig's height, tilt and roll from pairs of a target lying on the floor.

Lay a heated planar target (warm discs on a mat, a heated chessboard) flat on the floor where
both cameras see it, record a few seconds of raw pairs (a rosbag2, two raw captures or image
files, as for ``st-stereo calibrate``), and run this with the stereo calibration. Each pair
gives the target's pose (``st_stereo.core.floor_pose``); the median over the pairs is written
as a rig pose YAML (``config/rig_pose.yaml``'s fields) that the launch files' transforms and
the people node read. The position in the room and the yaw are copied from ``--base`` (the
floor does not give them).
"""

import bisect
import dataclasses
import pathlib

import cv2
import numpy as np

from st_stereo.core.calibration.files import CalibrationError, check_stereo_pair, \
    load_calibration
from st_stereo.core.calibration.targets import CalibrationTarget, find_target, \
    MIN_SPACING_PX, REJECTIONS
from st_stereo.core.floor_pose import check_distortion_model, combine_views, floor_view, \
    FloorPoseError, MIN_TILT_FOR_ROLL_DEG
from st_stereo.core.rig_pose import load_rig_pose, POSE_FIELDS, rig_pose_yaml, RigPose
from st_stereo.tools.calibrate import bag_frames, BAG_NAMESPACE_HELP, input_pairs


# The target's size as the baseline measures it may differ from its description by this
# fraction (median over the views): on the simulator 0.1-0.3 % with the right spacing (true
# or fitted calibration); a spacing 2 % off showed as 1.9 % and a height 1.6 cm off, 3 % as
# 2.9 % and 2.5 cm.
MAX_SCALE_ERROR = 0.015
# Beyond this reprojection error (median over the views, pixels) the points do not fit one
# planar target seen by both cameras: 0.02-0.04 px on the simulator, 0.17 px with detection
# noise of 0.12 px per axis.
MAX_STEREO_RMS_PX = 0.5


class RigPoseInputError(ValueError):
    """Input from which ``rig-pose`` cannot work (names the file, field or problem)."""


@dataclasses.dataclass
class FloorTargetViews:
    """Every pair's view of the floor target, and what was not found and why."""

    target: CalibrationTarget
    left: object                # CameraCalibration
    right: object
    thickness_m: float = 0.0
    views: list = dataclasses.field(default_factory=list)
    pairs: int = 0
    seen: dict = dataclasses.field(default_factory=lambda: {'both': 0, 'left only': 0,
                                                            'right only': 0, 'neither': 0})
    rejected: dict = dataclasses.field(default_factory=lambda: {
        side: dict.fromkeys(REJECTIONS, 0) for side in ('left', 'right')})
    pose_failures: list = dataclasses.field(default_factory=list)   # (pair, reason)

    def add(self, name, left_image, right_image):
        """Find the target in one raw pair and keep the floor it gives."""
        self.pairs += 1
        found = []
        for side, image, calibration in (('left', left_image, self.left),
                                         ('right', right_image, self.right)):
            image = np.asarray(image)
            if image.shape != (calibration.height, calibration.width):
                raise RigPoseInputError(
                    f'{name}: the {side} image is {image.shape[1]}x{image.shape[0]} but its '
                    f'calibration is for {calibration.width}x{calibration.height}')
            detection, reason = find_target(image, self.target, reseed=True)
            if reason:
                self.rejected[side][reason] += 1
            found.append(None if detection is None else detection.points)
        key = {(True, True): 'both', (True, False): 'left only', (False, True): 'right only',
               (False, False): 'neither'}[(found[0] is not None, found[1] is not None)]
        self.seen[key] += 1
        if key != 'neither':
            try:
                self.views.append(floor_view(name, self.target, found[0], found[1],
                                             self.left, self.right, self.thickness_m))
            except (FloorPoseError, cv2.error) as error:
                self.pose_failures.append((name, str(error).strip().splitlines()[-1]))

    def why_none(self):
        """Explain why no pair gave a view (the most frequent rejection, with a hint)."""
        counts = {reason: sum(self.rejected[side][reason] for side in self.rejected)
                  for reason in REJECTIONS}
        reason = max(counts, key=counts.get)
        hints = {
            'not found': 'check that the whole grid is in view and the rows / cols given',
            'too small': f'its points lie closer than {MIN_SPACING_PX[self.target.kind]} px in '
                         'the image: use a larger spacing, or lay it nearer the rig',
            'fit failed': 'its points could not be located (too blurred or too faint?)',
            'not planar': 'the grid was found only partly or misordered',
        }
        return f'{reason} in {counts[reason]} images: {hints[reason]}'


def nearest_stamp_pairs(path, max_delta_s, counts, namespace=''):
    """
    Pairs of a rosbag2's raw images: each left image with the nearest right one in time.

    The scene is static, so the two free-running cameras' images need not share a stamp
    (other recorders stamp each camera apart); a left image without a right one within
    ``max_delta_s`` is counted in ``counts['unpaired_left']``, right images never used in
    ``counts['unused_right']``.
    """
    frames = bag_frames(path, namespace)
    rights = sorted(frames['right'])
    used = set()
    for stamp in sorted(frames['left']):
        index = bisect.bisect_left(rights, stamp)
        near = [rights[i] for i in (index - 1, index) if 0 <= i < len(rights)]
        best = min(near, key=lambda r: abs(r - stamp)) if near else None
        if best is None or abs(best - stamp) > max_delta_s * 1e9:
            counts['unpaired_left'] += 1
            continue
        used.add(best)
        yield f'{pathlib.Path(path).name}@{stamp}', frames['left'][stamp], frames['right'][best]
    counts['unused_right'] = len(rights) - len(used)
    counts['images'] = (len(frames['left']), len(rights))


def pose_yaml(pose, floor, base_source):
    """Return the rig pose YAML: ``config/rig_pose.yaml``'s fields, with their sources."""
    def span(field, unit):
        low, high = floor.spread[field]
        return f'{low:.4f} to {high:.4f} {unit} over the views (5th-95th percentile)'
    header = ['# The rig pose (st_stereo/core/rig_pose.py): height, tilt and roll fitted by',
              f'# st-stereo rig-pose from {floor.views} views of a target on the floor; world '
              'and', f'# rig frames, position and yaw from {base_source}.']
    if not floor.roll_determined:
        header.append(f'# Nearly straight down (tilt < {MIN_TILT_FOR_ROLL_DEG} deg) the roll is '
                      'poorly determined (straight down it is the yaw).')
    return rig_pose_yaml(pose, header, {'height_m': span('height_m', 'm'),
                                        'tilt_deg': span('tilt_deg', 'deg'),
                                        'roll_deg': span('roll_deg', 'deg')})


def chosen_views(views):
    """
    Return the views the pose is taken from: those of both cameras when there are any.

    With both cameras the target's distance rests on the baseline as well as on its size; a
    one-camera view at 3-4 m measured 5 cm and 1 deg off on the simulator (docs/people.md).
    """
    stereo = [v for v in views.views if v.stereo]
    return stereo or list(views.views)


def stereo_rms(views):
    """Median over the views of both cameras of the larger reprojection rms (None: none)."""
    rms = [max(v.rms_left_px, v.rms_right_px) for v in views if v.stereo]
    return float(np.median(rms)) if rms else None


def stereo_scale(views):
    """Median over the views of both cameras of the target's measured / described size."""
    scales = [v.scale for v in views if v.stereo]
    return float(np.median(scales)) if scales else None


def estimate(views, base, max_stereo_rms_px=MAX_STEREO_RMS_PX, max_scale_error=MAX_SCALE_ERROR,
             allow_one_camera=False):
    """
    Return ``(RigPose, FloorPose)``: ``base`` with the fitted height, tilt and roll.

    Refused (RigPoseInputError): views of both cameras that reproject more than
    ``max_stereo_rms_px`` off, or in which the baseline measures the target more than
    ``max_scale_error`` larger or smaller than described (a wrong ``--spacing``, or a
    calibration of another rig); views of one camera only unless ``allow_one_camera``.
    """
    chosen = chosen_views(views)
    rms, scale = stereo_rms(chosen), stereo_scale(chosen)
    if rms is not None and rms > max_stereo_rms_px:
        raise RigPoseInputError(
            f'the target reprojects {rms:.2f} px off in the two cameras (limit '
            f'{max_stereo_rms_px} px): its points do not fit one planar grid seen by both '
            'cameras (a wrong --target, --rows or --cols, or a calibration not of this rig)')
    if scale is not None and abs(scale - 1.0) > max_scale_error:
        raise RigPoseInputError(
            f"the cameras' baseline measures the target {abs(scale - 1.0) * 100:.1f} % "
            f'{"larger" if scale > 1 else "smaller"} than --spacing {views.target.spacing_m} m '
            f'says (limit {max_scale_error * 100:g} %): check the spacing (about '
            f'{views.target.spacing_m * scale:.4f} m by the cameras) and that the calibration '
            "is this rig's; the height would be about that fraction off")
    if rms is None and not allow_one_camera:
        raise RigPoseInputError(
            'no pair showed the whole target to both cameras: with one camera the height '
            "rests on the target's size alone (on the simulator 5 cm and 1 deg off); place it "
            'where both cameras see all of it, or pass --allow-one-camera')
    floor = combine_views(chosen)
    # Rounded far below the accuracy (millimetres, hundredths of a degree): a readable file.
    return dataclasses.replace(base, height_m=round(floor.height_m, 4),
                               tilt_deg=round(floor.tilt_deg, 3),
                               roll_deg=round(floor.roll_deg, 3)), floor


def report_text(views, pose, floor):
    """Return the report printed after the fit."""
    rms = {side: [getattr(v, f'rms_{side}_px') for v in views.views
                  if getattr(v, f'rms_{side}_px') is not None] for side in ('left', 'right')}
    lines = [f'pairs: {views.pairs}; target seen by both cameras in {views.seen["both"]}, the '
             f'left only in {views.seen["left only"]}, the right only in '
             f'{views.seen["right only"]}, neither in {views.seen["neither"]}']
    for side in ('left', 'right'):
        rejected = ', '.join(f'{reason} {count}' for reason, count in
                             views.rejected[side].items() if count)
        if rejected:
            lines.append(f'{side} images without the target: {rejected}')
        if rms[side]:
            lines.append(f'{side} reprojection rms (px): median {np.median(rms[side]):.3f}, max '
                         f'{max(rms[side]):.3f}')
    for name, reason in views.pose_failures:
        lines.append(f'{name}: no pose: {reason}')
    scale = stereo_scale(chosen_views(views))
    if scale is not None:
        lines.append(f"the target's size by the baseline / as described: {scale:.4f}")
    lines.append('| field | value | 5th-95th percentile over the views |')
    lines.append('|---|---:|---|')
    for field, unit in (('height_m', 'm'), ('tilt_deg', 'deg'), ('roll_deg', 'deg')):
        low, high = floor.spread[field]
        lines.append(f'| {field} | {getattr(pose, field):.4f} | {low:.4f} - {high:.4f} {unit} |')
    if floor.views < len(views.views):
        lines.append(f'used the {floor.views} views of both cameras; the '
                     f'{len(views.views) - floor.views} views of one camera only were left out')
    elif not views.seen['both']:
        lines.append('warning: no pair showed the target to both cameras: the height rests on '
                     "the target's size alone (on the simulator such views were up to 5 cm and "
                     '1 deg off)')
    if not floor.roll_determined:
        lines.append(f'tilt below {MIN_TILT_FOR_ROLL_DEG} deg: the roll is poorly determined '
                     '(looking straight down it is the yaw); the measured value is written')
    return '\n'.join(lines)


def calibrations(args):
    """Return the CameraCalibrations named by ``--calibration`` or ``--left/--right``."""
    if args.calibration and (args.left or args.right):
        raise RigPoseInputError('give --calibration DIR or --left FILE --right FILE, not both')
    if args.calibration:
        paths = [pathlib.Path(args.calibration) / f'{side}.yaml' for side in ('left', 'right')]
    elif args.left and args.right:
        paths = [pathlib.Path(args.left), pathlib.Path(args.right)]
    else:
        raise RigPoseInputError('the stereo calibration is needed: --calibration DIR (with '
                                'left.yaml and right.yaml) or --left FILE --right FILE')
    try:
        left, right = (load_calibration(path) for path in paths)
        check_stereo_pair(left, right, str(paths[0]), str(paths[1]))
        for calibration, path in zip((left, right), paths):
            check_distortion_model(calibration, str(path))
    except (CalibrationError, FloorPoseError, OSError) as error:
        raise RigPoseInputError(str(error)) from None
    return left, right


def main(args):
    """Run ``st-stereo rig-pose``."""
    from tqdm import tqdm
    target = CalibrationTarget(args.target, args.rows, args.cols, args.spacing)
    bag_counts = {'unpaired_left': 0, 'unused_right': 0, 'images': (0, 0)}
    pairs = input_pairs(args, lambda bag, namespace: nearest_stamp_pairs(
        bag, args.max_pair_delta, bag_counts, namespace))
    for name, value in (('--max-rms', args.max_rms), ('--max-scale-error', args.max_scale_error),
                        ('--max-pair-delta', args.max_pair_delta)):
        if not value > 0:
            raise RigPoseInputError(f'{name}: expected a positive number, got {value}')
    if not args.thickness >= 0:
        raise RigPoseInputError(f'--thickness: expected the target surface height above the '
                                f'floor (>= 0 m), got {args.thickness}')
    left, right = calibrations(args)
    base = load_rig_pose(args.base) if args.base else RigPose()
    if base.tilt_deg < 0:
        # The fit gives tilt >= 0 with the yaw along the direction the camera looks; a base
        # written with a negative tilt has its yaw the other way round.
        raise RigPoseInputError(
            f'{args.base}: tilt_deg {base.tilt_deg} is negative: rig-pose writes the tilt as '
            '>= 0 with yaw_deg the heading the camera looks towards; give the base that way '
            f'(yaw_deg {(base.yaw_deg + 180.0) % 360.0:g} and a positive tilt)')
    base_source = args.base or 'the defaults (x 0, y 0, yaw 0)'
    views = FloorTargetViews(target, left, right, args.thickness)
    with tqdm(desc='finding the target', unit='pair', disable=args.quiet) as bar:
        for name, left_image, right_image in pairs:
            views.add(name, left_image, right_image)
            bar.update(1)
    if args.bag:
        left_count, right_count = bag_counts['images']
        if bag_counts['unpaired_left'] or bag_counts['unused_right']:
            print(f'{args.bag}: {left_count} left and {right_count} right images; '
                  f'{bag_counts["unpaired_left"]} left images had no right one within '
                  f'{args.max_pair_delta} s, {bag_counts["unused_right"]} right images were '
                  'not used')
    if views.pairs == 0:
        raise RigPoseInputError('no pairs in the input' + (
            f' ({left_count} left and {right_count} right images, none within '
            f'{args.max_pair_delta} s of each other)' if args.bag else ''))
    if not views.views:
        raise RigPoseInputError(f'the target was not found in any of {views.pairs} pairs: '
                                f'{views.why_none()}')
    try:
        pose, floor = estimate(views, base, args.max_rms, args.max_scale_error,
                               args.allow_one_camera)
    except FloorPoseError as error:
        raise RigPoseInputError(str(error)) from None
    print(report_text(views, pose, floor))
    out = pathlib.Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(pose_yaml(pose, floor, base_source))
    written = load_rig_pose(out)        # what the launch files and the people node will read
    print(f'wrote {out}: ' + ', '.join(f'{field} {getattr(written, field)}'
                                       for field in POSE_FIELDS))
    return 0


def add_parser(sub):
    """Add ``rig-pose`` to the ``st-stereo`` parser."""
    p = sub.add_parser('rig-pose', help="the rig's height, tilt and roll from pairs of a target "
                       'lying on the floor')
    p.add_argument('--images', help='directory of pairs (left*/right* or left/ and right/)')
    p.add_argument('--bag', help='rosbag2 with */left/image_raw and */right/image_raw')
    p.add_argument('--bag-namespace', default='', help=BAG_NAMESPACE_HELP)
    p.add_argument('--capture', nargs=2, metavar=('LEFT', 'RIGHT'),
                   help='two raw Lepton captures')
    p.add_argument('--calibration', help='directory with the stereo calibration (left.yaml, '
                   'right.yaml, as st-stereo calibrate writes it)')
    p.add_argument('--left', help='left camera calibration YAML (instead of --calibration)')
    p.add_argument('--right', help='right camera calibration YAML (instead of --calibration)')
    p.add_argument('--target', required=True, choices=('circles', 'acircles', 'chessboard'),
                   help='circles: symmetric grid; acircles: asymmetric grid; chessboard')
    p.add_argument('--rows', type=int, required=True,
                   help='rows of circles, or of inner corners for a chessboard')
    p.add_argument('--cols', type=int, required=True,
                   help='circles per row, or inner corners per row for a chessboard')
    p.add_argument('--spacing', type=float, required=True,
                   help='square side, or distance between circle centres in a row, metres')
    p.add_argument('--thickness', type=float, default=0.0,
                   help="the target's surface above the floor, metres (default 0)")
    p.add_argument('--base', help='rig pose YAML whose frames, position and yaw are kept '
                   '(default: x 0, y 0, yaw 0, frames map / stereo_rig)')
    p.add_argument('--max-rms', type=float, default=MAX_STEREO_RMS_PX,
                   help='refuse when the views of both cameras reproject farther off than '
                   f'this, pixels (default {MAX_STEREO_RMS_PX})')
    p.add_argument('--max-scale-error', type=float, default=MAX_SCALE_ERROR,
                   help="refuse when the baseline measures the target's size this fraction "
                   f'away from --spacing (default {MAX_SCALE_ERROR})')
    p.add_argument('--allow-one-camera', action='store_true',
                   help='use views of one camera when no pair shows the target to both '
                   '(the height then rests on the target size alone: cm, not mm)')
    p.add_argument('--max-pair-delta', type=float, default=0.06,
                   help='--bag: pair each left image with the nearest right one within this '
                   'many seconds (default 0.06; the scene is static)')
    p.add_argument('--out', required=True, help='rig pose YAML to write')
    p.add_argument('--quiet', action='store_true', help='no progress bar')
    p.set_defaults(handler=main)
