"""
``st-stereo calibrate``: recorded pairs of a heated target -> left.yaml / right.yaml + a report.

Pairs come from a directory of images (``left*.png`` / ``right*.png`` in it, or ``left/`` and
``right/`` subdirectories, paired in sorted order), from two raw Lepton captures (paired by
stamp), or from a rosbag2 (the raw image topics ending in ``left/image_raw`` and
``right/image_raw``, paired by identical stamps; read with ``rosbags``, no ROS needed). The
target is described on the command line. Detection, calibration and the distortion model are
explained in ``st_stereo.core.calibration.targets`` and ``st_stereo.core.calibration.stereo``.
"""

import dataclasses
import json
import pathlib
import sys

import cv2
import numpy as np

from st_stereo.bag_streams import raw_image_messages
from st_stereo.core.calibration.files import save_calibration
from st_stereo.core.calibration.stereo import calibrate_stereo, coverage, OUTLIER_VIEW_FACTOR
from st_stereo.core.calibration.targets import (CalibrationInputError, CalibrationTarget,
                                                find_target, REJECTIONS, stereo_numbering,
                                                to_u8)
from st_stereo.core.image_io import COUNT_ENCODINGS, image_from_buffer, read_thermal_image
from st_stereo.core.rectification import StereoRectifier

IMAGE_SUFFIXES = ('.png', '.tif', '.tiff', '.pgm')
MIN_COVERED_CELLS = 0.5


def pairs_from_directory(directory):
    """Image pairs of a directory: left*/right* files, or left/ and right/ subdirectories."""
    directory = pathlib.Path(directory)
    if not directory.is_dir():
        raise CalibrationInputError(f'{directory}: no such directory')

    def images(folder, prefix=''):
        return sorted(p for p in folder.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES
                      and p.name.lower().startswith(prefix))
    if (directory / 'left').is_dir() and (directory / 'right').is_dir():
        left, right = images(directory / 'left'), images(directory / 'right')
    else:
        left, right = images(directory, 'left'), images(directory, 'right')
    if not left and not right:
        raise CalibrationInputError(f'{directory}: no pairs (expected left*.png and right*.png, '
                                    'or left/ and right/ subdirectories)')
    if len(left) != len(right):
        raise CalibrationInputError(f'{directory}: {len(left)} left images but {len(right)} '
                                    'right images')
    for a, b in zip(left, right):
        yield str(a), read_thermal_image(a), read_thermal_image(b)


BAG_NAMESPACE_HELP = ('a bag of several rigs: the namespace of the image pair to read, e.g. '
                      '/rig2/stereo (default: the bag must hold one)')


def bag_frames(path, namespace='', notes=None):
    """Every raw left and right image of a rosbag2: ``{side: {stamp_ns: pixels}}``."""
    frames = {'left': {}, 'right': {}}
    try:
        for side, stamp, msg in raw_image_messages(path, namespace=namespace, notes=notes):
            if msg.encoding not in COUNT_ENCODINGS + ('mono8',):
                raise CalibrationInputError(f'{path}: {side}/image_raw: encoding '
                                            f'{msg.encoding!r}, expected mono16, 16UC1 or '
                                            f'mono8')
            try:
                pixels = image_from_buffer(msg.data, msg.encoding, msg.width, msg.height,
                                           msg.step, msg.is_bigendian)
            except ValueError as error:
                raise CalibrationInputError(f'{path}: {side}/image_raw: {error}') from None
            frames[side][stamp] = pixels.copy()
    except FileNotFoundError as error:
        raise CalibrationInputError(str(error)) from None
    return frames


def pairs_from_bag(path, namespace=''):
    """Pairs of a rosbag2's raw image topics with identical stamps (none: an error says why)."""
    notes = []
    frames = bag_frames(path, namespace, notes)
    for note in notes:                  # a recording that did not end: read as far as it goes
        print(f'calibrate: {note}', file=sys.stderr)
    stamps = sorted(set(frames['left']) & set(frames['right']))
    if not stamps and frames['left'] and frames['right']:
        raise CalibrationInputError(
            f'{path}: {len(frames["left"])} left and {len(frames["right"])} right images but '
            'no two with the same stamp (the driver stamps both images of a pair alike)')
    for stamp in stamps:
        yield f'{pathlib.Path(path).name}@{stamp}', frames['left'][stamp], frames['right'][stamp]


def pairs_from_captures(left_path, right_path, max_delta=0.05):
    """Pairs of two raw Lepton captures, matched by stamp (``PairSynchronizer``)."""
    from st_stereo.lepton.capture import decode_capture
    from st_stereo.lepton.pairing import PairSynchronizer
    streams = [decode_capture(left_path)[0], decode_capture(right_path)[0]]
    sync = PairSynchronizer(max_delta=max_delta)
    pairs = []
    merged = sorted([(f.stamp, side, f) for side, frames in zip(('left', 'right'), streams)
                     for f in frames], key=lambda item: item[0])
    for _, side, frame in merged:
        pairs.extend(sync.push(side, frame))
    for pair in pairs:
        yield f'capture@{pair.stamp:.3f}', pair.left.pixels, pair.right.pixels


def input_pairs(args, bag_pairs=pairs_from_bag):
    """
    Return the pairs of the one input given: ``--images``, ``--bag`` or ``--capture``.

    ``bag_pairs``: how a bag's images are paired (default: identical stamps). Pairs are read
    as they are iterated.
    """
    sources = [s for s in (args.images, args.bag, args.capture) if s]
    if len(sources) != 1:
        raise CalibrationInputError('give exactly one input: --images DIR, --bag BAG or '
                                    '--capture LEFT RIGHT')
    if args.images:
        return pairs_from_directory(args.images)
    if args.bag:
        return bag_pairs(args.bag, args.bag_namespace)
    return pairs_from_captures(*args.capture)


class Collector:
    """Detections of every pair, with counts of what was rejected and why."""

    def __init__(self, target):
        self.target = target
        self.size = None
        self.names, self.left, self.right = [], [], []
        self.left_only, self.right_only = [], []
        self.counts = {'pairs': 0, 'both': 0, 'left_only': 0, 'right_only': 0, 'neither': 0}
        self.rejected = {side: dict.fromkeys(REJECTIONS, 0) for side in ('left', 'right')}
        self.example = None

    def add(self, name, left, right):
        """Detect the target in one pair; return the left and right Detection (or None)."""
        left, right = np.asarray(left), np.asarray(right)
        if left.shape != right.shape:
            raise CalibrationInputError(f'{name}: left is {left.shape[1]}x{left.shape[0]} but '
                                        f'right is {right.shape[1]}x{right.shape[0]}')
        size = (left.shape[1], left.shape[0])
        if self.size is None:
            self.size = size
        elif size != self.size:
            raise CalibrationInputError(f'{name}: images are {size[0]}x{size[1]}, earlier ones '
                                        f'{self.size[0]}x{self.size[1]}')
        self.counts['pairs'] += 1
        found = []
        for side, image in (('left', left), ('right', right)):
            detection, reason = find_target(image, self.target)
            if reason:
                self.rejected[side][reason] += 1
            found.append(detection)
        if found[0] and found[1]:
            found[1] = dataclasses.replace(found[1], points=stereo_numbering(
                self.target, found[0].points, found[1].points))
            self.counts['both'] += 1
            self.names.append(name)
            self.left.append(found[0].points)
            self.right.append(found[1].points)
            if self.example is None:
                self.example = (left, right, found[0].points, found[1].points)
        elif found[0]:
            self.counts['left_only'] += 1
            self.left_only.append(found[0].points)
        elif found[1]:
            self.counts['right_only'] += 1
            self.right_only.append(found[1].points)
        else:
            self.counts['neither'] += 1
        return tuple(found)


def calibrate(collector, min_coverage=MIN_COVERED_CELLS):
    """Calibrate from a Collector; clear errors when the data cannot support it."""
    counts = collector.counts
    if not counts['pairs']:
        raise CalibrationInputError('no pairs in the input')
    if counts['both'] + counts['left_only'] + counts['right_only'] == 0:
        raise CalibrationInputError(f'target never found in {counts["pairs"]} pairs (check '
                                    'the kind, rows, columns and that it is fully in view)')
    cells = {}
    for side, points in (('left', collector.left + collector.left_only),
                         ('right', collector.right + collector.right_only)):
        grid = coverage(points, collector.size)
        cells[side] = grid
        share = float((grid > 0).mean())
        if share < min_coverage:
            raise CalibrationInputError(
                f'too little coverage: the target touched {share * 100:.0f} % of the {side} '
                f'image cells (need {min_coverage * 100:.0f} %); move it towards the edges and '
                f'corners')
    result = calibrate_stereo(collector.target, collector.left, collector.right,
                              collector.size, collector.left_only, collector.right_only)
    return result, cells


def tilts(result):
    """Angle between each view's target normal and the left optical axis, degrees."""
    values = []
    for rvec in result.left.rotations:
        rotation, _ = cv2.Rodrigues(rvec)
        values.append(float(np.degrees(np.arccos(min(1.0, abs(rotation[2, 2]))))))
    return np.array(values)


def report(result, cells, collector):
    """Return the numbers of a calibration as a dict (JSON-ready)."""
    size = collector.size
    left, right = result.calibrations(size)
    vertical = result.vertical_disparity
    angle = tilts(result)
    return {
        'pairs': collector.counts, 'rejected_images': collector.rejected,
        'views_used': result.views, 'views_dropped_as_outliers': result.dropped_views,
        'image_size': list(size),
        'rms_px': {'left': result.left.rms, 'right': result.right.rms,
                   'stereo': result.stereo_rms},
        'rectified_vertical_disparity_px': {'median': float(np.median(vertical)),
                                            'p95': float(np.percentile(vertical, 95)),
                                            'points': int(len(vertical))},
        'baseline_m': result.baseline_m,
        'left': {'fx': left.camera_matrix[0, 0], 'fy': left.camera_matrix[1, 1],
                 'cx': left.camera_matrix[0, 2], 'cy': left.camera_matrix[1, 2],
                 'distortion': left.distortion.tolist()},
        'right': {'fx': right.camera_matrix[0, 0], 'fy': right.camera_matrix[1, 1],
                  'cx': right.camera_matrix[0, 2], 'cy': right.camera_matrix[1, 2],
                  'distortion': right.distortion.tolist()},
        'coverage_cells': {side: grid.tolist() for side, grid in cells.items()},
        'tilt_deg': {'min': float(angle.min()), 'median': float(np.median(angle)),
                     'max': float(angle.max())},
    }


def report_text(numbers):
    """Human-readable report."""
    v = numbers['rectified_vertical_disparity_px']
    lines = [
        f'pairs: {numbers["pairs"]["pairs"]}, target in both: {numbers["pairs"]["both"]}, '
        f'left only: {numbers["pairs"]["left_only"]}, right only: '
        f'{numbers["pairs"]["right_only"]}, neither: {numbers["pairs"]["neither"]}',
    ] + [
        f'{side} images without the target: ' + ', '.join(
            f'{reason} {count}' for reason, count in numbers['rejected_images'][side].items())
        for side in ('left', 'right')
    ] + [
        f'RMS reprojection error: left {numbers["rms_px"]["left"]:.3f} px, right '
        f'{numbers["rms_px"]["right"]:.3f} px, stereo {numbers["rms_px"]["stereo"]:.3f} px',
        f'rectified vertical disparity of the target points: median {v["median"]:.3f} px, '
        f'p95 {v["p95"]:.3f} px ({v["points"]} points)',
        f'baseline: {numbers["baseline_m"]:.4f} m',
    ]
    dropped = numbers['views_dropped_as_outliers']
    lines.append(f'stereo views used: {numbers["views_used"]}; views dropped as outliers '
                 f'(reprojection RMS > {OUTLIER_VIEW_FACTOR:g}x the median view): left '
                 f'{dropped["left"]}, right {dropped["right"]}')
    for side in ('left', 'right'):
        c = numbers[side]
        lines.append(f'{side}: fx {c["fx"]:.3f} fy {c["fy"]:.3f} cx {c["cx"]:.3f} cy '
                     f'{c["cy"]:.3f} k1 {c["distortion"][0]:.4f} k2 {c["distortion"][1]:.4f}')
    t = numbers['tilt_deg']
    lines.append(f'target tilt to the optical axis: {t["min"]:.0f} to {t["max"]:.0f} deg '
                 f'(median {t["median"]:.0f})')
    for side, grid in numbers['coverage_cells'].items():
        lines.append(f'{side} coverage (points per image cell, top row first):')
        lines += ['  ' + ' '.join(f'{n:4d}' for n in row) for row in grid]
    return '\n'.join(lines)


def figure(collector, result, path, scale=4):
    """PNG: detected targets (top) and the rectified pair with epipolar lines (bottom)."""
    left, right, left_points, right_points = collector.example
    panels = []
    for image, points in ((left, left_points), (right, right_points)):
        big = cv2.cvtColor(cv2.resize(to_u8(image), None, fx=scale, fy=scale,
                                      interpolation=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR)
        for x, y in points:
            cv2.circle(big, (int((x + 0.5) * scale), int((y + 0.5) * scale)), 3, (0, 0, 255),
                       1, cv2.LINE_AA)
        panels.append(big)
    calibrations = result.calibrations(collector.size)
    rectified = StereoRectifier(*calibrations).rectify(left, right)
    stretched = to_u8(np.hstack(rectified))
    bottom = cv2.cvtColor(cv2.resize(stretched, None, fx=scale, fy=scale,
                                     interpolation=cv2.INTER_NEAREST), cv2.COLOR_GRAY2BGR)
    for row in range(4, collector.size[1], 6):
        y = int((row + 0.5) * scale)
        cv2.line(bottom, (0, y), (bottom.shape[1], y), (0, 200, 0), 1)
    image = np.vstack([np.hstack(panels), bottom])
    if not cv2.imwrite(str(path), image):
        raise CalibrationInputError(f'{path}: could not write the figure')


def main(args):
    """Run ``st-stereo calibrate``."""
    from tqdm import tqdm
    target = CalibrationTarget(args.target, args.rows, args.cols, args.spacing)
    pairs = input_pairs(args)
    collector = Collector(target)
    with tqdm(desc='detecting', unit='pair', disable=args.quiet) as bar:
        for name, left, right in pairs:
            collector.add(name, left, right)
            bar.update(1)
            bar.set_postfix(found=collector.counts['both'])
    result, cells = calibrate(collector)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    left, right = result.calibrations(collector.size, (args.left_name, args.right_name))
    save_calibration(left, out / 'left.yaml')
    save_calibration(right, out / 'right.yaml')
    numbers = report(result, cells, collector)
    (out / 'calibration_report.json').write_text(json.dumps(numbers, indent=1))
    text = report_text(numbers)
    (out / 'calibration_report.txt').write_text(text + '\n')
    figure(collector, result, out / 'calibration.png')
    print(text)
    print(f'wrote {out / "left.yaml"}, {out / "right.yaml"}, calibration_report.json / .txt and '
          f'calibration.png in {out}')
    return 0


def add_parser(sub):
    """Add ``calibrate`` to the ``st-stereo`` parser."""
    p = sub.add_parser('calibrate', help='stereo calibration from pairs of a heated target')
    p.add_argument('--images', help='directory of pairs (left*/right* or left/ and right/)')
    p.add_argument('--bag', help='rosbag2 with */left/image_raw and */right/image_raw')
    p.add_argument('--bag-namespace', default='', help=BAG_NAMESPACE_HELP)
    p.add_argument('--capture', nargs=2, metavar=('LEFT', 'RIGHT'),
                   help='two raw Lepton captures')
    p.add_argument('--target', required=True, choices=('circles', 'acircles', 'chessboard'),
                   help='circles: symmetric grid; acircles: asymmetric grid; chessboard')
    p.add_argument('--rows', type=int, required=True,
                   help='rows of circles, or of inner corners for a chessboard')
    p.add_argument('--cols', type=int, required=True,
                   help='circles per row, or inner corners per row for a chessboard')
    p.add_argument('--spacing', type=float, required=True,
                   help='square side, or distance between circle centres in a row, metres')
    p.add_argument('--out', required=True, help='output directory')
    p.add_argument('--left-name', default='left', help='camera_name of the left camera')
    p.add_argument('--right-name', default='right', help='camera_name of the right camera')
    p.add_argument('--quiet', action='store_true', help='no progress bar')
    p.set_defaults(handler=main)
