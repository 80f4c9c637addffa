"""
Write a simulated sequence as a recording: a rosbag2 of the raw pair, its calibration, truth.

A recording directory holds ``bag/`` (rosbag2, MCAP, metadata version 9 as Jazzy writes it:
``<namespace>/left/image_raw``, ``left/camera_info`` and the same for the right, mono16, both
images of a pair with the same acquisition stamp), ``left.yaml`` / ``right.yaml`` (the true
calibration, camera_calibration format), ``ground_truth.npz`` (per frame: stamps, depth and
disparity maps and labels in the rectified left camera, each person's head centre in the world
and in the rectified left optical frame) and ``README.md`` (what it is, how it was made, the
attribution of the real textures). Written with ``rosbags`` alone: no ROS installation needed.
"""

import json
import pathlib
import shutil

import numpy as np
from rosbags.rosbag2 import Writer
from rosbags.rosbag2.enums import StoragePlugin
from rosbags.typesys import get_typestore, Stores

from st_stereo.core.calibration.files import load_calibration, save_calibration
from st_stereo.core.rectification import StereoRectifier
from st_stereo.lepton.pairing import pair_info_values

START_NS = 1_764_000_000_000_000_000       # fixed, so a regenerated recording is identical
TEXTURE_CREDITS = (
    'Textures derived from real thermal frames (../shared/data/thermal): floor from '
    '"floor_heating.png" (Herbertweidner, CC0), walls from "ducks.png" (Zaereth, CC0), the '
    'electrical panel from "panel_flir_c2_80x60.png" (Tenbergen, CC-BY-SA-4.0; this recording '
    'is a derived work under the same licence).')


def _messages(typestore, frame_id):
    types = typestore.types
    header_type, time_type = types['std_msgs/msg/Header'], types['builtin_interfaces/msg/Time']

    def header(stamp_ns):
        sec, nanosec = divmod(stamp_ns, 1_000_000_000)
        return header_type(stamp=time_type(sec=sec, nanosec=nanosec), frame_id=frame_id)

    def image(pixels, stamp_ns):
        pixels = np.ascontiguousarray(pixels, dtype='<u2')
        return types['sensor_msgs/msg/Image'](
            header=header(stamp_ns), height=pixels.shape[0], width=pixels.shape[1],
            encoding='mono16', is_bigendian=0, step=2 * pixels.shape[1],
            data=np.frombuffer(pixels.tobytes(), dtype=np.uint8))

    def camera_info(calibration, stamp_ns):
        roi = types['sensor_msgs/msg/RegionOfInterest'](
            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        return types['sensor_msgs/msg/CameraInfo'](
            header=header(stamp_ns), height=calibration.height, width=calibration.width,
            distortion_model=calibration.distortion_model,
            d=np.asarray(calibration.distortion, dtype=np.float64),
            k=calibration.camera_matrix.ravel().astype(np.float64),
            r=calibration.rectification.ravel().astype(np.float64),
            p=calibration.projection.ravel().astype(np.float64), binning_x=0, binning_y=0,
            roi=roi)
    return image, camera_info


def write_recording(renderer, out_dir, namespace='/stereo', progress=None, overwrite=False):
    """
    Render every frame of ``renderer.spec`` and write the recording directory.

    Returns a summary dict (frames, sizes in bytes, paths).
    """
    spec = renderer.spec
    out_dir = pathlib.Path(out_dir)
    bag_dir = out_dir / 'bag'
    if bag_dir.exists():
        if not overwrite:
            raise FileExistsError(f'{bag_dir} exists (pass --overwrite to replace it)')
        shutil.rmtree(bag_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    calibrations = spec.rig.calibrations()
    for side, calibration in zip(('left', 'right'), calibrations):
        save_calibration(calibration, out_dir / f'{side}.yaml')
    # What the driver will load: round-trip through the YAML, as a user's files would.
    calibrations = [load_calibration(out_dir / f'{side}.yaml') for side in ('left', 'right')]
    typestore = get_typestore(Stores.ROS2_JAZZY)
    fx = StereoRectifier(*calibrations).model.fx
    truth_frames = {key: [] for key in ('stamp_ns', 'left_stamp_ns', 'right_stamp_ns', 'depth',
                                        'disparity', 'disparity_min', 'disparity_max', 'labels',
                                        'visible_right', 'heads_world', 'heads_rectified',
                                        'heads_image_velocity')}
    namespace = namespace.rstrip('/')
    pairs = spec.pair_times()
    period = 1.0 / spec.fps
    with Writer(bag_dir, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {}
        for side in ('left', 'right'):
            for name, msgtype in (('image_raw', 'sensor_msgs/msg/Image'),
                                  ('camera_info', 'sensor_msgs/msg/CameraInfo')):
                connections[side, name] = writer.add_connection(
                    f'{namespace}/{side}/{name}', msgtype, typestore=typestore)
        connections['pair_info'] = writer.add_connection(
            f'{namespace}/pair_info', 'diagnostic_msgs/msg/DiagnosticArray', typestore=typestore)
        builders = [_messages(typestore, f'stereo_{side}_optical_frame')
                    for side in ('left', 'right')]
        for index, (t_left, t_right) in enumerate(pairs):
            # Each camera at its own instant; both images of the pair carry the midpoint, as
            # the driver stamps them, and pair_info says which instant each image shows.
            frame = renderer.frame(t_left, right_t=t_right)
            acquired_ns = [START_NS + int(round(t * 1e9)) for t in (t_left, t_right)]
            stamp_ns = (acquired_ns[0] + acquired_ns[1]) // 2
            for side_index, side in enumerate(('left', 'right')):
                image, camera_info = builders[side_index]
                for name, msg in (('image_raw', image(frame[side], stamp_ns)),
                                  ('camera_info', camera_info(calibrations[side_index],
                                                              stamp_ns))):
                    writer.write(connections[side, name], stamp_ns,
                                 typestore.serialize_cdr(msg, msg.__msgtype__))
            msg = _pair_info_message(typestore, stamp_ns, acquired_ns,
                                     [int(round(t / period)) for t in (t_left, t_right)])
            writer.write(connections['pair_info'], stamp_ns,
                         typestore.serialize_cdr(msg, msg.__msgtype__))
            truth = frame['truth']
            truth_frames['stamp_ns'].append(stamp_ns)
            truth_frames['left_stamp_ns'].append(acquired_ns[0])
            truth_frames['right_stamp_ns'].append(acquired_ns[1])
            truth_frames['depth'].append(truth.depth.astype(np.float32))
            for key in ('disparity', 'disparity_min', 'disparity_max'):
                truth_frames[key].append(getattr(truth, key).astype(np.float32))
            truth_frames['labels'].append(truth.labels.astype(np.uint8))
            truth_frames['visible_right'].append(truth.visible_right)
            truth_frames['heads_world'].append(frame['heads_world'])
            truth_frames['heads_rectified'].append(frame['heads_rectified'])
            truth_frames['heads_image_velocity'].append(renderer.head_image_velocity(t_left, fx))
            if progress is not None:
                progress(index + 1, len(pairs))
    arrays = {key: np.asarray(value) for key, value in truth_frames.items()}
    arrays['label_names'] = np.array(json.dumps(renderer.scene(0.0)[0].label_names))
    np.savez_compressed(out_dir / 'ground_truth.npz', **arrays)
    (out_dir / 'README.md').write_text(recording_readme(spec, namespace), encoding='utf-8')
    sizes = {path.name: path.stat().st_size for path in out_dir.rglob('*') if path.is_file()}
    return {'frames': len(pairs), 'bytes': sum(sizes.values()), 'sizes': sizes,
            'path': str(out_dir)}


def _pair_info_message(typestore, stamp_ns, acquired_ns, frame_indices):
    """Build the driver's ``pair_info`` of one recorded pair (the simulated FFC never freezes)."""
    types = typestore.types
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    values = pair_info_values((acquired_ns[1] - acquired_ns[0]) * 1e-9,
                              [t * 1e-9 for t in acquired_ns], frame_indices, (False, False))
    status = types['diagnostic_msgs/msg/DiagnosticStatus'](
        level=0, name='lepton_driver: stereo pair', message='ok',
        hardware_id='sim', values=[types['diagnostic_msgs/msg/KeyValue'](key=k, value=str(v))
                                   for k, v in values.items()])
    header = types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec), frame_id='')
    return types['diagnostic_msgs/msg/DiagnosticArray'](header=header, status=[status])


def write_pairs_bag(pairs, bag_dir, namespace='/stereo', fps=8.7, overwrite=False,
                    right_offset_s=0.0):
    """
    Write raw pairs (uint16) as a rosbag2 of ``<namespace>/{left,right}/image_raw`` only.

    What a user records while moving a calibration target in front of the rig (no camera_info:
    the rig is not calibrated yet). MCAP, metadata version 9; stamps ``1 / fps`` apart, the
    right images' ``right_offset_s`` later (a recorder stamping each camera apart).
    """
    bag_dir = pathlib.Path(bag_dir)
    if bag_dir.exists():
        if not overwrite:
            raise FileExistsError(f'{bag_dir} exists (pass --overwrite to replace it)')
        shutil.rmtree(bag_dir)
    typestore = get_typestore(Stores.ROS2_JAZZY)
    namespace = namespace.rstrip('/')
    with Writer(bag_dir, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = [writer.add_connection(f'{namespace}/{side}/image_raw',
                                             'sensor_msgs/msg/Image', typestore=typestore)
                       for side in ('left', 'right')]
        builders = [_messages(typestore, f'stereo_{side}_optical_frame')[0]
                    for side in ('left', 'right')]
        for index, pair in enumerate(pairs):
            stamp_ns = START_NS + int(round(index / fps * 1e9))
            for connection, image, pixels, offset in zip(connections, builders, pair,
                                                         (0.0, right_offset_s)):
                msg = image(pixels, stamp_ns + int(round(offset * 1e9)))
                writer.write(connection, stamp_ns, typestore.serialize_cdr(msg, msg.__msgtype__))
    return bag_dir


def recording_readme(spec, namespace):
    """Return the README text of a recording directory."""
    rig = spec.rig
    return (
        f'# Simulated recording: {spec.name}\n\n'
        f'{spec.description}. {len(spec.frame_times)} stereo pairs at {spec.fps} Hz '
        f'({spec.duration_s} s), rendered by `st_stereo.sim` (regenerate with '
        f'`st-stereo sim record --sequence {spec.name} --out <dir>`).\n\n'
        f'- `bag/`: rosbag2 (MCAP, metadata version 9): `{namespace}/left/image_raw`, '
        f'`{namespace}/left/camera_info`, `{namespace}/right/image_raw`, '
        f'`{namespace}/right/camera_info`, `{namespace}/pair_info`; mono16 14-bit counts. '
        f'The two cameras free-run: the right one exposes {abs(1e3 * spec.right_phase_s):.0f} '
        f'ms {"after" if spec.right_phase_s >= 0 else "before"} the left one (its clock '
        f'{spec.right_drift_ppm:+.0f} ppm), each image is '
        'rendered at its own instant, both images of a pair carry the midpoint stamp (as the '
        'driver stamps them) and `pair_info` (diagnostic_msgs/DiagnosticArray, as the driver '
        'publishes it) gives both acquisition stamps and the skew.\n'
        f'- `left.yaml`, `right.yaml`: the true calibration (camera_calibration format); '
        f'distortion k1, k2 = {rig.distortion}, right camera misaligned by '
        f'{rig.misalignment_deg} deg (roll, pitch, yaw), baseline {rig.baseline_m:.4f} m, '
        f'fx B = {rig.fx_baseline:.3f} px m.\n'
        f'- `ground_truth.npz`: per pair `stamp_ns` (the pair stamp), `left_stamp_ns` and '
        '`right_stamp_ns` (the instants the images show), `depth` (Z in the rectified left '
        'camera at the left instant, m), `disparity` (fx B / Z, px) with its range over each '
        'pixel area (`disparity_min`, `disparity_max`), `labels` (see `label_names`), '
        '`visible_right`, '
        '`heads_world` and `heads_rectified` (the head centre of each person, m) and '
        '`heads_image_velocity` (its horizontal speed in the rectified left image, px/s).\n\n'
        f'{TEXTURE_CREDITS}\n')


def frame_truth(truth, index):
    """Return the GroundTruth of frame ``index`` of a loaded ground_truth.npz (no raw depths)."""
    from st_stereo.sim.render import GroundTruth
    return GroundTruth(depth=truth['depth'][index], disparity=truth['disparity'][index],
                       disparity_min=truth['disparity_min'][index],
                       disparity_max=truth['disparity_max'][index],
                       labels=truth['labels'][index].astype(np.int32),
                       visible_right=truth['visible_right'][index], raw_depth_left=None,
                       raw_depth_right=None)


def load_ground_truth(path):
    """Read a recording's ground_truth.npz into a dict (``label_names`` decoded)."""
    path = pathlib.Path(path)
    if path.is_dir():
        path = path / 'ground_truth.npz'
    if not path.is_file():
        raise FileNotFoundError(f'{path}: no ground truth file')
    with np.load(path) as data:
        truth = {key: data[key] for key in data.files}
    truth['label_names'] = {int(k): v for k, v in json.loads(str(truth['label_names'])).items()}
    return truth
