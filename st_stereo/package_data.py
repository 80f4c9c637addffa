"""
Files of the package: ``file://`` and ``package://`` URLs, and the data it ships.

An install resolves ``package://st_stereo/...`` through the ament index (its share directory);
a pip or editable install, without one, falls back to the source tree. The shared real thermal
frames the evaluations and tests read (not shipped): ``$ST_STEREO_SHARED`` or ``../shared``
beside the source tree.
"""

import os
import pathlib


def resolve_url(url):
    """Path of a ``file://`` or ``package://PACKAGE/relative`` camera_info URL."""
    if url.startswith('file://'):
        return url[len('file://'):]
    if url.startswith('package://'):
        package, _, relative = url[len('package://'):].partition('/')
        try:
            from ament_index_python.packages import (get_package_share_directory,
                                                     PackageNotFoundError)
            return os.path.join(get_package_share_directory(package), relative)
        except (ImportError, LookupError, OSError, PackageNotFoundError):
            if package != 'st_stereo':
                raise ValueError(f'{url}: package {package!r} not found (is its workspace '
                                 f'sourced?)') from None
            # Not installed through ament (a pip / editable install): the source tree.
            return str(pathlib.Path(__file__).resolve().parents[1] / relative)
    raise ValueError(f'camera_info URL {url!r}: expected file:// or package://')


PACKAGED_TEXTURE = 'people_lab_180x180.png'


def _package_data(relative):
    """Path of ``data/<relative>`` in the package share (an install) or the source tree."""
    try:
        from ament_index_python.packages import get_package_share_directory
        share = pathlib.Path(get_package_share_directory('st_stereo')) / 'data'
    except (ImportError, LookupError, OSError):
        share = None
    for base in (share, pathlib.Path(__file__).resolve().parents[1] / 'data'):
        if base is not None and (base / relative).exists():
            return base / relative
    raise FileNotFoundError(f'package data data/{relative} not found (in the st_stereo share '
                            'directory or the source tree)')


def packaged_texture():
    """Return the thermal texture the package ships (data/textures; the sim plane's default)."""
    return _package_data(f'textures/{PACKAGED_TEXTURE}')


def bundled_recording():
    """Directory of the bundled recording: the package share, or the source tree."""
    return _package_data('recordings/office/bag').parent


FRAMES = ('people_lab_180x180.png', 'panel_flir_c2_80x60.png', 'ducks.png',
          'floor_heating.png', 'moving_car.png')
DEFAULT_FRAME = 'people_lab_180x180.png'


def shared_thermal_dir():
    """Directory of the shared thermal frames; a clear error when it cannot be found."""
    candidates = []
    if os.environ.get('ST_STEREO_SHARED'):
        candidates.append(pathlib.Path(os.environ['ST_STEREO_SHARED']) / 'data' / 'thermal')
    repo = pathlib.Path(__file__).resolve().parents[1]
    candidates.append(repo.parent / 'shared' / 'data' / 'thermal')
    for candidate in candidates:
        if (candidate / DEFAULT_FRAME).is_file():
            return candidate
    raise FileNotFoundError('shared thermal frames not found (looked in '
                            f'{", ".join(map(str, candidates))}); set ST_STEREO_SHARED to the '
                            'shared/ directory or pass --image')


def shared_frame(name=DEFAULT_FRAME):
    """Path of one shared frame."""
    return shared_thermal_dir() / name
