"""
The package built by colcon as a workspace builds it, and its installed executables.

The tracked files are copied into ``ws/src/st_stereo`` in a temporary directory (as a clone
would be: nothing untracked, no ``../shared`` beside it), ``colcon build`` (colcon-core,
colcon-ros' ament_python build) installs it, and the installed executables run from
``install/st_stereo/lib/st_stereo`` (colcon's default isolated layout) in the environment of
``install/setup.sh`` (the POSIX form of ``setup.bash``): package:// URLs and the share
directory resolve through the ament index.
"""

import os
import pathlib
import shutil
import signal
import subprocess
import sys
import time
import venv

import pytest
import rclpy
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from ros_helpers import new_context
from sensor_msgs.msg import Image

pytestmark = pytest.mark.slow

REPO = pathlib.Path(__file__).resolve().parents[1]
SITE_PACKAGES = next(pathlib.Path(p) for p in sys.path if p.endswith('site-packages') and
                     pathlib.Path(p, 'rclpy').is_dir())
COLCON_MAIN = 'import sys; from colcon_core.command import main; sys.exit(main())'


def runtime_python(base):
    """
    Make a Python with everything this environment installed except st_stereo itself.

    The development environment holds st_stereo as an editable install (a meta-path finder
    that maps every ``st_stereo.*`` import to the source tree): a workspace build run with it
    would import the source tree's modules, not the installed ones. This venv sees the same
    site-packages (rclpy's bootstrap included) but not that finder, as a ROS install's Python
    would not.
    """
    venv.EnvBuilder(with_pip=False).create(base)
    python = base / 'bin' / 'python'
    site = subprocess.run([str(python), '-c', 'import site; print(site.getsitepackages()[0])'],
                          check=True, capture_output=True, text=True).stdout.strip()
    pathlib.Path(site, 'st_stereo_runtime.pth').write_text(
        f'{SITE_PACKAGES}\nimport ros_wheels_bootstrapper\n', encoding='utf-8')
    return python


def tracked_files():
    """Return the files a clone of this repository holds (git ls-files; the tree without git)."""
    try:
        listed = subprocess.run(['git', 'ls-files', '-z'], cwd=REPO, check=True,
                                capture_output=True).stdout.split(b'\0')
        return [pathlib.Path(name.decode()) for name in listed if name]
    except (OSError, subprocess.CalledProcessError):
        return [path.relative_to(REPO) for path in REPO.rglob('*') if path.is_file() and
                not {'.venv', '.git', '__pycache__'} & set(path.relative_to(REPO).parts)]


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    if not (SITE_PACKAGES / 'colcon_core').is_dir():
        pytest.fail('colcon is not installed in this environment (requirements.txt pins '
                    'colcon-core, colcon-ros, colcon-python-setup-py)')
    python = runtime_python(tmp_path_factory.mktemp('runtime') / 'venv')
    ws = tmp_path_factory.mktemp('ws')
    source = ws / 'src' / 'st_stereo'
    for relative in tracked_files():
        if (REPO / relative).is_file():
            (source / relative).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / relative, source / relative)
    environment = {key: value for key, value in os.environ.items()
                   if key not in ('AMENT_PREFIX_PATH', 'COLCON_PREFIX_PATH', 'ST_STEREO_SHARED')}
    done = subprocess.run([str(python), '-c', COLCON_MAIN, 'build', '--event-handlers',
                           'console_direct-'], cwd=ws, capture_output=True, text=True,
                          env=environment, timeout=300)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]
    return ws, environment, python


def installed(ws, environment, command, **kwargs):
    """Run ``command`` (a shell string) with ``install/setup.sh`` sourced, in ``ws``."""
    return subprocess.Popen(['sh', '-c', f'. install/setup.sh && exec {command}'], cwd=ws,
                            env=environment, start_new_session=True, **kwargs)


def test_colcon_installs_executables_share_files_and_the_ament_index(workspace):
    ws, _, python = workspace
    prefix = ws / 'install' / 'st_stereo'
    for executable in ('lepton_driver', 'rectifier', 'matcher', 'people', 'stereo_pipeline',
                       'bag_play', 'bag_record', 'st-stereo', 'st-stereo-suite'):
        path = prefix / 'lib' / 'st_stereo' / executable
        assert os.access(path, os.X_OK), executable
        # The interpreter colcon built with (not the development environment's).
        assert path.read_text(encoding='utf-8').splitlines()[0] == f'#!{python}', executable
    share = prefix / 'share' / 'st_stereo'
    for relative in ('package.xml', 'launch/st_stereo.launch.py',
                     'launch/st_stereo_replay.launch.py', 'config/rig_pose.yaml',
                     'config/st_stereo.yaml',
                     'config/calibration/left.yaml', 'config/calibration/right.yaml',
                     'data/textures/people_lab_180x180.png', 'data/textures/README.md',
                     'data/recordings/office/bag/metadata.yaml'):
        assert (share / relative).is_file(), relative
    assert (prefix / 'share' / 'ament_index' / 'resource_index' / 'packages' /
            'st_stereo').is_file()


def test_installed_code_resolves_package_urls_in_the_install(workspace):
    ws, environment, python = workspace
    script = ('import st_stereo.nodes.driver_node as d; '
              'from st_stereo.package_data import resolve_url; '
              'from st_stereo.package_data import packaged_texture; '
              'print(d.__file__); '
              'print(resolve_url("package://st_stereo/config/calibration/left.yaml")); '
              'print(packaged_texture())')
    process = installed(ws, environment, f"{python} -c '{script}'",
                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 0, err
    module, calibration, texture = out.split()
    install = str(ws / 'install' / 'st_stereo')
    assert module.startswith(install), module             # not the source tree's modules
    assert calibration.startswith(install + '/share/st_stereo/config/calibration')
    assert texture.startswith(install + '/share/st_stereo/data/textures')


class Images(Node):
    def __init__(self, context):
        super().__init__('installed_images', context=context, namespace='stereo')
        self.left, self.right = [], []
        self.create_subscription(Image, 'left/image_raw', self.left.append,
                                 qos_profile_sensor_data)
        self.create_subscription(Image, 'right/image_raw', self.right.append,
                                 qos_profile_sensor_data)


@pytest.mark.timeout(180)
def test_the_installed_driver_starts_with_its_installed_defaults_and_publishes(workspace):
    ws, environment, python = workspace
    # Its defaults: source sim (the texture shipped in share/), the calibration by package://.
    process = installed(ws, environment, 'install/st_stereo/lib/st_stereo/lepton_driver '
                        '--ros-args -r __ns:=/stereo', stdout=subprocess.PIPE,
                        stderr=subprocess.STDOUT, text=True)
    context, executor = new_context()
    node = Images(context)
    executor.add_node(node)
    try:
        deadline = time.monotonic() + 90.0
        while (len(node.left) < 10 or len(node.right) < 10) and \
                time.monotonic() < deadline and process.poll() is None:
            executor.spin_once(timeout_sec=0.05)
        running = process.poll() is None
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGINT)
        out, _ = process.communicate(timeout=30)
        node.destroy_node()
        rclpy.try_shutdown(context=context)
    assert running, out
    assert len(node.left) >= 10 and len(node.right) >= 10, out
    assert node.left[0].encoding == 'mono16' and node.left[0].width == 80
    assert node.left[0].header.frame_id == 'stereo_left_optical_frame'
    assert node.right[0].header.frame_id == 'stereo_right_optical_frame'
    assert process.returncode == 0, out                  # a clean Ctrl-C
    assert 'Traceback' not in out


def test_the_installed_parameter_file_is_the_generated_one(workspace):
    ws, environment, python = workspace
    process = installed(ws, environment, 'install/st_stereo/lib/st_stereo/st-stereo params --yaml',
                        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 0, err
    share = ws / 'install' / 'st_stereo' / 'share' / 'st_stereo'
    assert out == (share / 'config' / 'st_stereo.yaml').read_text(encoding='utf-8')


LAUNCH_PROBE = """
import importlib.util, sys, types
share = sys.argv[1]
for name, arguments in (('st_stereo.launch.py', {}),
                        ('st_stereo_replay.launch.py',
                         {'bag': f'{share}/data/recordings/office/bag'})):
    spec = importlib.util.spec_from_file_location('probe', f'{share}/launch/{name}')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    declared = {e.name: e.default_value for e in description.entities
                if hasattr(e, 'default_value')}
    context = types.SimpleNamespace(launch_configurations={**declared, **arguments})
    nodes = [node for e in description.entities if hasattr(e, 'function')
             for node in e.function(context)]
    print(name, declared['params_file'], ' '.join(sorted(n.executable for n in nodes)))
"""


def test_the_installed_launch_files_load_from_the_share_directory(workspace):
    ws, environment, python = workspace
    share = ws / 'install' / 'st_stereo' / 'share' / 'st_stereo'
    # launch and launch_ros are not installable here: their stand-ins (test/fake_launch).
    fakes = pathlib.Path(__file__).resolve().parent / 'fake_launch'
    environment_probe = dict(environment, PROBE=LAUNCH_PROBE)
    process = installed(ws, environment_probe, f'env PYTHONPATH={fakes}:$PYTHONPATH {python} '
                        f'-c "$PROBE" {share}', stdout=subprocess.PIPE,
                        stderr=subprocess.PIPE, text=True)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 0, err
    rig, replay = out.splitlines()
    assert rig.split()[1] == f'{share}/config/st_stereo.yaml'
    assert rig.split()[2:] == ['lepton_driver', 'matcher', 'people', 'rectifier'] + \
        ['static_transform_publisher'] * 3
    assert replay.split()[2:] == ['bag_play', 'matcher', 'people', 'rectifier'] + \
        ['static_transform_publisher'] * 3
