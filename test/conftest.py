"""Shared fixtures: the real thermal frames of ../shared/data/thermal, a private rclpy context."""

import numpy as np
import pytest

from st_stereo.core.image_io import read_thermal_image, resize_area
from st_stereo.package_data import FRAMES, shared_thermal_dir


@pytest.fixture(scope='session')
def thermal_dir():
    """Return the shared frames' directory (a missing one fails loudly, never skips)."""
    return shared_thermal_dir()


@pytest.fixture(scope='session')
def people_80x60(thermal_dir):
    """Return people_lab_180x180.png resized to 80x60 (pixel-area averaging), float64."""
    return resize_area(read_thermal_image(thermal_dir / 'people_lab_180x180.png'), 80, 60)


@pytest.fixture(scope='session')
def lepton_frame(thermal_dir):
    """Return the native 80x60 Lepton-class frame (FLIR C2), raw uint16 counts."""
    return read_thermal_image(thermal_dir / 'panel_flir_c2_80x60.png')


@pytest.fixture(scope='session', params=FRAMES)
def any_frame_80x60(request, thermal_dir):
    """Return each shared frame resized to 80x60."""
    return resize_area(read_thermal_image(thermal_dir / request.param), 80, 60)


@pytest.fixture
def ros():
    """Yield (context, executor, add) of a private rclpy context (ros_helpers.ros_nodes)."""
    from ros_helpers import ros_nodes      # rclpy only where a test asks for it
    with ros_nodes() as nodes:
        yield nodes


@pytest.fixture
def rng():
    """Return a seeded random generator."""
    return np.random.default_rng(1234)


@pytest.fixture(scope='session', autouse=True)
def compiled_kernels():
    """
    Compile (or load) the numba kernels once, before any test's nodes start.

    On a clean checkout the first compile takes seconds; a node test that starts a driver
    before its matcher would otherwise lose that many pairs to the first matcher's start.
    """
    from st_stereo.core.kernels import warm_up
    return warm_up()
