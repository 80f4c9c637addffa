#!/usr/bin/env python3
"""Create or update the local virtual environment, then run the suite or the tests.

    python3 .ci/dev.py run  [ARGS...]   the main job (st-stereo-suite ARGS)
    python3 .ci/dev.py test [ARGS...]   lint + tests (pytest ARGS)
    python3 .ci/dev.py noble [ARGS...]  the core tests on Jazzy's platform versions
                                        (.ci/requirements-noble.txt, in .venv-noble)

Needs only Python 3.11 and a network path to the package index. The environment lives in
.venv (or $ST_STEREO_VENV) and is reinstalled from requirements.txt whenever requirements.txt,
setup.py or setup.cfg change. Uses the standard library only.
"""

import hashlib
import os
import pathlib
import random
import subprocess
import sys
import venv

ROOT = pathlib.Path(__file__).resolve().parent.parent
VENV = pathlib.Path(os.environ.get('ST_STEREO_VENV', ROOT / '.venv'))
STAMP = VENV / '.st_stereo_requirements.sha256'
INPUTS = ('requirements.txt', 'setup.py', 'setup.cfg')
PIP = 'pip==26.3'   # the resolver the pins were made with (a new venv has Python's own pip)


def log(message):
    print(f'[dev] {message}', flush=True)


def venv_python():
    return VENV / 'bin' / 'python'


def requirements_digest():
    digest = hashlib.sha256()
    for name in INPUTS:
        digest.update((ROOT / name).read_bytes())
    return digest.hexdigest()


def ensure_environment():
    if sys.version_info[:2] != (3, 11):
        log(f'warning: the pins are made for Python 3.11, this is {sys.version.split()[0]}')
    if not venv_python().exists():
        log(f'creating the virtual environment {VENV}')
        venv.EnvBuilder(with_pip=True, clear=True).create(VENV)
    digest = requirements_digest()
    if STAMP.exists() and STAMP.read_text().strip() == digest:
        return
    log('installing the pinned requirements (first run or requirements changed)')
    pip = [str(venv_python()), '-m', 'pip', '--disable-pip-version-check']
    subprocess.run(pip + ['install', '--quiet', PIP], check=True)
    # Both OpenCV wheels install the same cv2 package: drop the one the pins replaced before
    # the contrib build goes in (uninstalling it afterwards would delete the shared files).
    contrib = subprocess.run(pip + ['show', '--quiet', 'opencv-contrib-python-headless'],
                             capture_output=True).returncode == 0
    if not contrib:
        subprocess.run(pip + ['uninstall', '--quiet', '--yes', 'opencv-python-headless',
                              'opencv-python'], check=False, capture_output=True)
    subprocess.run(pip + ['install', '--quiet', '-r', str(ROOT / 'requirements.txt')],
                   check=True)
    subprocess.run(pip + ['install', '--quiet', '--no-deps', '--no-build-isolation', '-e',
                          str(ROOT)], check=True)
    STAMP.write_text(digest + '\n')
    log('environment ready')


NOBLE_VENV = ROOT / '.venv-noble'
NOBLE_REQUIREMENTS = ROOT / '.ci' / 'requirements-noble.txt'
# The tests of the algorithm room (st_stereo/core): no ROS, no Lepton layer.
CORE_TESTS = ('test_kernels.py', 'test_phase_congruency.py', 'test_matcher.py',
              'test_subpixel.py', 'test_rough_matching.py', 'test_fourier.py',
              'test_triangulation.py', 'test_skew.py', 'test_trusted_points.py',
              'test_camera_calibration.py', 'test_target_refinement.py', 'test_config.py')


def noble(rest):
    """Build (or update) .venv-noble from requirements-noble.txt; run the core tests there."""
    python = NOBLE_VENV / 'bin' / 'python'
    stamp = NOBLE_VENV / '.st_stereo_requirements.sha256'
    digest = hashlib.sha256(NOBLE_REQUIREMENTS.read_bytes()).hexdigest()
    if not python.exists():
        log(f'creating {NOBLE_VENV}')
        venv.EnvBuilder(with_pip=True, clear=True).create(NOBLE_VENV)
    if not stamp.exists() or stamp.read_text().strip() != digest:
        log('installing the Noble versions')
        subprocess.run([str(python), '-m', 'pip', '--disable-pip-version-check', 'install',
                        '--quiet', '-r', str(NOBLE_REQUIREMENTS)], check=True)
        stamp.write_text(digest + '\n')
    subprocess.run([str(python), '-c', 'import numpy, scipy, numba, cv2; print("[dev] numpy",'
                    ' numpy.__version__, "scipy", scipy.__version__, "numba", '
                    'numba.__version__, "OpenCV", cv2.__version__)'], check=True)
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONDONTWRITEBYTECODE='1')
    cmd = [str(python), '-m', 'pytest', '-p', 'no:cacheprovider'] + \
        [str(ROOT / 'test' / name) for name in CORE_TESTS] + rest
    log(' '.join(cmd))
    return subprocess.run(cmd, cwd=ROOT, env=env).returncode


def ros_environment():
    env = dict(os.environ)
    env.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    env.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 100)))
    env['PATH'] = f'{VENV / "bin"}{os.pathsep}{env.get("PATH", "")}'
    env.setdefault('PYTHONUNBUFFERED', '1')
    return env


def main(argv):
    if not argv or argv[0] not in ('run', 'test', 'noble'):
        print(__doc__)
        return 2
    if argv[0] == 'noble':
        return noble(argv[1:])
    ensure_environment()
    command, rest = argv[0], argv[1:]
    env = ros_environment()
    if command == 'run':
        cmd = [str(VENV / 'bin' / 'st-stereo-suite')] + rest
    else:
        cmd = [str(venv_python()), '-m', 'pytest', str(ROOT / 'test')] + rest
    log(' '.join(cmd))
    return subprocess.run(cmd, cwd=ROOT, env=env).returncode


if __name__ == '__main__':
    sys.exit(main(sys.argv[1:]))
