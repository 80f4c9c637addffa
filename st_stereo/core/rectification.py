"""Rectification of a raw stereo pair with its calibration (D, R and P, always)."""

import cv2
import numpy as np

from st_stereo.core.camera_calibration import check_stereo_pair
from st_stereo.core.triangulation import StereoModel


def rectification_maps(calibration):
    """
    Pixel maps from rectified to raw coordinates: undistort with D, rotate with R, project.

    R and P are always applied (ROS image_proc skips them when D is all zero, which is wrong
    for stereo).
    """
    size = (calibration.width, calibration.height)
    projection = calibration.projection[:, :3]
    if calibration.distortion_model == 'equidistant':
        return cv2.fisheye.initUndistortRectifyMap(
            calibration.camera_matrix, calibration.distortion, calibration.rectification,
            projection, size, cv2.CV_32FC1)
    return cv2.initUndistortRectifyMap(calibration.camera_matrix, calibration.distortion,
                                       calibration.rectification, projection, size,
                                       cv2.CV_32FC1)


class StereoRectifier:
    """Rectify raw pairs of a calibrated rig; keeps raw counts (float32 output, no 8-bit)."""

    def __init__(self, left_calibration, right_calibration):
        check_stereo_pair(left_calibration, right_calibration)
        self.left = left_calibration
        self.right = right_calibration
        self.left_maps = rectification_maps(left_calibration)
        self.right_maps = rectification_maps(right_calibration)
        self.model = StereoModel.from_projection_matrices(left_calibration.projection,
                                                          right_calibration.projection)

    @property
    def shape(self):
        """(rows, cols) of the images this rectifier accepts."""
        return self.left.height, self.left.width

    def rectify_one(self, image, maps, name):
        """Rectify one image with bilinear interpolation; border pixels replicate the edge."""
        image = np.asarray(image)
        if image.shape != self.shape:
            raise ValueError(f'{name} image is {image.shape[1]}x{image.shape[0]}, the '
                             f'calibration is {self.shape[1]}x{self.shape[0]}')
        return cv2.remap(image.astype(np.float32), maps[0], maps[1], cv2.INTER_LINEAR,
                         borderMode=cv2.BORDER_REPLICATE)

    def rectify(self, left, right):
        """Rectify a raw pair; returns float32 images in raw-count units."""
        return (self.rectify_one(left, self.left_maps, 'left'),
                self.rectify_one(right, self.right_maps, 'right'))
