"""
``people``: people on the floor, with ids, from the matcher's points (``st_stereo.core.people``).

Subscribes ``points2`` (the rectified left frame: x, y, z, disparity, confidence, u, v: each
point is put back on the ray of its feature's pixel u, v at its depth, ``at_their_features``;
any PointCloud2 with x, y, z works, used as it lies, with a WARN when u, v are missing),
``left/image_rect`` (the warm foreground, ``use_image``: the image of the points' stamp, which
the rectifier publishes before the matcher has matched it; a pair whose image has not arrived
is counted, ``pairs_without_image``, and its detections are skipped, the tracks coast and the
messages still go out) and ``left/camera_info`` (its R turns the rectified frame into the raw
optical one, its P gives each point's pixel; a camera_info with a P or R that cannot be used is
dropped, counted and named in the diagnostics). With ``use_image`` and
``silhouette_margin_counts`` > 0 also ``right/image_rect`` and ``right/camera_info`` (its P:
``fx B`` and the right principal point): far bodies starved of matches are placed by their
silhouettes' disparity; a pair without the right image of its stamp is counted
(``pairs_without_right_image``) and gets no silhouettes. ``pair_info`` (the driver's, as the
matcher reads it) gives each pair's camera skew, for a moving silhouette's disparity; a pair
without it is counted (``pairs_without_pair_info``) and its silhouettes are not corrected for
the skew.

Publishes, each with the pair's stamp and ``world_frame``: ``people/poses``
(geometry_msgs/PoseArray), ``people/detections`` (PointCloud2, one point per person:
``st_stereo.nodes.people_messages.DETECTION_FIELDS``), ``people/markers``
(visualization_msgs/MarkerArray) and, when vision_msgs is importable, ``people/detections_3d``
(vision_msgs/Detection3DArray). A pair without people publishes empty messages. Until a
camera_info has arrived no pair can be placed in the room: each one is counted
(``waiting_for_camera_info``) and nothing is published for it.
"""

import collections
import importlib
import traceback

from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import PoseArray
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from st_stereo.core.people import PeopleConfig, PeopleEstimator, project_to_pixels, \
    world_from_rectified
from st_stereo.core.rig_pose import nearest_rotation, RigPose, RigPoseError
from st_stereo.core.triangulation import at_their_features
from st_stereo.lepton.pairing import pair_times_from_values
from st_stereo.nodes import conversions, diagnostics, people_messages
from st_stereo.nodes.node_parameters import people_config_parameters, PEOPLE_PARAMETERS
from st_stereo.nodes.parameters import declare_node_parameters
from st_stereo.nodes.runtime import RELIABLE, spin_node, with_default_namespace
from st_stereo.nodes.sync import stamp_key
from std_msgs.msg import Header
from visualization_msgs.msg import MarkerArray

POSE_PARAMETERS = ('x_m', 'y_m', 'height_m', 'yaw_deg', 'tilt_deg', 'roll_deg')
IMAGES_KEPT = 30        # left images waiting for their points (3.4 s at 8.7 Hz)


def _numbers(values):
    """Return a message's number array as plain text (``[1, 0, 41.5, ...]``)."""
    return '[' + ', '.join(f'{float(value):g}' for value in values) + ']'


def optional_vision_msgs():
    """Return the vision_msgs.msg module, or None when it is not installed."""
    try:
        return importlib.import_module('vision_msgs.msg')
    except ImportError:
        return None


NO_FEATURE_PIXELS = ('points2 without the fields u, v (a matcher before 2026-12-07, or a '
                     'filter that dropped them): points used where they lie; the people '
                     'stage was tuned on points at their features (point_location feature '
                     'upstream, or keep the fields)')


class PeopleNode(Node):
    """Thin wrapper: points2 (+ left image) -> PeopleEstimator -> people topics."""

    def __init__(self, **kwargs):
        super().__init__('people', **with_default_namespace(kwargs))
        declare_node_parameters(self, PEOPLE_PARAMETERS + people_config_parameters())
        values = {name: self.get_parameter(name).value for name in POSE_PARAMETERS}
        try:
            self.pose = RigPose(world_frame=self.get_parameter('world_frame').value, **values)
        except RigPoseError as error:
            raise ValueError(f'people: {error}') from None
        self.config = PeopleConfig(**{p.name: self.get_parameter(p.name).value
                                      for p in people_config_parameters()})
        self.poses_pub = self.create_publisher(PoseArray, 'people/poses', RELIABLE)
        self.detections_pub = self.create_publisher(PointCloud2, 'people/detections', RELIABLE)
        self.markers_pub = self.create_publisher(MarkerArray, 'people/markers', RELIABLE)
        self.vision_msgs = optional_vision_msgs()
        self.detection3d_pub = None if self.vision_msgs is None else self.create_publisher(
            self.vision_msgs.Detection3DArray, 'people/detections_3d', RELIABLE)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_subscription(CameraInfo, 'left/camera_info', self._on_camera_info,
                                 qos_profile_sensor_data)
        self.use_image = self.get_parameter('use_image').value
        self.use_right = self.use_image and self.config.silhouette_margin_counts > 0
        self.images = collections.OrderedDict()     # stamp key -> left/image_rect
        self.right_images = collections.OrderedDict()   # stamp key -> right/image_rect
        self.right_projection = None
        if self.use_image:
            self.create_subscription(Image, 'left/image_rect', self._on_image,
                                     qos_profile_sensor_data)
        if self.use_right:
            self.create_subscription(Image, 'right/image_rect', self._on_right_image,
                                     qos_profile_sensor_data)
            self.create_subscription(CameraInfo, 'right/camera_info', self._on_right_info,
                                     qos_profile_sensor_data)
            self.create_subscription(DiagnosticArray, 'pair_info', self._on_pair_info,
                                     RELIABLE)
        self.skews = collections.OrderedDict()      # stamp key -> skew, s (pair_info)
        self.create_subscription(PointCloud2, 'points2', self._on_points,
                                 qos_profile_sensor_data)
        self.camera_info = None
        self.estimator = None
        self._rectification = None
        self.counts = {'pairs': 0, 'published': 0, 'waiting_for_camera_info': 0,
                       'dropped_bad_input': 0, 'pairs_without_image': 0,
                       'images_without_points': 0, 'points_not_finite': 0,
                       'camera_info_rejected': 0, 'pairs_without_right_image': 0,
                       'right_images_without_points': 0, 'right_camera_info_rejected': 0,
                       'right_image_rejected': 0, 'pairs_without_pair_info': 0,
                       'pair_info_unreadable': 0, 'points_behind_camera': 0,
                       'dropped_frame_mismatch': 0, 'dropped_internal_error': 0,
                       'points_placed_at_their_features': 0,
                       'clouds_without_feature_pixels': 0}
        self.last_without_pixels = False
        if all(values[name] == next(p.default for p in PEOPLE_PARAMETERS if p.name == name)
               for name in POSE_PARAMETERS):
            self.get_logger().warning(
                'the rig pose is at its defaults (2.7 m high, looking straight down, at the '
                "room's origin): set x_m ... roll_deg (the launch files take them from "
                'rig_pose_file) or people are placed wrongly')
        self.last_error = ''
        self.right_error = ''           # the last right/camera_info or right/image_rect refused
        self.frequency = diagnostics.FrequencyTracker(
            diagnostics.target_frequency(self.get_parameter('target_frequency').value))
        self.add_on_set_parameters_callback(self._on_parameters)
        self.create_timer(1.0, self._publish_diagnostics)

    def _on_parameters(self, parameters):
        for parameter in parameters:
            if parameter.name == 'target_frequency':
                try:
                    self.frequency.target_hz = diagnostics.target_frequency(parameter.value)
                except ValueError as error:
                    return SetParametersResult(successful=False, reason=str(error))
        return SetParametersResult(successful=True)

    def _on_camera_info(self, msg):
        try:
            transform = self._transform_of(msg)
        except ValueError as error:
            self.counts['camera_info_rejected'] += 1
            self.last_error = f'left/camera_info: {error}'
            self.get_logger().warning(self.last_error, throttle_duration_sec=5.0)
            return
        if transform is not None:
            if self.estimator is None:
                self.estimator = PeopleEstimator(transform, self.config)
            else:                           # a new calibration: same tracks, new geometry
                self.estimator.transform = transform
            self._rectification = tuple(msg.r)
        self.camera_info = msg

    def _transform_of(self, msg):
        """Return the world transform of a camera_info (None: unchanged); ValueError if bad."""
        p = np.array(msg.p, dtype=np.float64).reshape(3, 4)
        if not (np.isfinite(p).all() and p[0, 0] > 0 and p[1, 1] > 0):
            raise ValueError(f'P: expected fx = P[0] > 0 and fy = P[5] > 0, got '
                             f'{_numbers(msg.p)}')
        if tuple(msg.r) == self._rectification:
            return None
        r1 = np.array(msg.r, dtype=np.float64).reshape(3, 3)
        if not np.any(r1):                  # R not filled in: an unrectified camera
            r1 = np.eye(3)
        try:
            r1 = nearest_rotation(r1)
        except ValueError as error:
            raise ValueError(f'R: {error}') from None
        return world_from_rectified(self.pose, r1)

    def _on_pair_info(self, msg):
        values = diagnostics.key_values(msg)
        try:
            _, skew = pair_times_from_values(values)
        except ValueError as error:
            self.counts['pair_info_unreadable'] += 1
            self.get_logger().warning(f'{error}: that pair is not corrected for the skew',
                                      throttle_duration_sec=5.0)
            return
        self.skews[stamp_key(msg)] = skew
        while len(self.skews) > IMAGES_KEPT:
            self.skews.popitem(last=False)

    def _on_right_info(self, msg):
        p = np.array(msg.p, dtype=np.float64).reshape(3, 4)
        if not (np.isfinite(p).all() and p[0, 0] > 0 and p[0, 3] < 0):
            self.counts['right_camera_info_rejected'] += 1
            self.right_error = (f'right/camera_info: P: expected fx = P[0] > 0 and P[3] = '
                                f'-fx B < 0 (left camera first), got {_numbers(msg.p)}')
            self.get_logger().warning(self.right_error, throttle_duration_sec=5.0)
            return
        self.right_projection = p

    @staticmethod
    def _keep(images, msg, counts, dropped):
        images[stamp_key(msg)] = msg
        while len(images) > IMAGES_KEPT:
            images.popitem(last=False)
            counts[dropped] += 1

    def _on_image(self, msg):
        self._keep(self.images, msg, self.counts, 'images_without_points')

    def _on_right_image(self, msg):
        self._keep(self.right_images, msg, self.counts, 'right_images_without_points')

    def _on_points(self, points_msg):
        key = stamp_key(points_msg)
        image_msg = self.images.pop(key, None)
        right_msg = self.right_images.pop(key, None)
        skew = self.skews.pop(key, None)
        for old in [k for k in self.skews if k < key]:
            del self.skews[old]
        # Older images can no longer be paired: points come in stamp order.
        for images, dropped in ((self.images, 'images_without_points'),
                                (self.right_images, 'right_images_without_points')):
            for old in [k for k in images if k < key]:
                del images[old]
                self.counts[dropped] += 1
        self._on_pair(points_msg, image_msg, right_msg, skew)

    def _right_image(self, right_msg, image):
        """
        Return the right image of a pair for the silhouettes, or None.

        A bad one (not decodable, not the left image's size) does not drop the pair, only its
        silhouettes: counted (``right_image_rejected``) and named in the diagnostics.
        """
        if right_msg is None or image is None:
            return None
        try:
            right = conversions.msg_to_image(right_msg, 'mono16')
            if right.shape != image.shape:
                raise ValueError(f'{right.shape[1]}x{right.shape[0]}, left/image_rect is '
                                 f'{image.shape[1]}x{image.shape[0]}')
        except ValueError as error:
            self.counts['right_image_rejected'] += 1
            self.right_error = f'right/image_rect: {error}'
            self.get_logger().warning(f'{self.right_error}: no silhouettes for this pair',
                                      throttle_duration_sec=5.0)
            return None
        self.right_error = ''
        return right

    def _stereo(self):
        """``(fx B, cx_left - cx_right)`` from the two camera_infos' P, or None."""
        if self.right_projection is None or self.camera_info is None:
            return None
        left = np.array(self.camera_info.p, dtype=np.float64).reshape(3, 4)
        return -self.right_projection[0, 3], left[0, 2] - self.right_projection[0, 2]

    def _on_pair(self, points_msg, image_msg=None, right_msg=None, skew=None):
        self.counts['pairs'] += 1
        if self.camera_info is None:
            self.counts['waiting_for_camera_info'] += 1
            self.get_logger().warning('no left/camera_info yet: people wait for it',
                                      throttle_duration_sec=5.0)
            return
        try:
            fields = conversions.point_cloud_fields(points_msg, ('x', 'y', 'z'),
                                                    ('disparity', 'confidence', 'u', 'v'))
            info = self.camera_info
            frame, expected = points_msg.header.frame_id, info.header.frame_id
            if frame and expected and frame.lstrip('/') != expected.lstrip('/'):
                self.counts['dropped_frame_mismatch'] += 1
                raise ValueError(f'points2: frame {frame!r}, expected {expected!r}, the frame '
                                 f'of left/camera_info (the rectified left optical frame; no '
                                 f'TF is applied)')
            image = None
            if image_msg is not None:
                if image_msg.encoding not in conversions.COUNT_ENCODINGS:
                    raise ValueError(f'left/image_rect: encoding {image_msg.encoding}, '
                                     f'expected mono16 or 16UC1 (raw counts: '
                                     f'warm_margin_counts)')
                image = conversions.msg_to_image(image_msg)
                if not image.size:
                    raise ValueError('left/image_rect: empty image (0 pixels)')
            if image is not None and info.width and image.shape != (info.height, info.width):
                raise ValueError(f'left/image_rect: {image.shape[1]}x{image.shape[0]}, '
                                 f'left/camera_info says {info.width}x{info.height}')

        except ValueError as error:
            self.counts['dropped_bad_input'] += 1
            self.last_error = str(error)
            self.get_logger().warning(f'pair dropped: {error}', throttle_duration_sec=5.0)
            return
        self.last_error = ''
        right = self._right_image(right_msg, image)
        p = np.array(self.camera_info.p, dtype=np.float64).reshape(3, 4)
        points = np.column_stack([fields['x'], fields['y'], fields['z']])
        points, placed = at_their_features(points, fields['u'], fields['v'], p)
        self.counts['points_placed_at_their_features'] += placed
        # A cloud without u, v: an older matcher's (its points at their features) or a filter
        # that dropped the fields (its points perhaps at their structure): used as they are.
        self.last_without_pixels = fields['u'] is None or fields['v'] is None
        self.counts['clouds_without_feature_pixels'] += int(self.last_without_pixels)
        finite = np.isfinite(points).all(axis=1)
        self.counts['points_not_finite'] += int((~finite).sum())
        behind = finite & ~(points[:, 2] > 0)
        self.counts['points_behind_camera'] += int(behind.sum())
        finite &= ~behind
        points = points[finite]
        if self.use_image and image is None:
            # No image of this stamp (yet): no warm foreground, so no detection; the tracks
            # coast and the pair's (maybe empty) messages still go out.
            self.counts['pairs_without_image'] += 1
            points = points[:0]
            finite = np.zeros_like(finite)
        if self.use_right and image is not None and (right is None or self._stereo() is None):
            self.counts['pairs_without_right_image'] += 1
        elif self.use_right and image is not None and skew is None:
            self.counts['pairs_without_pair_info'] += 1
        x_left, y = project_to_pixels(points, p[0, 0], p[1, 1], p[0, 2], p[1, 2])
        shape = None if image is None else image.shape
        if shape is None and self.camera_info.width and self.camera_info.height:
            shape = (self.camera_info.height, self.camera_info.width)
        stamp_s = points_msg.header.stamp.sec + 1e-9 * points_msg.header.stamp.nanosec
        try:
            frame = self.estimator.process(
                stamp_s, points, x_left, y,
                None if fields['disparity'] is None else fields['disparity'][finite],
                None if fields['confidence'] is None else fields['confidence'][finite],
                image, shape, intrinsics=(p[0, 0], p[1, 1], p[0, 2], p[1, 2]),
                right_image=right, stereo=self._stereo(), skew_s=skew)
        except Exception as error:  # noqa: B902 -- the node lives on, the pair is counted
            self.counts['dropped_internal_error'] += 1
            self.last_error = f'internal error on a pair: {type(error).__name__}: {error}'
            self.get_logger().error(f'{self.last_error}\n{traceback.format_exc()}',
                                    throttle_duration_sec=5.0)
            return
        header = Header(stamp=points_msg.header.stamp, frame_id=self.pose.world_frame)
        self.poses_pub.publish(people_messages.poses_msg(header, frame.tracks))
        self.detections_pub.publish(people_messages.detections_cloud(header, frame.tracks))
        self.markers_pub.publish(people_messages.markers_msg(header, frame.tracks, frame.ended))
        if self.detection3d_pub is not None:
            self.detection3d_pub.publish(people_messages.detection3d_msg(
                self.vision_msgs, header, frame.tracks))
        self.counts['published'] += 1
        self.frequency.tick(self.get_clock().now().nanoseconds * 1e-9)

    def _publish_diagnostics(self):
        now = self.get_clock().now().nanoseconds * 1e-9
        level, message, values = self.frequency.values(now)
        values.update(self.counts)
        if self.estimator is not None:
            values.update({f'people {k}': v for k, v in self.estimator.counts.items()})
            values.update({f'tracks {k}': v for k, v in self.estimator.tracker.counts.items()})
        if self.last_error:
            level, message = diagnostics.ERROR, f'dropping pairs: {self.last_error}'
        elif self.camera_info is None:
            level, message = diagnostics.WARN, 'waiting for left/camera_info'
        elif self.counts['pairs_without_image'] and not self.counts['published'] - \
                self.counts['pairs_without_image']:
            level, message = diagnostics.WARN, 'no left/image_rect with the stamps of ' \
                'points2 (use_image): no people can be found'
        elif self.last_without_pixels:
            level, message = diagnostics.WARN, NO_FEATURE_PIXELS
        elif self.right_error:
            level, message = diagnostics.WARN, f'no silhouettes: {self.right_error}'
        elif self.use_right and self.counts['pairs_without_right_image'] and \
                self.right_projection is None:
            level, message = diagnostics.WARN, 'no right/camera_info: far bodies starved of ' \
                'matches are not placed by their silhouettes'
        elif self.use_right and self.counts['published'] and \
                self.counts['pairs_without_right_image'] >= self.counts['published']:
            level, message = diagnostics.WARN, 'no right/image_rect with the stamps of ' \
                'points2: far bodies starved of matches are not placed by their silhouettes'
        status = diagnostics.status(diagnostics.status_name(self, 'people'), 'st_stereo',
                                    level, message, values)
        diagnostics.publish(self, self.diagnostics_pub, [status])


def main(args=None):
    """Run the people node."""
    return spin_node(PeopleNode, args)
