"""
The launch files: their arguments, their nodes, and the rig's static transforms to 1e-9.

``launch`` and ``launch_ros`` are not installable here: the real launch files are imported
against stand-ins with the same API (test/fake_launch/README.md) and their nodes inspected.
The expected transforms are computed here independently of ``st_stereo.core.rig_pose``: the
stereo extrinsics from the simulated rig's true R, T (OpenCV's convention: a left-camera
point p is R p + T in the right camera), the rig pose from its definition with scipy.
"""

import contextlib
import importlib.util
import math
import pathlib
import sys
import types

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from st_stereo.core.calibration.files import save_calibration
from st_stereo.core.rig_pose import load_rig_pose, RigPoseError
from st_stereo.sim.rig import realistic_rig

REPO = pathlib.Path(__file__).resolve().parents[1]
BAG = REPO / 'data' / 'recordings' / 'office' / 'bag'
FAKES = pathlib.Path(__file__).resolve().parent / 'fake_launch'


@contextlib.contextmanager
def fake_launch_modules():
    saved = {name: sys.modules.pop(name) for name in list(sys.modules)
             if name.split('.')[0] in ('launch', 'launch_ros')}
    sys.path.insert(0, str(FAKES))
    try:
        yield
    finally:
        sys.path.remove(str(FAKES))
        for name in [n for n in sys.modules if n.split('.')[0] in ('launch', 'launch_ros')]:
            del sys.modules[name]
        sys.modules.update(saved)


def load_launch_file(name):
    spec = importlib.util.spec_from_file_location(name.replace('.', '_'), REPO / 'launch' / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def launch(name, **arguments):
    """Return a launch file's declared arguments {name: default} and its nodes."""
    with fake_launch_modules():
        description = load_launch_file(name).generate_launch_description()
        declared = {entity.name: entity.default_value for entity in description.entities
                    if hasattr(entity, 'default_value')}
        unknown = set(arguments) - set(declared)
        assert not unknown, f'not arguments of {name}: {unknown}'
        context = types.SimpleNamespace(launch_configurations={**declared, **arguments})
        nodes = []
        for entity in description.entities:
            if hasattr(entity, 'function'):
                nodes += entity.function(context, *entity.args, **entity.kwargs)
    return declared, nodes


@pytest.fixture(autouse=True)
def ament_prefix(tmp_path_factory, monkeypatch):
    """Make an ament prefix whose share/st_stereo is this source tree (as in an install)."""
    prefix = tmp_path_factory.mktemp('prefix')
    index = prefix / 'share' / 'ament_index' / 'resource_index' / 'packages'
    index.mkdir(parents=True)
    (index / 'st_stereo').write_text('', encoding='utf-8')
    (prefix / 'share' / 'st_stereo').symlink_to(REPO, target_is_directory=True)
    monkeypatch.setenv('AMENT_PREFIX_PATH', str(prefix))
    return prefix


def transform_of(node):
    """Return (parent, child, translation, quaternion xyzw) of a static_transform_publisher."""
    arguments = list(node.arguments)
    values = dict(zip(arguments[::2], arguments[1::2]))
    assert set(values) == {'--x', '--y', '--z', '--qx', '--qy', '--qz', '--qw', '--frame-id',
                           '--child-frame-id'}, arguments
    return (values['--frame-id'], values['--child-frame-id'],
            np.array([float(values[k]) for k in ('--x', '--y', '--z')]),
            np.array([float(values[k]) for k in ('--qx', '--qy', '--qz', '--qw')]))


@pytest.fixture
def rig_files(tmp_path):
    rig = realistic_rig()
    urls = []
    for side, calibration in zip(('left', 'right'), rig.calibrations()):
        save_calibration(calibration, tmp_path / f'{side}.yaml')
        urls.append(f'file://{tmp_path / side}.yaml')
    pose = tmp_path / 'pose.yaml'
    pose.write_text('world_frame: room\nrig_frame: rig_a\nx_m: 1.25\ny_m: -0.5\nheight_m: 2.9\n'
                    'yaw_deg: 30.0\ntilt_deg: 50.0\nroll_deg: 2.0\n', encoding='utf-8')
    return rig, urls, pose


def test_the_rig_launch_declares_the_arguments_users_expect():
    declared, nodes = launch('st_stereo.launch.py')
    for name in ('namespace', 'source', 'params_file', 'use_sim_time', 'respawn', 'left_device',
                 'right_device', 'left_i2c_bus', 'right_i2c_bus', 'rig_pose_file', 'bag'):
        assert name in declared, name
    assert declared['namespace'] == 'stereo' and declared['use_sim_time'] == 'false'
    by_executable = {node.executable: node for node in nodes}
    assert {'lepton_driver', 'rectifier', 'matcher', 'static_transform_publisher'} <= \
        set(by_executable)
    driver = by_executable['lepton_driver']
    assert driver.namespace == 'stereo' and driver.respawn is True
    assert driver.parameters[0].endswith('config/st_stereo.yaml')
    # Empty arguments leave the parameter file's values: only the clock is set.
    assert driver.parameters[1] == {'use_sim_time': False}


def test_launch_arguments_reach_the_driver(rig_files):
    _, urls, pose = rig_files
    _, nodes = launch('st_stereo.launch.py', source='spi', left_device='/dev/spidev1.0',
                      right_i2c_bus='3', use_sim_time='true', respawn='false', namespace='rig2',
                      left_camera_info_url=urls[0], right_camera_info_url=urls[1],
                      rig_pose_file=str(pose))
    driver = next(node for node in nodes if node.executable == 'lepton_driver')
    overrides = driver.parameters[1]
    # Strings stay strings (launch_ros would read a bare '1' as an integer).
    assert (overrides['source'].value, overrides['source'].value_type) == ('spi', str)
    assert overrides['left_device'].value == '/dev/spidev1.0'
    assert overrides['right_i2c_bus'] == 3 and overrides['use_sim_time'] is True
    # URLs given: the driver publishes them, not a replayed bag's own camera_info.
    assert overrides['bag_camera_info'] is False
    assert overrides['left.camera_info_url'].value == urls[0]
    assert driver.respawn is False and driver.namespace == 'rig2'
    for node in nodes:
        if node.executable in ('rectifier', 'matcher', 'static_transform_publisher'):
            assert node.parameters[-1]['use_sim_time'] is True
    with pytest.raises(ValueError, match='use_sim_time: expected true or false'):
        launch('st_stereo.launch.py', use_sim_time='maybe')
    with pytest.raises(ValueError, match="left_i2c_bus: expected an integer, got 'one'"):
        launch('st_stereo.launch.py', left_i2c_bus='one')


@pytest.mark.parametrize('launch_file', ['st_stereo.launch.py', 'st_stereo_replay.launch.py'])
def test_the_static_transforms_are_the_calibration_and_the_rig_pose(rig_files, launch_file):
    rig, urls, pose = rig_files
    extra = {'bag': str(BAG)} if 'replay' in launch_file else {}
    _, nodes = launch(launch_file, left_camera_info_url=urls[0], right_camera_info_url=urls[1],
                      rig_pose_file=str(pose), **extra)
    transforms = [transform_of(node) for node in nodes
                  if node.executable == 'static_transform_publisher']
    assert [t[:2] for t in transforms] == [
        ('room', 'rig_a'), ('rig_a', 'stereo_left_optical_frame'),
        ('stereo_left_optical_frame', 'stereo_right_optical_frame')]
    for _, _, _, quaternion in transforms:
        assert np.linalg.norm(quaternion) == pytest.approx(1.0, abs=1e-12)

    # world -> rig: the position, and the heading about the world's z.
    _, _, translation, quaternion = transforms[0]
    np.testing.assert_allclose(translation, [1.25, -0.5, 2.9], atol=1e-12)
    expected = Rotation.from_euler('z', 30.0, degrees=True)
    assert (Rotation.from_quat(quaternion) * expected.inv()).magnitude() < 1e-9

    # rig -> left optical: the optical axis leaves straight down towards the rig's +x by the
    # tilt; with no roll the image's right is horizontal, towards the rig's -y; the roll turns
    # the image about the optical axis.
    _, _, translation, quaternion = transforms[1]
    np.testing.assert_allclose(translation, 0.0, atol=1e-12)
    axes = Rotation.from_quat(quaternion).as_matrix()       # columns: optical x, y, z in rig
    tilt, roll = math.radians(50.0), math.radians(2.0)
    np.testing.assert_allclose(axes[:, 2], [math.sin(tilt), 0.0, -math.cos(tilt)], atol=1e-9)
    right0 = np.array([0.0, -1.0, 0.0])                      # image right before the roll
    down0 = np.cross(axes[:, 2], right0)
    np.testing.assert_allclose(axes[:, 0], math.cos(roll) * right0 + math.sin(roll) * down0,
                               atol=1e-9)

    # left -> right optical: the right camera's axes and centre in the left camera's frame.
    r, t = rig.stereo_extrinsics()
    _, _, translation, quaternion = transforms[2]
    np.testing.assert_allclose(translation, -r.T @ t, atol=1e-9)
    np.testing.assert_allclose(Rotation.from_quat(quaternion).as_matrix(), r.T, atol=1e-9)


def test_the_replay_launch_plays_the_bag_on_its_clock(rig_files):
    _, urls, pose = rig_files
    declared, nodes = launch('st_stereo_replay.launch.py', bag=str(BAG), rate='0.5',
                             left_camera_info_url=urls[0], right_camera_info_url=urls[1])
    assert declared['use_sim_time'] == 'true'
    player = next(node for node in nodes if node.executable == 'bag_play')
    assert player.arguments == [str(BAG), '--rate', '0.5', '--delay', '3.0', '--clock']
    assert player.remappings == []            # the bag's /stereo is the launch's namespace
    assert 'lepton_driver' not in {node.executable for node in nodes}
    for node in nodes:
        if node.executable in ('rectifier', 'matcher'):
            assert node.parameters[-1] == {'use_sim_time': True}
    _, nodes = launch('st_stereo_replay.launch.py', bag=str(BAG), use_sim_time='false',
                      publish_tf='false', namespace='rig2')
    player = next(node for node in nodes if node.executable == 'bag_play')
    assert '--clock' not in player.arguments
    assert 'static_transform_publisher' not in {node.executable for node in nodes}
    # Another namespace: the bag's raw pair is remapped into it.
    assert ('/stereo/left/image_raw', '/rig2/left/image_raw') in player.remappings
    assert ('/stereo/pair_info', '/rig2/pair_info') in player.remappings
    with pytest.raises(ValueError, match='bag: the rosbag2 directory to replay is required'):
        launch('st_stereo_replay.launch.py')


def test_the_launch_files_default_rig_pose_and_params_are_shipped():
    pose = load_rig_pose(REPO / 'config' / 'rig_pose.yaml')
    assert pose.world_frame == 'map' and pose.height_m > 0


def test_a_bad_rig_pose_file_names_the_field(tmp_path):
    path = tmp_path / 'pose.yaml'
    path.write_text('height_m: -1\n', encoding='utf-8')
    with pytest.raises(RigPoseError, match=r'pose.yaml: height_m: expected the height above'):
        load_rig_pose(path)
    path.write_text('hieght_m: 2.5\n', encoding='utf-8')
    with pytest.raises(RigPoseError, match=r"unknown field\(s\) \['hieght_m'\]"):
        load_rig_pose(path)
    path.write_text('tilt_deg: .nan\n', encoding='utf-8')
    with pytest.raises(RigPoseError, match='tilt_deg: expected a finite number'):
        load_rig_pose(path)


def test_the_replay_transforms_come_from_the_bags_camera_info():
    # No calibration URL given: the recorded camera_info, not the parameter file's default
    # calibration (the bundled recording's right camera is misaligned by 0.4-0.6 degrees).
    _, nodes = launch('st_stereo_replay.launch.py', bag=str(BAG))
    stereo = [transform_of(node) for node in nodes
              if node.executable == 'static_transform_publisher'][2]
    from st_stereo.sim.sequences import standard_sequences
    r, t = standard_sequences()['office'].rig.stereo_extrinsics()
    np.testing.assert_allclose(stereo[2], -r.T @ t, atol=1e-9)
    np.testing.assert_allclose(Rotation.from_quat(stereo[3]).as_matrix(), r.T, atol=1e-9)


def test_the_rig_launch_replaying_a_bag_takes_its_transforms_from_the_bags_camera_info():
    # The driver publishes a replayed bag's own camera_info (bag_camera_info): the stereo
    # transform must be that calibration's too, not the parameter file's default.
    from st_stereo.sim.sequences import standard_sequences
    _, nodes = launch('st_stereo.launch.py', source='bag', bag=str(BAG))
    stereo = [transform_of(node) for node in nodes
              if node.executable == 'static_transform_publisher'][2]
    r, t = standard_sequences()['office'].rig.stereo_extrinsics()
    np.testing.assert_allclose(stereo[2], -r.T @ t, atol=1e-9)
    np.testing.assert_allclose(Rotation.from_quat(stereo[3]).as_matrix(), r.T, atol=1e-9)


def test_rig_pose_launch_arguments_override_the_file(rig_files):
    _, urls, pose = rig_files
    _, nodes = launch('st_stereo.launch.py', rig_pose_file=str(pose), height_m='3.1',
                      world_frame='lab', left_camera_info_url=urls[0],
                      right_camera_info_url=urls[1])
    parent, child, translation, _ = transform_of(next(
        node for node in nodes if node.executable == 'static_transform_publisher'))
    assert (parent, child) == ('lab', 'rig_a')
    np.testing.assert_allclose(translation, [1.25, -0.5, 3.1], atol=1e-12)
    # The people node places people with the same pose as the transforms.
    people = next(node for node in nodes if node.executable == 'people')
    given = {key: value for entry in people.parameters if isinstance(entry, dict)
             for key, value in entry.items()}
    expected = load_rig_pose(pose)
    assert given['world_frame'] == 'lab' and given['height_m'] == 3.1
    for field in ('x_m', 'y_m', 'yaw_deg', 'tilt_deg', 'roll_deg'):
        assert given[field] == getattr(expected, field), field
    with pytest.raises(ValueError, match='launch argument tilt_deg: expected a number'):
        launch('st_stereo.launch.py', tilt_deg='steep')


def test_a_rig_pose_file_without_the_height_is_refused_unless_the_argument_gives_it(
        rig_files, tmp_path):
    _, urls, _ = rig_files
    pose = tmp_path / 'pose.yaml'
    pose.write_text('yaw_deg: 30.0\ntilt_deg: 40.0\n', encoding='utf-8')
    calibration = {'left_camera_info_url': urls[0], 'right_camera_info_url': urls[1]}
    with pytest.raises(RigPoseError, match=r'pose.yaml: height_m missing \(st-stereo rig-pose '
                                           r'measures height_m, tilt_deg and roll_deg'):
        launch('st_stereo.launch.py', rig_pose_file=str(pose), **calibration)
    _, nodes = launch('st_stereo.launch.py', rig_pose_file=str(pose), height_m='2.9',
                      **calibration)
    people = next(node for node in nodes if node.executable == 'people')
    given = {key: value for entry in people.parameters if isinstance(entry, dict)
             for key, value in entry.items()}
    assert (given['height_m'], given['tilt_deg'], given['yaw_deg']) == (2.9, 40.0, 30.0)


PARAMETER_FILE = """\
/**:
  ros__parameters:
    left.frame_id: everyone_left
/**/lepton_driver:
  ros__parameters:
    right_frame_id: old_style_right
rig2:
  lepton_driver:
    ros__parameters:
      left:
        frame_id: rig2_left
        camera_info_url: {left}
      right:
        camera_info_url: {right}
lepton_driver:
  ros__parameters:
    left.frame_id: root_left
"""


@pytest.mark.parametrize('namespace, frames', [
    ('rig2', ('rig2_left', 'old_style_right')),
    ('stereo', ('everyone_left', 'old_style_right'))])
def test_the_launch_reads_the_parameter_file_as_the_driver_does(rig_files, tmp_path, namespace,
                                                                frames):
    # Wildcards, nested namespaces and names, later sections winning, a deprecated name, a
    # section for another node: the transforms use the frame ids and the calibration the
    # driver itself takes from the same file in the same namespace.
    import rclpy
    from rclpy.parameter import Parameter
    from st_stereo.nodes.driver_node import DriverNode
    rig, urls, pose = rig_files
    params = tmp_path / 'params.yaml'
    params.write_text(PARAMETER_FILE.format(left=urls[0], right=urls[1]), encoding='utf-8')
    _, nodes = launch('st_stereo.launch.py', params_file=str(params), namespace=namespace,
                      rig_pose_file=str(pose))
    transforms = [transform_of(node) for node in nodes
                  if node.executable == 'static_transform_publisher']
    assert transforms[2][:2] == frames
    context = rclpy.Context()
    rclpy.init(context=context, args=['--ros-args', '--params-file', str(params)])
    try:
        driver = DriverNode(context=context, namespace=namespace, parameter_overrides=[
            Parameter('duration', value=0.2)])
        try:
            assert tuple(driver.frame_ids) == frames
            assert (driver.info_urls == urls) == (namespace == 'rig2')
        finally:
            driver.destroy_node()
    finally:
        rclpy.try_shutdown(context=context)
    if namespace == 'rig2':
        r, t = rig.stereo_extrinsics()                    # the file's calibration was used
        np.testing.assert_allclose(transforms[2][2], -r.T @ t, atol=1e-9)


def test_calibration_rotations_rounded_to_four_decimals_still_give_a_transform():
    from st_stereo.core.rig_pose import nearest_rotation, quaternion_of_rotation
    rotation = Rotation.from_euler('xyz', [2.0, -3.0, 1.5], degrees=True).as_matrix()
    rounded = np.round(rotation, 4)
    quaternion = quaternion_of_rotation(rounded)
    assert (Rotation.from_quat(quaternion) * Rotation.from_matrix(rotation).inv()).magnitude() \
        < 1e-3
    with pytest.raises(ValueError, match='not a rotation matrix'):
        nearest_rotation(rotation * 1.01)
    with pytest.raises(ValueError, match='not a rotation matrix'):
        nearest_rotation(-rotation)                   # a reflection
