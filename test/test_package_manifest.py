"""package.xml declares, by its rosdep key, every package the installed code imports."""

import ast
import pathlib
import sys
import xml.etree.ElementTree as ElementTree

REPO = pathlib.Path(__file__).resolve().parents[1]

# Top-level module -> the rosdep key (or ROS package) that provides it. rosdep keys: the
# rosdistro's base.yaml and python.yaml (e.g. python3-spidev-pip, python3-rosbags-pip).
PROVIDERS = {
    'ament_index_python': 'ament_index_python',
    'builtin_interfaces': 'builtin_interfaces',
    'diagnostic_msgs': 'diagnostic_msgs',
    'geometry_msgs': 'geometry_msgs',
    'visualization_msgs': 'visualization_msgs',
    'rcl_interfaces': 'rcl_interfaces',
    'rclpy': 'rclpy',
    'rosgraph_msgs': 'rosgraph_msgs',
    'sensor_msgs': 'sensor_msgs',
    'std_msgs': 'std_msgs',
    'std_srvs': 'std_srvs',
    'stereo_msgs': 'stereo_msgs',
    'launch': 'launch',
    'launch_ros': 'launch_ros',
    'cv2': 'python3-opencv',
    'numpy': 'python3-numpy',
    'scipy': 'python3-scipy',
    'numba': 'python3-numba',
    'yaml': 'python3-yaml',
    'tqdm': 'python3-tqdm',
    'matplotlib': 'python3-matplotlib',
    'skimage': 'python3-skimage',
    'psutil': 'python3-psutil',
    'spidev': 'python3-spidev-pip',
    'smbus2': 'python3-smbus2',
    'usb': 'python3-usb',
    'rosbags': 'python3-rosbags-pip',
    # rosbags' own dependencies, which bag_reading.py uses directly (pip installs them with
    # rosbags; `compression.zstd` is the standard library's from Python 3.14).
    'apsw': 'python3-rosbags-pip',
    'backports': 'python3-rosbags-pip',
    'compression': 'python3-rosbags-pip',
}
# Declared for what is not a Python import of the package: the launch files' static TF
# publisher and `ros2 launch` itself.
NOT_IMPORTED = {'tf2_ros', 'ros2launch'}
# Imported only by an offline evaluation, installed with pip from requirements.txt, with no
# rosdep key we could verify (README, "On a real ROS 2 Jazzy install"): not in package.xml, so
# `rosdep install` never fails on an unknown key; `st-stereo eval people` needs it.
EVALUATION_ONLY = {'motmetrics'}


def imported_modules(root):
    """{top-level module: [files]} of every absolute import under ``root``, lazy ones too."""
    found = {}
    for path in sorted(root.rglob('*.py')):
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'), str(path))):
            if isinstance(node, ast.Import):
                names = [alias.name for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                names = [node.module]
            else:
                continue
            for name in names:
                found.setdefault(name.split('.')[0], []).append(str(path.relative_to(REPO)))
    return found


def declared(kind):
    tree = ElementTree.parse(REPO / 'package.xml')
    return {element.text.strip() for element in tree.getroot().iter(kind)}


def third_party(modules):
    return {name: files for name, files in modules.items()
            if name not in sys.stdlib_module_names and name != 'st_stereo'}


def test_every_import_of_the_installed_code_maps_to_a_declared_rosdep_key():
    modules = third_party(imported_modules(REPO / 'st_stereo'))
    assert set(modules['motmetrics']) == {'st_stereo/tools/eval_people.py'}
    modules = {name: files for name, files in modules.items() if name not in EVALUATION_ONLY}
    modules.update(third_party(imported_modules(REPO / 'launch')))
    unknown = {name: files[:3] for name, files in modules.items() if name not in PROVIDERS}
    assert not unknown, f'imports without a known rosdep key (add them to PROVIDERS and ' \
                        f'package.xml): {unknown}'
    exec_depends = declared('exec_depend') | declared('depend')
    missing = {name: PROVIDERS[name] for name in modules if PROVIDERS[name] not in exec_depends}
    assert not missing, f'imported but not declared in package.xml: {missing}'


def test_every_declared_run_dependency_is_used():
    modules = third_party(imported_modules(REPO / 'st_stereo'))
    modules.update(third_party(imported_modules(REPO / 'launch')))
    used = {PROVIDERS[name] for name in modules if name in PROVIDERS} | NOT_IMPORTED
    unused = (declared('exec_depend') | declared('depend')) - used
    assert not unused, f'declared in package.xml but never imported: {sorted(unused)}'


def test_the_scan_sees_lazy_imports_inside_functions():
    # spidev is imported only inside SpiTransport's constructor: the check must see it.
    modules = imported_modules(REPO / 'st_stereo')
    assert 'st_stereo/lepton/spi.py' in modules['spidev']
