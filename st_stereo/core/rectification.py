"""Rectification of a raw stereo pair with its calibration (D, R and P, always)."""

import cv2
import numpy as np

from st_stereo.core.calibration.files import CalibrationError, check_stereo_pair
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


def valid_region(maps, shape):
    """Pixels of a rectification map whose source point lies on a raw pixel's area."""
    rows, cols = shape
    map_x, map_y = maps
    return (map_x >= -0.5) & (map_x <= cols - 0.5) & (map_y >= -0.5) & (map_y <= rows - 0.5)


# A real calibration maps most rectified pixels into the raw image (the bundled one: all);
# one that maps almost none (a NaN or absurd K, D or R) would publish blank images.
MIN_VALID_FRACTION = 0.01


class StereoRectifier:
    """Rectify raw pairs of a calibrated rig; keeps raw counts (float32 output, no 8-bit)."""

    def __init__(self, left_calibration, right_calibration):
        check_stereo_pair(left_calibration, right_calibration)
        self.left = left_calibration
        self.right = right_calibration
        maps = []
        for calibration, side in ((left_calibration, 'left'), (right_calibration, 'right')):
            try:
                maps.append(rectification_maps(calibration))
            except cv2.error as error:
                raise CalibrationError(f'{side}: OpenCV cannot rectify with this calibration: '
                                       f'{str(error).strip().splitlines()[-1]}') from None
        self.left_maps, self.right_maps = maps
        # Fixed by the calibration: computed once, not per frame.
        self._valid = (valid_region(self.left_maps, self.shape),
                       valid_region(self.right_maps, self.shape))
        for valid, side in zip(self._valid, ('left', 'right')):
            if valid.mean() < MIN_VALID_FRACTION:
                raise CalibrationError(
                    f'{side}: the calibration maps {valid.sum()} of {valid.size} rectified '
                    f'pixels into the raw image (check K, D, R and P)')
        self.model = StereoModel.from_projection_matrices(left_calibration.projection,
                                                          right_calibration.projection)

    @property
    def shape(self):
        """(rows, cols) of the images this rectifier accepts."""
        return self.left.height, self.left.width

    def valid_masks(self):
        """
        Rectified pixels that sample inside the raw image, (left, right) bool (rows, cols).

        Outside them a rectified image has no data: ``rectify`` leaves them 0 (as image_proc
        does) and the matcher must not find features there (``StereoMatcher.match``'s
        ``left_valid`` / ``right_valid``).
        """
        return self._valid

    def valid_keywords(self):
        """``valid_masks`` as the keywords of ``StereoMatcher.match``."""
        left, right = self.valid_masks()
        return {'left_valid': left, 'right_valid': right}

    def rectify_one(self, image, maps, valid, name):
        """Rectify one image with bilinear interpolation; pixels outside ``valid`` are 0."""
        image = np.asarray(image)
        if image.shape != self.shape:
            raise ValueError(f'{name} image is {image.shape[1]}x{image.shape[0]}, the '
                             f'calibration is {self.shape[1]}x{self.shape[0]}')
        rectified = cv2.remap(image.astype(np.float32), maps[0], maps[1], cv2.INTER_LINEAR,
                              borderMode=cv2.BORDER_REPLICATE)
        rectified[~valid] = 0.0
        return rectified

    def rectify(self, left, right):
        """Rectify a raw pair; returns float32 images in raw-count units."""
        return (self.rectify_one(left, self.left_maps, self._valid[0], 'left'),
                self.rectify_one(right, self.right_maps, self._valid[1], 'right'))
