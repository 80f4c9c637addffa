"""
The parameters of the driver, rectifier and matcher nodes (the ST ones come from STConfig).

One list per node, each entry its name, default, description and whether a change while the
node runs takes effect (``live``); every other parameter is declared read-only (a live change
is refused: it is read once, at start-up). The nodes declare them from here, and
``st-stereo params --yaml`` (``config/st_stereo.yaml``) and the README document them from here.
"""

import dataclasses

SIDES = ('left', 'right')


@dataclasses.dataclass(frozen=True)
class NodeParameter:
    """One ROS parameter of a node."""

    name: str
    default: object
    description: str
    live: bool = False         # False: read-only, read at start-up


DRIVER_PARAMETERS = [
    NodeParameter('source', 'sim', 'frame source: sim (two simulated cameras), capture (two raw '
                  'capture files), spi (two Leptons on spidev), purethermal (two PureThermal '
                  'USB boards) or bag (the raw image topics of a rosbag2)'),
    NodeParameter('bag', '', 'bag: rosbag2 directory holding left/image_raw and '
                  'right/image_raw'),
    NodeParameter('bag_namespace', '', 'bag: the namespace of the image pair to replay, '
                  'e.g. /rig2/stereo (its left/image_raw, right/image_raw, camera_info and '
                  "pair_info); '': the bag's one namespace with both image topics (a bag of "
                  "several rigs is refused, naming them); '/': the root namespace"),
    NodeParameter('bag_camera_info', True, "bag: publish the bag's own calibration (its first "
                  'left/camera_info and right/camera_info) when it has one, else the '
                  "camera_info_url's (logged); false: always the camera_info_url's"),
    NodeParameter('replay_wait', 5.0, 'bag, capture: before replaying, wait up to this many '
                  'seconds until each of left/right image_raw and camera_info has '
                  'replay_subscribers subscribers (a consumer started beside the driver is '
                  'discovered within a second or so, and what is published before is lost); '
                  'then start anyway, logging the topics still without; 0: start at once'),
    NodeParameter('replay_rate', 1.0, 'bag, capture: replay speed, times the recorded pace '
                  '(2: twice as fast); 0: as fast as the frames are read (a slow consumer with '
                  'keep_latest then drops pairs, counted). A capture of plain SPI bytes has no '
                  'recorded times and is never paced'),
    NodeParameter('exit_at_end', False, 'bag, capture: end the process when the source ends '
                  '(after publishing the last pair and the final status; exit code 0, or 1 '
                  'when the source gave no pair), for scripted replays and launch files with '
                  'an on-exit shutdown; false: the node stays up, its status says finished'),
    NodeParameter('replay_subscribers', 1, 'bag, capture: subscribers each of left/right '
                  'image_raw and camera_info must have before the replay starts (replay_wait)'),
    NodeParameter('telemetry', 'off', 'camera telemetry rows: off, header or footer (a capture '
                  'says its own, or it is detected from its data)'),
    NodeParameter('max_pair_delta', 0.06, 'largest difference of the two acquisition times of '
                  'a stereo pair, seconds: two free-running Leptons drift through every phase, '
                  'so their frames are up to half a unique-frame period (56.8 ms) apart; 0.06 '
                  'pairs every frame (the matcher corrects the skew of moving features, '
                  'docs/skew.md); 0.05 gives no pair 12 % of the time (see docs/lepton.md)',
                  live=True),
    NodeParameter('duration', 0.0, 'stop after this many seconds of stream (0 = until the '
                  'source ends)'),
    NodeParameter('sim_depth', 3.5, 'sim: depth of the textured plane the cameras see, metres'),
    NodeParameter('sim_texture', '', 'sim: texture image (empty = the thermal texture shipped '
                  'with the package, share/st_stereo/data/textures)'),
    NodeParameter('spi_hz', 16000000, 'spi: SPI clock, Hz (4 to 20 MHz: a frame must be '
                  'clocked out well within one 37.9 ms core period)'),
    NodeParameter('spi_reader', 'process', 'spi: where each camera is read: process (its own '
                  'process, never waiting for the GIL of this one: the default, measured to '
                  'survive a busy neighbour) or thread (a thread of this process; enough when '
                  'nothing else here holds the GIL)'),
    NodeParameter('boot_timeout', 10.0, 'spi: seconds to wait for a camera to boot (I2C NACKs, '
                  'then busy) before its start-up counts as failed and is retried'),
    NodeParameter('give_up_after', 60.0, 'spi, purethermal: exit the node (non-zero, for '
                  'launch respawn) when a camera has delivered no frame for this many seconds '
                  '(0 = never)'),
] + [
    parameter for index, side in enumerate(SIDES) for parameter in (
        NodeParameter(f'{side}.camera_name', f'lepton_{side}', f'{side} camera name (the '
                      f'camera_name written by {side}/set_camera_info)'),
        NodeParameter(f'{side}.camera_info_url',
                      f'package://st_stereo/config/calibration/{side}.yaml',
                      f'{side} camera_calibration YAML (file:// or package://)'),
        NodeParameter(f'{side}.frame_id', f'stereo_{side}_optical_frame',
                      f'{side} optical frame id'),
        NodeParameter(f'{side}_capture', '', f'capture: raw capture file of the {side} camera'),
        NodeParameter(f'{side}_device', f'/dev/spidev0.{index}',
                      f'spi: spidev device of the {side} camera'),
        NodeParameter(f'{side}_i2c_bus', index, f'spi: I2C bus number of the {side} camera '
                      'CCI'),
        NodeParameter(f'{side}_serial', '', f'purethermal: serial number of the {side} board'),
        NodeParameter(f'{side}_video_device', f'/dev/video{2 * index}',
                      f'purethermal: V4L2 device of the {side} board'),
    )
]

# Old name -> new name: still accepted (a warning at start-up) for one release.
DEPRECATED_DRIVER_PARAMETERS = {
    f'{side}_{key}': f'{side}.{key}' for side in SIDES for key in ('camera_info_url', 'frame_id')
}

RECTIFIER_PARAMETERS = [
    NodeParameter('publish_mono8', False, 'also publish left/image_rect_mono8, '
                  'right/image_rect_mono8: contrast-stretched 8-bit copies for viewers '
                  '(1st-99th percentile)'),
]

MATCHER_PARAMETERS = [
    NodeParameter('target_frequency', 8.7, 'expected rate of point clouds, Hz (the '
                  'diagnostics say WARN more than 20 % away from it)', live=True),
    NodeParameter('pair_info_wait', 0.1, 'seconds a pair waits for its pair_info (another '
                  'topic, which an executor may deliver after the images) before it is matched '
                  'without skew compensation (counted); only once a pair_info has been seen',
                  live=True),
    NodeParameter('keep_latest', True, 'match in a worker thread, newest pair first: a pair '
                  'still waiting when a newer one arrives is dropped and counted (pairs '
                  'dropped_stale) instead of queued behind a slow match; false: every pair is '
                  "matched in the executor's thread, in arrival order (offline replays)"),
]

PEOPLE_PARAMETERS = [
    NodeParameter('world_frame', 'map', 'frame of the people topics: the room at floor level, '
                  'z up (the rig pose, config/rig_pose.yaml, places the rig in it)'),
    NodeParameter('x_m', 0.0, "rig pose: the left camera's position in the room, metres"),
    NodeParameter('y_m', 0.0, "rig pose: the left camera's position in the room, metres"),
    NodeParameter('height_m', 2.7, "rig pose: the left camera's optical centre above the "
                  'floor, metres'),
    NodeParameter('yaw_deg', 0.0, "rig pose: heading of the rig's tilt direction about the "
                  "world's z, degrees"),
    NodeParameter('tilt_deg', 0.0, 'rig pose: optical axis from straight down, degrees'),
    NodeParameter('roll_deg', 0.0, 'rig pose: image rotation about the optical axis, degrees'),
    NodeParameter('use_image', True, 'pair points2 with left/image_rect (exact stamp) for the '
                  'warm foreground, and with right/image_rect and right/camera_info for the '
                  'silhouettes (silhouette_margin_counts); false: points2 alone (require_warm '
                  'and the silhouettes have no effect)'),
    NodeParameter('target_frequency', 8.7, 'expected rate of the people topics, Hz (the '
                  'diagnostics say WARN more than 20 % away from it)', live=True),
]


def people_config_parameters():
    """Return the PeopleConfig fields as read-only NodeParameters (``st_stereo.core.people``)."""
    from st_stereo.core.people import people_fields
    return [NodeParameter(name, default, description)
            for name, _, default, description in people_fields()]


def _sections(document, path=()):
    """Yield ``(node path tokens, ros__parameters)`` of a ROS 2 parameter file, file order."""
    for key, value in document.items():
        if key == 'ros__parameters':
            if isinstance(value, dict):
                yield path, value
        elif isinstance(value, dict):
            yield from _sections(value, path + tuple(t for t in str(key).split('/') if t))


def _flattened(values, prefix=''):
    """Nested parameter names joined with dots, as rcl reads them."""
    for key, value in values.items():
        if isinstance(value, dict):
            yield from _flattened(value, f'{prefix}{key}.')
        else:
            yield f'{prefix}{key}', value


def _node_matches(pattern, name):
    """Match node path tokens against a pattern with rcl's wildcards (``**``: any, ``*``: one)."""
    if not pattern:
        return not name
    head, rest = pattern[0], pattern[1:]
    if head == '**':
        return any(_node_matches(rest, name[index:]) for index in range(len(name) + 1))
    return bool(name) and head in ('*', name[0]) and _node_matches(rest, name[1:])


def parameters_for_node(parameter_file, node):
    """
    Return the parameters a ROS 2 parameter file gives the node ``node`` (``/ns/name``).

    As rcl applies them: every section whose node path (``/stereo/lepton_driver``, nested
    ``stereo: {lepton_driver: ...}``, a key without a leading slash is in the root namespace;
    wildcards ``/**`` and ``*``) matches the node, in file order, later values winning; nested
    parameter names are joined with dots.
    """
    import yaml
    with open(parameter_file, encoding='utf-8') as stream:
        document = yaml.safe_load(stream) or {}
    if not isinstance(document, dict):
        raise ValueError(f'{parameter_file}: expected a mapping of node names')
    target = tuple(t for t in node.split('/') if t)
    values = {}
    for path, section in _sections(document):
        if _node_matches(path, target):
            values.update(_flattened(section))
    return values


def driver_parameter(parameter_file, name, namespace='stereo'):
    """
    Return the value the driver in ``namespace`` takes for ``name`` from a parameter file.

    As the node resolves it (``parameters_for_node``; a deprecated name counts when the new
    one is absent), else the parameter's default.
    """
    values = parameters_for_node(parameter_file, f'/{namespace.strip("/")}/lepton_driver')
    if name in values:
        return values[name]
    old = {new: old for old, new in DEPRECATED_DRIVER_PARAMETERS.items()}.get(name)
    if old is not None and values.get(old):
        return values[old]
    return next(p.default for p in DRIVER_PARAMETERS if p.name == name)
