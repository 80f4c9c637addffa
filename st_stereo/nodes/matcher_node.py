"""
``matcher``: ST on the rectified pair; publishes ``points2``, ``disparity``, diagnostics.

Subscribes ``left/image_rect``, ``right/image_rect``, ``left/camera_info``, ``right/camera_info``
(sensor-data QoS, exact stamp sync; as stereo_image_proc's disparity node: a raw camera_info's
P is the rectified geometry, so any image_proc-style rectifier can feed it) and the driver's
``pair_info``
(both acquisition stamps of each pair: the camera skew, see ``st_stereo.core.skew``); every ST
parameter is a ROS parameter with its range and can be changed live (validated by STConfig).

With ``keep_latest`` (the default) the matching runs in the node's own worker thread: the
executor hands each complete pair over (``LatestSlot``) and goes on serving the other
callbacks, and a pair still waiting when a newer one arrives is dropped and counted
(``dropped_stale``), so a matcher slower than the cameras publishes the newest pair, never a
queue of old ones.
"""

import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, Image, PointCloud2
from st_stereo.core.kernels import use_compiled, warm_up
from st_stereo.core.matcher import fill_invalid, StereoMatcher
from st_stereo.core.skew import compensation_options, SkewCompensator
from st_stereo.core.temporal import TemporalCheck
from st_stereo.core.triangulation import StereoModel
from st_stereo.lepton.pairing import pair_ffc_from_values, pair_times_from_values
from st_stereo.nodes import conversions, diagnostics
from st_stereo.nodes.node_parameters import MATCHER_PARAMETERS
from st_stereo.nodes.parameters import declare_node_parameters, declare_st_parameters, \
    validate_changes
from st_stereo.nodes.runtime import LatestSlot, RELIABLE, spin_node, \
    with_default_namespace
from st_stereo.nodes.sync import stamp_key, subscribe_exact, sync_drop_message, \
    SyncDropWatch
from stereo_msgs.msg import DisparityImage


def data_mask(msg, image):
    """
    Pixels with data: in a rectified image of counts (mono16, 16UC1) 0 means none.

    image_proc and the rectifier fill what lies outside the raw image with 0.

    Raw 14-bit Lepton counts are never 0 (about 8000 at room temperature); in mono8 (AGC,
    stretched) 0 is a real value, and float images carry no such marker: all pixels count.
    """
    return image != 0 if msg.encoding in conversions.COUNT_ENCODINGS else None


STAMP_LATENCY_PLAUSIBLE_S = 5.0     # a stamp older than this is not on the node's clock


def _pair_images(left_msg, right_msg, left_info, right_info):
    """Return a pair's two images; ValueError when one's size is not its camera_info's."""
    left = conversions.msg_to_image(left_msg)
    right = conversions.msg_to_image(right_msg)
    for image, info, side in ((left, left_info, 'left'), (right, right_info, 'right')):
        if image.shape != (info.height, info.width):
            raise ValueError(f'{side} image is {image.shape[1]}x{image.shape[0]} but its '
                             f'camera_info says {info.width}x{info.height}')
    return left, right


PERIOD_UNITS = {'target_frequency': 'Hz', 'pair_info_wait': 's'}


class MatcherNode(Node):
    """Thin wrapper: messages -> StereoMatcher -> messages."""

    def __init__(self, **kwargs):
        super().__init__('matcher', **with_default_namespace(kwargs))
        self.config = declare_st_parameters(self)
        declare_node_parameters(self, MATCHER_PARAMETERS)
        self.add_on_set_parameters_callback(self._on_parameters)
        self.matcher = StereoMatcher(self.config)
        # Compile (or load from numba's cache) the kernels now, not on the first pair.
        kernels = 'compiled' if use_compiled(self.config.kernels) else 'numpy'
        self.kernel_warm_up_s = warm_up() if kernels == 'compiled' else 0.0
        self.get_logger().info(f'kernels: {kernels} (start-up compile or cache load '
                               f'{self.kernel_warm_up_s:.2f} s)')
        overriding = QoSOverridingOptions.with_default_policies()
        self.points_pub = self.create_publisher(PointCloud2, 'points2', RELIABLE,
                                                qos_overriding_options=overriding)
        self.disparity_pub = self.create_publisher(DisparityImage, 'disparity', RELIABLE,
                                                   qos_overriding_options=overriding)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        topics = [(Image, 'left/image_rect'), (Image, 'right/image_rect'),
                  (CameraInfo, 'left/camera_info'), (CameraInfo, 'right/camera_info')]
        self.sync = subscribe_exact(self, topics, self._on_pair, qos_profile_sensor_data)
        self.sync_topics = [name for _, name in topics]
        self.sync_watch = SyncDropWatch(self.sync)
        self.last_pair_without_pair_info = False     # it waited pair_info_wait in vain
        self.skew = SkewCompensator()
        # Static matches the previous pair did not make alike are dropped (temporal_tolerance_px).
        self.temporal = TemporalCheck()
        self.pair_times = {}         # pair stamp -> (left acquisition time, skew), seconds
        self.create_subscription(DiagnosticArray, 'pair_info', self._on_pair_info, RELIABLE)
        self.frequency = diagnostics.FrequencyTracker(
            diagnostics.target_frequency(self.get_parameter('target_frequency').value))
        self.counts = {'pairs': 0, 'matched': 0, 'dropped_bad_input': 0, 'dropped_stale': 0,
                       'dropped_internal_error': 0, 'dropped_at_shutdown': 0, 'empty_clouds': 0,
                       'pair_info_unreadable': 0, 'waited_for_pair_info': 0,
                       'stamps_not_on_node_clock': 0, 'stale_kept_for_skew': 0,
                       'stale_not_kept_for_skew': 0, 'pair_info_wait_expired': 0}
        self._pair_times_lock = threading.Lock()
        self._models = {}            # (left P, right P) -> StereoModel, the last few
        self.last_drop_reason = ''
        self.processing_times = []
        self.last_pair_info_problem = ''
        # A pair whose pair_info has not arrived yet (another topic: an executor may deliver
        # it after the images) waits for it, at most pair_info_wait seconds, once it has been
        # seen at all (a driver without it never makes a pair wait).
        self.pair_info_wait = diagnostics.positive_number(
            'pair_info_wait', self.get_parameter('pair_info_wait').value, 's')
        self.pair_info_seen = False
        self._waiting = None         # (monotonic arrival, the pair's four messages)
        # On the steady clock: under use_sim_time a /clock that stops (a bag's end) must not
        # keep the last pair waiting.
        # Running only while a pair waits: an idle 50 Hz timer woke the executor 50 times a
        # second, each wake-up rebuilding its wait set (measured: 7 ms of CPU per pair).
        self._stale_timer = self.create_timer(0.02, self._release_stale_pair,
                                              clock=Clock(clock_type=ClockType.STEADY_TIME))
        self._stale_timer.cancel()
        self.last_error = ''
        self.last_result = None
        self.latencies = []
        self.create_timer(1.0, self._publish_diagnostics)
        self._slot = None
        self._last_submitted = None  # the pair handed over last, and the one taken last
        self._last_taken = None
        if self.get_parameter('keep_latest').value:
            self._slot = LatestSlot()
            self._worker = threading.Thread(target=self._work, name='matcher', daemon=True)
            self._worker.start()

    def destroy_node(self):
        """Stop the worker thread (a pair still waiting is counted as dropped_at_shutdown)."""
        if self._slot is not None:
            self.counts['dropped_at_shutdown'] += self._slot.close()
            self._worker.join(timeout=10.0)
        return super().destroy_node()

    def _submit(self, messages):
        if self._slot is None:
            self._match_pair(*messages)
            return
        # Each pair travels with the one handed over before it: if that one is dropped as
        # stale, the worker still gives its images to the skew compensation.
        self._slot.put((messages, self._last_submitted))
        self._last_submitted = messages
        self.counts['dropped_stale'] = self._slot.replaced

    def _work(self):
        while True:
            item = self._slot.take()
            if item is None:
                return
            messages, before = item
            if before is not None and before is not self._last_taken:
                self._keep_skipped_for_skew(*before)
            self._last_taken = messages
            try:
                self._match_pair(*messages)
            except Exception as error:  # noqa: B902 - the thread must outlive any one pair
                # Inline, such an error would end the node; here it would end the thread
                # unseen: the pair is counted, the error logged and shown in diagnostics.
                self.counts['dropped_internal_error'] += 1
                self.last_error = self.last_drop_reason = \
                    f'internal error: {type(error).__name__}: {error}'
                self.get_logger().error(f'matching a pair failed: {self.last_error}')

    def _on_parameters(self, parameters):
        for parameter in parameters:
            if parameter.name in ('target_frequency', 'pair_info_wait'):
                try:
                    diagnostics.positive_number(parameter.name, parameter.value,
                                                PERIOD_UNITS[parameter.name])
                except ValueError as error:
                    return SetParametersResult(successful=False, reason=str(error))
        result, config = validate_changes(self.config, parameters)
        if not result.successful:
            return result
        for parameter in parameters:
            if parameter.name == 'target_frequency':
                self.frequency.target_hz = float(parameter.value)
            if parameter.name == 'pair_info_wait':
                self.pair_info_wait = float(parameter.value)
        if config is not None:
            try:
                use_compiled(config.kernels)
            except ValueError as error:
                return SetParametersResult(successful=False, reason=str(error))
            self.config = config
            self.matcher = StereoMatcher(config)
            if use_compiled(config.kernels):
                self.kernel_warm_up_s = warm_up()     # at once, not on the next pair
        return result

    def _on_pair_info(self, msg):
        values = diagnostics.key_values(msg)
        try:
            left_time, skew = pair_times_from_values(values)
        except ValueError as error:
            # Counted and named: that pair is matched without skew compensation.
            self.counts['pair_info_unreadable'] += 1
            self.last_pair_info_problem = str(error)
            return
        stamp = stamp_key(msg)
        with self._pair_times_lock:
            self.pair_times[stamp] = (left_time, skew, pair_ffc_from_values(values))
            while len(self.pair_times) > 64:
                self.pair_times.pop(next(iter(self.pair_times)))
        self.pair_info_seen = True
        if self._waiting is not None and stamp_key(self._waiting[1][0]) == stamp:
            self.last_pair_without_pair_info = False
            self._release_waiting()

    def _release_waiting(self):
        if self._waiting is not None:
            messages, self._waiting = self._waiting[1], None
            self._stale_timer.cancel()
            self._submit(messages)

    def _release_stale_pair(self):
        if self._waiting is not None and \
                time.monotonic() - self._waiting[0] > self.pair_info_wait:
            stamp = stamp_key(self._waiting[1][0])
            self.counts['pair_info_wait_expired'] += 1
            self.last_pair_without_pair_info = True
            self.last_pair_info_problem = (
                f'no pair_info with the stamp {stamp[0]}.{stamp[1]:09d} in '
                f'{self.pair_info_wait:g} s (pair_info_wait): matched without skew '
                f'compensation (pair_info must carry the stamp of its pair)')
            self._release_waiting()       # matched without skew compensation (counted)

    def _pair_times_of(self, msg):
        # Without its pair_info a pair has neither a skew nor a left acquisition time (the
        # header stamp is the pair's midpoint) nor FFC flags: nothing is corrected, and the
        # next pair has no usable previous time either.
        with self._pair_times_lock:
            return self.pair_times.pop(stamp_key(msg), (None, None, (False, False)))

    def _keep_skipped_for_skew(self, left_msg, right_msg, left_info, right_info, _arrival):
        """
        Give a pair dropped as stale to the skew compensation as its previous frames.

        The compensation tracks each moving feature from the previous pair's images to this
        pair's (``SkewCompensator``). When the matcher is slower than the cameras it drops the
        pairs between two it matches; without their images the motion would be measured over
        two or more periods, which halves the fastest motion tracked, and beyond its
        ``max_period_s`` (0.25 s) not at all. The pair received just before the one about to
        be matched is one period older: its images are kept instead (counted:
        ``stale_kept_for_skew``), with its pair_info. One without its pair_info (no
        acquisition time) or whose images cannot be read is not kept, and counted
        (``stale_not_kept_for_skew``): the previous frames stay the last matched pair's, used
        when they are recent enough. Never raises: the pair after it is matched whatever
        happens here. The dropped pair's FFC flags reach the temporal check too (a frozen
        frame between two matched pairs makes them look static).
        """
        pair_times = self._pair_times_of(left_msg)
        left_time, skew, ffc = pair_times
        if any(ffc):
            self.temporal.previous_ffc = True
        if not self.matcher.config.skew_compensation:
            return
        try:
            if left_time is None:
                raise ValueError('no pair_info')
            left, right = _pair_images(left_msg, right_msg, left_info, right_info)
            model = self._model_for(left_info, right_info)
            self.skew.remember(left, left_time, right, skew, model, ffc,
                               data_mask(left_msg, left), data_mask(right_msg, right))
        except Exception:  # noqa: B902 - never costs the pair matched next
            self.counts['stale_not_kept_for_skew'] += 1
            return
        self.counts['stale_kept_for_skew'] += 1

    def _compensate_skew(self, result, left, right, pair_times, model, bounds, config, valid):
        left_time, skew, ffc = pair_times
        return self.skew.correct(result, left, left_time, skew, model, bounds, right=right,
                                 ffc=ffc, **valid, **compensation_options(config))

    def _model_for(self, left_info, right_info):
        # Built once per calibration, not per message (the rectifier's P rarely changes).
        key = (tuple(left_info.p), tuple(right_info.p))
        model = self._models.get(key)
        if model is None:
            model = StereoModel.from_projection_matrices(left_info.p, right_info.p)
            if len(self._models) >= 4:
                self._models.pop(next(iter(self._models)))
            self._models[key] = model
        return model

    def _on_pair(self, left_msg, right_msg, left_info, right_info):
        self.counts['pairs'] += 1
        messages = (left_msg, right_msg, left_info, right_info, time.monotonic())
        self._release_waiting()           # an older pair goes first, with what it has
        with self._pair_times_lock:
            known = stamp_key(left_msg) in self.pair_times
        if self.config.skew_compensation and self.pair_info_seen and not known:
            self.counts['waited_for_pair_info'] += 1
            self._waiting = (time.monotonic(), messages)
            self._stale_timer.reset()
            return
        if known:
            self.last_pair_without_pair_info = False
        self._submit(messages)

    def _match_pair(self, left_msg, right_msg, left_info, right_info, arrival):
        try:
            left, right = _pair_images(left_msg, right_msg, left_info, right_info)
            model = self._model_for(left_info, right_info)
            matcher = self.matcher
            matcher.model = model
            valid = {'left_valid': data_mask(left_msg, left),
                     'right_valid': data_mask(right_msg, right)}
            result = matcher.match(left, right, **valid)
            pair_times = self._pair_times_of(left_msg)
            # The matcher's own configuration: a live change may replace self.config meanwhile.
            if matcher.config.skew_compensation:
                result = self._compensate_skew(result, left, right, pair_times, model,
                                               matcher.disparity_bounds(),
                                               matcher.config, valid)
            if matcher.config.temporal_tolerance_px > 0:
                self.temporal.tolerance_px = matcher.config.temporal_tolerance_px
                stamp = left_msg.header.stamp
                # Filled as the matcher fills it: a border of 0 would lower the noise level of
                # changed_windows and call static windows changed (a review: 70 % with a 3-px
                # border), which the check then leaves unchecked.
                result = self.temporal.check(result, fill_invalid(left, valid['left_valid']),
                                             stamp.sec + stamp.nanosec * 1e-9, model,
                                             ffc=any(pair_times[2]))
        except ValueError as error:
            self.counts['dropped_bad_input'] += 1
            self.last_error = self.last_drop_reason = str(error)
            return
        self.last_error = ''              # the state is the latest pair's: a good one clears it
        header = left_msg.header
        points = result.points if result.points is not None else np.zeros((0, 3))
        # The intensity of the pixel each point lies on (its feature's, or its structure's).
        intensity = left[np.clip(np.rint(result.y_point).astype(int), 0, left.shape[0] - 1),
                         np.clip(np.rint(result.x_point).astype(int), 0, left.shape[1] - 1)] \
            if len(result) else np.zeros(0)
        self.points_pub.publish(conversions.point_cloud(header, points, result.disparity,
                                                        result.similarity, intensity,
                                                        result.confidence,
                                                        (result.x_left, result.y)))
        config = matcher.config
        low, high = matcher.disparity_bounds()
        self.disparity_pub.publish(conversions.disparity_image(
            header, left.shape, result.x_left, result.y, result.disparity, model.fx,
            model.baseline, max(low, config.disparity_min), min(high, config.disparity_max),
            (config.poc_window // 2, config.poc_window // 2,
             left.shape[1] - 2 * (config.poc_window // 2),
             left.shape[0] - 2 * (config.poc_window // 2)), model.disparity_offset))
        self.counts['matched'] += 1
        if not len(result):
            self.counts['empty_clouds'] += 1
        done = time.monotonic()
        self.frequency.tick(done)
        self.processing_times = (self.processing_times + [done - arrival])[-50:]
        # Latency from the stamp, on the node clock (sim time under use_sim_time): only where
        # the stamp is on this clock (a bag replayed without /clock has old stamps).
        latency = self.get_clock().now().nanoseconds * 1e-9 - \
            (header.stamp.sec + header.stamp.nanosec * 1e-9)
        if 0.0 <= latency <= STAMP_LATENCY_PLAUSIBLE_S:
            self.latencies = (self.latencies + [latency])[-50:]
        else:
            self.counts['stamps_not_on_node_clock'] += 1
        self.last_result = result

    def _publish_diagnostics(self):
        level, summary, values = self.frequency.values(time.monotonic())
        values.update({f'pairs {k}': v for k, v in self.counts.items()})
        values['kernels'] = 'compiled' if use_compiled(self.config.kernels) else 'numpy'
        values['kernels start-up (s)'] = round(self.kernel_warm_up_s, 3)
        values['pairs dropped by sync (left, right, left info, right info)'] = \
            ', '.join(map(str, self.sync.dropped))
        if self.last_pair_info_problem:
            values['pair_info: last problem (pair matched without skew compensation)'] = \
                self.last_pair_info_problem
        if self.latencies:
            values['latency from stamp, node clock, median (ms)'] = \
                round(1e3 * float(np.median(self.latencies)), 2)
        if self.processing_times:
            values['time from arrival to points2, median (ms)'] = \
                round(1e3 * float(np.median(self.processing_times)), 2)
        if self.last_drop_reason:
            values['last dropped pair'] = self.last_drop_reason
        result = self.last_result
        if result is not None:
            values.update(result.counts)
            values.update({f'skew {k}': v for k, v in self.skew.counts.items()})
            values.update({f'temporal {k}': v for k, v in self.temporal.counts.items()})
            values.update({f'time {k} (ms)': round(v, 2) for k, v in
                           result.timings_ms.items()})
        if result is not None and not len(result) and level == diagnostics.OK:
            level, summary = diagnostics.WARN, 'the last pair gave no point (see the rejections)'
        if self.last_pair_without_pair_info and level != diagnostics.ERROR:
            level, summary = diagnostics.WARN, 'the last pair was matched without skew ' \
                f'compensation: {self.last_pair_info_problem}'
        stalled = self.sync_watch.recent(self.counts['pairs'])
        if stalled:
            level, summary = diagnostics.ERROR, sync_drop_message(stalled, self.sync_topics)
        if self.last_error:
            level, summary = diagnostics.ERROR, f'dropping pairs: {self.last_error}'
        status = diagnostics.status(diagnostics.status_name(self, 'ST matching'), 'st_stereo',
                                    level, summary, values)
        diagnostics.publish(self, self.diagnostics_pub, [status])


def main(args=None):
    """Run the matcher node."""
    return spin_node(MatcherNode, args)
