"""The default rig's calibration (``config/calibration``), built in code for tools and tests."""

import numpy as np

from st_stereo.core.camera_calibration import CameraCalibration
from st_stereo.core.triangulation import DEFAULT_FX_BASELINE_PX_M, LEPTON2_FX


def default_rig_calibrations(width=80, height=60):
    """Left and right CameraCalibration of the default rectified rig (fx B = 46.3 px m)."""
    scale = width / 80.0
    fx = LEPTON2_FX * scale
    cx, cy = (width - 1) / 2.0, (height - 1) / 2.0
    camera_matrix = np.array([[fx, 0, cx], [0, fx, cy], [0, 0, 1.0]])
    out = []
    for name, tx in (('lepton_left', 0.0), ('lepton_right', -DEFAULT_FX_BASELINE_PX_M * scale)):
        projection = np.array([[fx, 0, cx, tx], [0, fx, cy, 0], [0, 0, 1.0, 0]])
        out.append(CameraCalibration(width, height, name, camera_matrix, 'plumb_bob',
                                     np.zeros(5), np.eye(3), projection))
    return tuple(out)
