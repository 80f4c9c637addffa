"""``file://`` and ``package://`` URLs (camera_info_url, parameter files) to paths."""

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
            return str(pathlib.Path(__file__).resolve().parents[2] / relative)
    raise ValueError(f'camera_info URL {url!r}: expected file:// or package://')
