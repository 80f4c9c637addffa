"""Where the shared real thermal frames are: ``$ST_STEREO_SHARED`` or ``../shared`` of the repo."""

import os
import pathlib

FRAMES = ('people_lab_180x180.png', 'panel_flir_c2_80x60.png', 'ducks.png',
          'floor_heating.png', 'moving_car.png')
DEFAULT_FRAME = 'people_lab_180x180.png'


def shared_thermal_dir():
    """Directory of the shared thermal frames; a clear error when it cannot be found."""
    candidates = []
    if os.environ.get('ST_STEREO_SHARED'):
        candidates.append(pathlib.Path(os.environ['ST_STEREO_SHARED']) / 'data' / 'thermal')
    repo = pathlib.Path(__file__).resolve().parents[2]
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


PACKAGED_TEXTURE = 'people_lab_180x180.png'


def _package_data(relative):
    """Path of ``data/<relative>`` in the package share (an install) or the source tree."""
    try:
        from ament_index_python.packages import get_package_share_directory
        share = pathlib.Path(get_package_share_directory('st_stereo')) / 'data'
    except (ImportError, LookupError, OSError):
        share = None
    for base in (share, pathlib.Path(__file__).resolve().parents[2] / 'data'):
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
