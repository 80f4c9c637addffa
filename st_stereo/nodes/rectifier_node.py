"""
``rectifier``: rectifies the raw pair with D, R and P; 16-bit counts kept.

Subscribes ``left/image_raw``, ``right/image_raw``, ``left/camera_info``,
``right/camera_info`` (exact stamp sync); publishes ``left/image_rect``, ``right/image_rect``
(mono16, 0 where a rectified pixel has no data), each in its own camera's header (stamp and
optical frame). As image_proc's rectify node, no new camera_info: consumers of ``image_rect``
(the matcher, stereo_image_proc) pair it with the raw ``camera_info``, whose P is the
rectified geometry. ``left/camera_info_rect`` and ``right/camera_info_rect`` (K = P[:3, :3],
no distortion) are still published for one release, deprecated.
"""

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, Image

from st_stereo.core.calibration.files import calibration_from_camera_info
from st_stereo.core.image_io import contrast_stretch_u8
from st_stereo.core.rectification import StereoRectifier
from st_stereo.nodes import conversions, diagnostics
from st_stereo.nodes.node_parameters import RECTIFIER_PARAMETERS
from st_stereo.nodes.parameters import declare_node_parameters
from st_stereo.nodes.runtime import RELIABLE, spin_node, with_default_namespace
from st_stereo.nodes.sync import subscribe_exact, sync_drop_message, SyncDropWatch


# A Lepton's raw output is 14 bits. More is another output (a radiometric Lepton in TLinear,
# which PureThermal firmware may restore, gives centikelvin, 100 a kelvin; this project's
# count parameters, e.g. the people node's warm_margin_counts, assume raw counts).
MAX_RAW_COUNT = 16383
ABOVE_14_BITS = ('{} (a radiometric Lepton in TLinear mode gives centikelvin: the count '
                 'parameters, e.g. warm_margin_counts, assume raw counts)')


class RectifierNode(Node):
    """Thin wrapper: raw pair + infos -> StereoRectifier -> rectified pair + infos."""

    def __init__(self, **kwargs):
        super().__init__('rectifier', **with_default_namespace(kwargs))
        overriding = QoSOverridingOptions.with_default_policies()
        self.image_pubs = [self.create_publisher(Image, f'{side}/image_rect', RELIABLE,
                                                 qos_overriding_options=overriding)
                           for side in ('left', 'right')]
        self.info_pubs = [self.create_publisher(CameraInfo, f'{side}/camera_info_rect',
                                                RELIABLE, qos_overriding_options=overriding)
                          for side in ('left', 'right')]
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        declare_node_parameters(self, RECTIFIER_PARAMETERS)
        self.mono8_pubs = None
        if self.get_parameter('publish_mono8').value:
            self.mono8_pubs = [self.create_publisher(Image, f'{side}/image_rect_mono8',
                                                     RELIABLE, qos_overriding_options=overriding)
                               for side in ('left', 'right')]
        topics = [(Image, 'left/image_raw'), (Image, 'right/image_raw'),
                  (CameraInfo, 'left/camera_info'), (CameraInfo, 'right/camera_info')]
        self.sync = subscribe_exact(self, topics, self._on_pair, qos_profile_sensor_data)
        self.sync_topics = [name for _, name in topics]
        self.sync_watch = SyncDropWatch(self.sync)
        self.rectifier = None
        self._calibration_key = None
        self.counts = {'pairs': 0, 'rectified': 0, 'dropped_bad_input': 0,
                       'pairs_above_14_bits': 0}
        self.last_above_14_bits = ''
        self.last_error = ''
        self.last_drop_reason = ''
        self.create_timer(1.0, self._publish_diagnostics)

    def _rectifier_for(self, left_info, right_info):
        # Everything the maps and the checks depend on (a changed K, model or size alone
        # must rebuild them, and be checked).
        key = tuple((info.width, info.height, info.distortion_model, tuple(info.k),
                     tuple(info.d), tuple(info.r), tuple(info.p))
                    for info in (left_info, right_info))
        if key != self._calibration_key:
            self.rectifier = StereoRectifier(
                calibration_from_camera_info(left_info, 'left'),
                calibration_from_camera_info(right_info, 'right'))
            self._calibration_key = key
        return self.rectifier

    def _on_pair(self, left_msg, right_msg, left_info, right_info):
        self.counts['pairs'] += 1
        try:
            rectifier = self._rectifier_for(left_info, right_info)
            raw = [conversions.msg_to_image(msg, 'mono16') for msg in (left_msg, right_msg)]
            left, right = rectifier.rectify(*raw)
        except ValueError as error:
            self.counts['dropped_bad_input'] += 1
            self.last_error = self.last_drop_reason = str(error)
            return
        self.last_error = ''              # the state is the latest pair's: a good one clears it
        above = [side for side, image in zip(('left', 'right'), raw)
                 if image.size and int(image.max()) > MAX_RAW_COUNT]
        # Rectified and matched all the same (ST does not mind the scale); said while it lasts,
        # because the count parameters downstream (warm_margin_counts) assume raw counts.
        self.counts['pairs_above_14_bits'] += bool(above)
        self.last_above_14_bits = (f'{" and ".join(above)} image_raw above {MAX_RAW_COUNT}: '
                                   f'not 14-bit raw counts') if above else ''
        # Each rectified stream keeps its camera's header (stamp and optical frame), as
        # image_proc does; pixels without data (outside the raw image) are 0.
        headers = (left_msg.header, right_msg.header)
        for pub, image, header in zip(self.image_pubs, (left, right), headers):
            pub.publish(conversions.image_to_msg(np.clip(np.rint(image), 0, 65535), header))
        for pub, info, header in zip(self.info_pubs, (left_info, right_info), headers):
            pub.publish(conversions.rectified_camera_info(info, header))
        if self.mono8_pubs is not None:
            for pub, image, header in zip(self.mono8_pubs, (left, right), headers):
                pub.publish(conversions.image_to_msg(contrast_stretch_u8(image), header,
                                                     'mono8'))
        self.counts['rectified'] += 1

    def _publish_diagnostics(self):
        diagnostics.publish(self, self.diagnostics_pub, [self.status()])

    def status(self):
        """Return the node's DiagnosticStatus (what the 1 Hz diagnostics publish)."""
        values = dict(self.counts)
        values['pairs dropped by sync (left, right, left info, right info)'] = \
            ', '.join(map(str, self.sync.dropped))
        if self.last_drop_reason:
            values['last dropped pair'] = self.last_drop_reason
        level, message = diagnostics.OK, 'rectifying'
        if self.last_error:
            level, message = diagnostics.ERROR, f'dropping pairs: {self.last_error}'
        elif not self.counts['rectified']:
            level, message = diagnostics.WARN, 'no pair rectified yet'
        elif self.last_above_14_bits:
            level, message = diagnostics.WARN, ABOVE_14_BITS.format(self.last_above_14_bits)
        stalled = self.sync_watch.recent(self.counts['pairs'])
        if stalled and not self.last_error:
            level, message = diagnostics.ERROR, sync_drop_message(stalled, self.sync_topics)
        return diagnostics.status(diagnostics.status_name(self, 'rectification'), 'st_stereo',
                                  level, message, values)


def main(args=None):
    """Run the rectifier node."""
    return spin_node(RectifierNode, args)
