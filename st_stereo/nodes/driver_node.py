"""
``lepton_driver``: two Leptons -> one synchronised raw pair.

Sources: ``sim`` (two simulated cameras looking at a textured plane at ``sim_depth`` metres),
``capture`` (two raw capture files), ``spi`` (two spidev devices, CCI on two I2C buses),
``purethermal`` (two boards by serial number) and ``bag`` (the raw image topics of a bag).
Publishes ``left/image_raw``, ``right/image_raw`` (mono16 raw counts, never rescaled) and
``left/camera_info``, ``right/camera_info`` from camera_calibration YAML (file:// or
package:// URLs), one identical stamp per pair, and ``pair_info`` (diagnostic_msgs/
DiagnosticArray with the pair's stamp: both cameras' acquisition times, their skew, FFC flags);
every Lepton counter, the pairing and the camera telemetry go to ``/diagnostics``. Services:
``trigger_ffc`` (std_srvs/Trigger) and ``left/set_camera_info``, ``right/set_camera_info``
(sensor_msgs/SetCameraInfo).

Live cameras (``spi``, ``purethermal``) are each read by their own thread
(``st_stereo.lepton.stream.CameraStream``), which clocks the camera continuously and restarts it
with back-off when it fails; a pairing thread pairs the frames and publishes. Acquisition times
are ``time.monotonic()`` at packet 0 of a unique frame (SPI) or when V4L2 returned it
(PureThermal), and are mapped onto the node clock when a pair is published, so a wall-clock
step moves stamps but never pairing. Recorded and simulated sources run on their own clocks in
one thread.
"""

import collections
import queue
import threading
import time

from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo
from st_stereo.core.calibration.files import calibration_from_camera_info, \
    load_calibration, save_calibration
from st_stereo.lepton.assembler import LeptonCounters
from st_stereo.lepton.cci import CciError, CMD_AGC_ENABLE
from st_stereo.lepton.packets import UNIQUE_FRAME_HZ
from st_stereo.lepton.pairing import pair_ffc_from_values, pair_info_values, PairFfcFlags, \
    PairSynchronizer, SKEW_KEY
from st_stereo.lepton.purethermal import PureThermalError
from st_stereo.lepton.reader import EndOfStream, LeptonReader
from st_stereo.nodes import conversions, diagnostics
from st_stereo.nodes.node_parameters import DEPRECATED_DRIVER_PARAMETERS, DRIVER_PARAMETERS, \
    SIDES
from st_stereo.nodes.parameters import declare_node_parameters
from st_stereo.nodes.runtime import RELIABLE, spin_node, with_default_namespace
from st_stereo.package_data import resolve_url
from std_msgs.msg import Header
from std_srvs.srv import Trigger

LIVE_SOURCES = ('spi', 'purethermal')
RECORDED_SOURCES = ('bag', 'capture')      # replay_wait holds them for their consumers
REPLAY_SETTLE_S = 0.3       # after this side sees its subscribers, for theirs to see it
EXIT_LINGER_S = 0.5         # exit_at_end: before and after the final status
ZERO_STAMPED = "images stamped 0 (the bag's receive time used)"


class DriverNode(Node):
    """Thin wrapper: Lepton readers + pairing -> image / camera_info messages."""

    def __init__(self, **kwargs):
        super().__init__('lepton_driver', **with_default_namespace(kwargs))
        declare_node_parameters(self, DRIVER_PARAMETERS, DEPRECATED_DRIVER_PARAMETERS)
        self.add_on_set_parameters_callback(self._on_parameters)
        value = self._value
        self.source = value('source')
        self.publish_wall_times = {}
        self.telemetry = value('telemetry')
        self.max_delta = value('max_pair_delta')
        self.duration = diagnostics.non_negative_number(
            'duration', value('duration'), 'seconds >= 0 (0: until the source ends)')
        self.replay_wait = diagnostics.non_negative_number('replay_wait', value('replay_wait'))
        self.replay_rate = diagnostics.non_negative_number(
            'replay_rate', value('replay_rate'), 'a speed factor >= 0 (0: as fast as read)')
        self.replay_subscribers = value('replay_subscribers')
        self.exit_at_end = bool(value('exit_at_end'))
        if isinstance(self.replay_subscribers, bool) or \
                not isinstance(self.replay_subscribers, int) or self.replay_subscribers < 1:
            raise ValueError(f'replay_subscribers: expected an integer >= 1, got '
                             f'{self.replay_subscribers!r}')
        self.sim_depth = value('sim_depth')
        self.sim_texture = value('sim_texture')
        captures = [value(f'{side}_capture') for side in SIDES]
        devices = [value(f'{side}_device') for side in SIDES]
        buses = [value(f'{side}_i2c_bus') for side in SIDES]
        spi_hz = value('spi_hz')
        self.camera_names = [value(f'{side}.camera_name') for side in SIDES]
        self.info_urls = [value(f'{side}.camera_info_url') for side in SIDES]
        self.frame_ids = [value(f'{side}.frame_id') for side in SIDES]
        self.calibrations = [self._load_calibration(url) for url in self.info_urls]
        self.live = self.source in LIVE_SOURCES
        self.boot_timeout = value('boot_timeout')
        self.give_up_after = value('give_up_after')
        self.exit_code = 0
        overriding = QoSOverridingOptions.with_default_policies()
        self.image_pubs = [self.create_publisher(Image, f'{side}/image_raw', RELIABLE,
                                                 qos_overriding_options=overriding)
                           for side in SIDES]
        self.info_pubs = [self.create_publisher(CameraInfo, f'{side}/camera_info', RELIABLE,
                                                qos_overriding_options=overriding)
                          for side in SIDES]
        self.pair_info_pub = self.create_publisher(DiagnosticArray, 'pair_info', RELIABLE,
                                                   qos_overriding_options=overriding)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_service(Trigger, 'trigger_ffc', self._trigger_ffc)
        for index, side in enumerate(SIDES):
            self.create_service(
                SetCameraInfo, f'{side}/set_camera_info',
                lambda request, response, i=index: self._set_camera_info(i, request, response))
        self.pairing = PairSynchronizer(self.max_delta, min_period=0.1)
        self.pair_ffc = PairFfcFlags()      # an FFC on a frame not paired flags the next pair
        self.frequency = diagnostics.FrequencyTracker(UNIQUE_FRAME_HZ)
        self.camera_rates = [diagnostics.FrequencyTracker(UNIQUE_FRAME_HZ) for _ in SIDES]
        self.recent_skews = collections.deque(maxlen=256)
        self.inexact_drops = [0, 0]
        self._lost_reported = [0, 0]
        self.ffc_pairs = 0
        self.recorded_pair_info = None     # source bag: what the bag's pair_info topic says
        self.bag_notes = []                # source bag: what reading it had to work around
        self.zero_stamps_said = False      # source bag: images stamped 0 logged once
        self.replay_started_without = []   # bag, capture: topics short of subscribers at start
        self.published = 0
        self.last_telemetry = [None, None]
        self.finished = threading.Event()
        self.last_error = ''
        self.started = time.monotonic()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        if self.live:
            self.readers, self.cameras = [None, None], [None, None]
            self._start_live(devices, buses, spi_hz)
        else:
            self.streams = None
            self.readers, self.cameras = self._open_source(captures)
            self._thread = threading.Thread(target=self._run, name='lepton_reader',
                                            daemon=True)
            self._thread.start()
        # On the steady clock: under use_sim_time a replay without /clock would stop them.
        self.create_timer(1.0, self._publish_diagnostics,
                          clock=Clock(clock_type=ClockType.STEADY_TIME))

    def camera_counters_list(self):
        """Each camera's LeptonCounters (live cameras across restarts, else the reader's)."""
        if self.live:
            return list(self.camera_counters)
        return [reader.counters for reader in self.readers]

    def _value(self, name):
        return self.get_parameter(name).value

    def _on_parameters(self, parameters):
        # Read-only parameters never get here: rclpy refuses them first ("Trying to set a
        # read-only parameter"; their descriptors' additional_constraints say why).
        # max_pair_delta applies to the next pair.
        for parameter in parameters:
            if parameter.name == 'max_pair_delta':
                if not 0.0 < parameter.value <= 0.1:
                    return SetParametersResult(
                        successful=False, reason=f'max_pair_delta: expected 0 < seconds <= '
                                                 f'0.1, got {parameter.value!r}')
        for parameter in parameters:
            if parameter.name == 'max_pair_delta':
                self.max_delta = self.pairing.max_delta = float(parameter.value)
        return SetParametersResult(successful=True)

    def _load_calibration(self, url):
        path = resolve_url(url)
        calibration = load_calibration(path)      # CalibrationError names file and field
        for note in calibration.notes:
            self.get_logger().warning(note)
        if (calibration.width, calibration.height) != (80, 60):
            raise ValueError(f'{path}: image size {calibration.width}x{calibration.height}, '
                             f'the Lepton 2 is 80x60')
        return calibration

    def _open_source(self, captures):
        telemetry = self.telemetry
        if self.source == 'sim':
            from st_stereo.core.triangulation import StereoModel
            from st_stereo.lepton.simulator import LeptonSimulator
            from st_stereo.sim.plane import plane_scene_sources
            model = StereoModel.from_projection_matrices(self.calibrations[0].projection,
                                                         self.calibrations[1].projection)
            sources = plane_scene_sources(model, self.sim_depth, self.sim_texture or None)
            cameras = [LeptonSimulator(sources[0], telemetry=telemetry, drift_ppm=30.0,
                                       phase_s=0.004, seed=1, keep_intended=False),
                       LeptonSimulator(sources[1], telemetry=telemetry, drift_ppm=-20.0,
                                       phase_s=0.011, seed=2, keep_intended=False)]
            readers = [LeptonReader(camera, telemetry=telemetry) for camera in cameras]
            return readers, cameras
        if self.source == 'capture':
            from st_stereo.lepton.capture import read_capture, replay_reader
            readers = []
            for path, side in zip(captures, SIDES):
                if not path:
                    raise ValueError(f'source capture: parameter {side}_capture is empty')
                capture = read_capture(path)
                if capture[3]:
                    self.get_logger().warning(
                        f'{path}: {capture[3]} bytes of damaged records passed over')
                # The mode a capture says, or the one its data show (not the parameter).
                reader, _, mode = replay_reader(capture, path)
                self.get_logger().info(f'{path}: telemetry {mode}')
                readers.append(reader)
            return readers, [None, None]
        if self.source == 'bag':
            from st_stereo.nodes.bag_source import open_bag_sides, RecordedPairInfo
            if not self._value('bag'):
                raise ValueError('source bag: parameter bag (the rosbag2 directory or file to '
                                 'replay) is empty')
            # Images of a recorded pair share its stamp: the skew is only in its pair_info.
            namespace = self._value('bag_namespace')
            self.recorded_pair_info = RecordedPairInfo(self._value('bag'), namespace)
            # A recording that did not end is read as far as it goes: said once, and kept in
            # the diagnostics.
            self.bag_notes = self.recorded_pair_info.notes
            for note in self.bag_notes:
                self.get_logger().warning(note)
            sides = open_bag_sides(self._value('bag'), namespace)
            if self._value('bag_camera_info'):
                self._use_recorded_calibrations(self._value('bag'), namespace)
            return sides, [None, None]
        raise ValueError(f'source: expected sim, capture, spi, purethermal or bag, got '
                         f'{self.source!r}')

    def _use_recorded_calibrations(self, bag, namespace):
        """Publish the bag's own camera_info (its first of each camera), if it has them."""
        from st_stereo.bag_streams import recorded_calibrations
        try:
            recorded = recorded_calibrations(bag, namespace)
        except ValueError as error:      # no camera_info in the bag (or not a usable one)
            self.get_logger().info(f'{error}: publishing the camera_info_url calibrations '
                                   f'({", ".join(self.info_urls)})')
            return
        for calibration, side in zip(recorded, SIDES):
            if (calibration.width, calibration.height) != (80, 60):
                raise ValueError(f'{bag}: {side}/camera_info is {calibration.width}x'
                                 f'{calibration.height}, the Lepton 2 is 80x60')
        differ = [side for side, own, given in zip(SIDES, recorded, self.calibrations)
                  if not (np.array_equal(own.projection, given.projection) and
                          np.array_equal(own.camera_matrix, given.camera_matrix) and
                          np.array_equal(own.distortion, given.distortion) and
                          np.array_equal(own.rectification, given.rectification))]
        self.calibrations = list(recorded)
        self.get_logger().info(
            f"{bag}: publishing the bag's own camera_info" +
            (f' (not the camera_info_url of {" and ".join(differ)}: bag_camera_info false '
             f'for those)' if differ else ''))

    # --- live cameras: a thread per camera, a pairing thread --------------------------------
    def _start_live(self, devices, buses, spi_hz):
        from st_stereo.lepton import stream
        from st_stereo.lepton.spi import MAX_HZ, MIN_HZ
        if self.source == 'spi' and not MIN_HZ <= spi_hz <= MAX_HZ:
            raise ValueError(f'spi_hz: expected {MIN_HZ} to {MAX_HZ} Hz, got {spi_hz} (a '
                             f'frame must be clocked out well within one 37.9 ms period)')
        self.camera_counters = [LeptonCounters() for _ in SIDES]
        self._frames = queue.Queue(maxsize=16)
        self.queue_drops = [0, 0]
        logger = self.get_logger()
        reader_mode = self._value('spi_reader')
        if reader_mode not in ('process', 'thread'):
            raise ValueError(f'spi_reader: expected process or thread, got {reader_mode!r}')
        self.streams = []
        for index, side in enumerate(SIDES):
            counters = self.camera_counters[index]
            if self.source == 'spi':
                arguments = {'device': devices[index], 'spi_hz': spi_hz,
                             'i2c_bus': buses[index], 'telemetry': self.telemetry,
                             'boot_timeout_s': self.boot_timeout}
                if reader_mode == 'process':
                    self.streams.append(stream.ProcessCameraStream(
                        side, arguments, self._on_frame, self._on_fatal, counters,
                        log=logger.warning))
                    continue
                opener = (lambda a=arguments, c=counters: stream.open_spi_camera(
                    counters=c, log=logger.warning, **a))
            else:
                opener = (lambda side=side, c=counters: stream.open_purethermal_camera(
                    self._value(f'{side}_serial'), self._value(f'{side}_video_device'), c))
            self.streams.append(stream.CameraStream(side, opener, self._on_frame,
                                                    self._on_fatal, log=logger.warning))
        self._thread = threading.Thread(target=self._pair_live, name='lepton_pairing',
                                        daemon=True)
        self._thread.start()
        for camera_stream in self.streams:
            camera_stream.start()

    def _on_frame(self, side, frame):
        # Called by a camera's reading thread: hand over and return at once.
        try:
            self._frames.put_nowait((side, frame))
        except queue.Full:
            self.queue_drops[SIDES.index(side)] += 1

    def _on_fatal(self, side, error):
        self._fail(f'{side} camera thread stopped: {type(error).__name__}: {error}')

    def _fail(self, message):
        """End the node (non-zero exit, for respawn): a camera cannot recover; say why."""
        if self._stop.is_set():
            return                          # shutting down: readers ending is expected
        self.last_error = message
        self.exit_code = 1
        self.get_logger().fatal(f'{message}; shutting down')
        self._stop.set()
        self.finished.set()
        self.context.try_shutdown()

    def _pair_live(self):
        while not self._stop.is_set():
            try:
                side, frame = self._frames.get(timeout=0.2)
            except queue.Empty:
                continue
            index = SIDES.index(side)
            self.camera_rates[index].tick(time.monotonic())
            self.last_telemetry[index] = frame.telemetry
            self.pair_ffc.seen(side, frame)       # an FFC seen on a frame not paired counts
            if not frame.stamp_exact:
                self.inexact_drops[index] += 1     # its acquisition time is not known
                continue
            try:
                for pair in self.pairing.push(side, frame):
                    self._publish_pair(pair, live=True)
            except Exception as error:   # noqa: B902 - never a silent dead thread
                if not self._stop.is_set() and self.context.ok():
                    self._fail(f'publishing a pair failed: {type(error).__name__}: {error}')
                break                    # shutting down (Ctrl-C): the context is gone
        self.finished.set()

    # --- recorded and simulated sources: one thread on their own clocks ----------------------
    def _wait_for_subscribers(self):
        """
        Hold a recorded source until its consumers are there (``replay_wait``).

        A node started beside the driver (launch, another terminal) discovers its publishers
        within a second or so, and a reliable topic's messages published before that are
        lost to it, uncounted: a replay would lose its first pairs. Live cameras cannot wait.
        """
        if self.source not in RECORDED_SOURCES or not self.replay_wait:
            return
        publishers = self.image_pubs + self.info_pubs
        deadline = time.monotonic() + self.replay_wait
        while not self._stop.is_set():
            missing = [pub.topic_name for pub in publishers
                       if pub.get_subscription_count() < self.replay_subscribers]
            if not missing:
                # The subscriber's side matches this publisher moments after this side does.
                self._stop.wait(REPLAY_SETTLE_S)
                self.get_logger().info(f'{self.source}: replay starts: every image_raw and '
                                       f'camera_info topic has {self.replay_subscribers} '
                                       f'subscriber(s)')
                return
            if time.monotonic() >= deadline:
                self.replay_started_without = missing
                self.get_logger().warning(
                    f'{self.source}: replay starts after {self.replay_wait:g} s (replay_wait) '
                    f'with fewer than {self.replay_subscribers} subscriber(s) on '
                    f'{", ".join(missing)}')
                return
            self._stop.wait(0.02)

    def _replay_pace(self):
        """
        Return ``(speed, origin)``: frames are released at ``speed`` x the pace of their times.

        The simulated cameras run at real time; a bag and a capture with recorded read times
        at ``replay_rate`` times their recorded pace from their first frame (``origin``); 0
        (``replay_rate`` 0, or a capture of plain SPI bytes, whose times are only its byte
        count at the SPI clock): as fast as the frames are read.
        """
        if self.source == 'sim':
            return 1.0, 0.0
        if self.source == 'bag':
            return self.replay_rate, 0.0     # its sides' times count from its first frame
        if self.source == 'capture' and self.replay_rate and \
                all(getattr(reader.transport, 'times', None) is not None
                    for reader in self.readers):
            return self.replay_rate, min(reader.transport.now() for reader in self.readers)
        return 0.0, 0.0

    def _run(self):
        self._wait_for_subscribers()
        clock_start = self.get_clock().now().nanoseconds * 1e-9
        wall_start = time.monotonic()
        speed, origin = self._replay_pace()
        base = None
        ended = 'end of the source'
        try:
            while not self._stop.is_set():
                # Read from the camera that is behind, so the streams stay interleaved.
                side = min(range(2), key=lambda i: self.readers[i].transport.now())
                reader = self.readers[side]
                frame = reader.read_frame(timeout_s=1.0)
                if speed:
                    # A frame is released when the wall clock reaches the (simulated or
                    # recorded) moment its last packet was read, at ``speed`` times that pace;
                    # a bag's frame at its stamp (its transport's time is the next frame's).
                    moment = reader.last_time if self.source == 'bag' else \
                        reader.transport.now()
                    lag = (moment - origin) / speed - (time.monotonic() - wall_start)
                    if 0 < lag < float('inf'):       # inf: that side's recording has ended
                        time.sleep(lag)
                if frame is None:
                    continue
                self.last_telemetry[side] = frame.telemetry
                self.camera_rates[side].tick(time.monotonic())
                if base is None:
                    base = frame.stamp
                if self.duration and frame.stamp - base > self.duration:
                    ended = f'duration {self.duration:g} s reached'
                    break
                self.pair_ffc.seen(SIDES[side], frame)
                if not frame.stamp_exact:
                    self.inexact_drops[side] += 1
                    continue
                for pair in self.pairing.push(SIDES[side], frame):
                    restamp = self.source in ('sim', 'capture')
                    self._publish_pair(pair, clock_start=clock_start if restamp else 0.0,
                                       base=base)
        except EndOfStream:
            pass
        except Exception as error:      # noqa: B902 - reported, the node stays up
            if self.context.ok() and not self._stop.is_set():   # not a shutdown
                self.last_error = f'{type(error).__name__}: {error}'
                self.get_logger().error(f'reading stopped: {self.last_error}')
        finally:
            self.finished.set()
        if self.last_error or self._stop.is_set():
            return
        if not (self.exit_at_end and self.source in RECORDED_SOURCES):
            self.get_logger().info(f'{self.source}: {ended}: {self.published} pairs published '
                                   f'(the node stays up; its status says finished)')
            return
        # The last pair's reliable messages and the final status go out, and nodes of the same
        # process (stereo_pipeline) finish that pair, before the process ends.
        self._stop.wait(EXIT_LINGER_S)
        self._publish_diagnostics()
        self.exit_code = 0 if self.published else 1
        self.get_logger().info(f'{self.source}: {ended}: {self.published} pairs published; '
                               f'exiting (exit_at_end, code {self.exit_code})')
        self._stop.wait(EXIT_LINGER_S)
        self.context.try_shutdown()

    def _to_stamp_s(self, acquired, live, clock_start, base):
        """Stamp (node-clock seconds) of an acquisition time of the source."""
        if live:
            # Monotonic acquisition time -> node clock: the clock's reading now, minus the
            # age of the acquisition.
            now_s = self.get_clock().now().nanoseconds * 1e-9
            return now_s - (time.monotonic() - acquired)
        # Simulated streams and raw captures are re-stamped onto the node clock from their
        # start; a bag keeps its recorded stamps.
        return clock_start + (acquired - base) if clock_start else acquired

    def _publish_pair(self, pair, live=False, clock_start=0.0, base=0.0):
        stamp_s = self._to_stamp_s(pair.stamp, live, clock_start, base)
        header = Header()
        header.stamp = _stamp_msg(stamp_s)
        if not live and not clock_start and pair.left.stamp_ns is not None and \
                pair.right.stamp_ns is not None:
            # A bag's pair keeps its recorded stamp to the nanosecond (the images' midpoint,
            # their shared stamp when the suite recorded them).
            header.stamp = _stamp_of_ns((pair.left.stamp_ns + pair.right.stamp_ns) // 2)
        for index, frame in enumerate((pair.left, pair.right)):
            header_side = Header(stamp=header.stamp, frame_id=self.frame_ids[index])
            self.image_pubs[index].publish(conversions.image_to_msg(frame.pixels, header_side))
            with self._lock:
                calibration = self.calibrations[index]
            self.info_pubs[index].publish(conversions.camera_info_from_calibration(
                calibration, header_side))
        skew = self._publish_pair_info(pair, header, live, clock_start, base)
        self.published += 1
        now = time.time()
        self.frequency.tick(time.monotonic())
        self.recent_skews.append(skew)
        # Wall time each stamp went out (bag stamps are not wall time): for latency monitors.
        self.publish_wall_times[(header.stamp.sec, header.stamp.nanosec)] = now
        while len(self.publish_wall_times) > 256:
            self.publish_wall_times.pop(next(iter(self.publish_wall_times)))

    def _publish_pair_info(self, pair, header, live, clock_start, base):
        ffc = list(self.pair_ffc.of_pair(pair))
        values = None
        if self.recorded_pair_info is not None:
            # A bag's pair: republish what the driver that recorded it said (its skew), or say
            # that the bag did not have it (the skew of the image stamps is then all there is).
            values = self.recorded_pair_info.values(header.stamp.sec * 1_000_000_000 +
                                                    header.stamp.nanosec)
            if values is not None:
                ffc = list(pair_ffc_from_values(values))
        if values is None:
            values = pair_info_values(
                pair.skew, [self._to_stamp_s(frame.stamp, live, clock_start, base)
                            for frame in (pair.left, pair.right)],
                [pair.left.index, pair.right.index], ffc)
        self.ffc_pairs += any(ffc)
        level = diagnostics.WARN if any(ffc) else diagnostics.OK
        message = 'a camera is in or just out of FFC' if any(ffc) else 'ok'
        array = DiagnosticArray(header=header)
        array.status = [diagnostics.status(diagnostics.status_name(self, 'stereo pair'),
                                           self.source, level, message, values)]
        self.pair_info_pub.publish(array)
        return float(values[SKEW_KEY]) * 1e-3

    # --- services ---------------------------------------------------------------------------
    def _ffc_actions(self):
        """One callable per camera that starts an FFC, or None where there is no control."""
        if not self.live:
            return [camera.run_ffc if camera is not None else None for camera in self.cameras]
        return [camera_stream.run_ffc for camera_stream in self.streams]

    def _trigger_ffc(self, request, response):
        done, failed = [], []
        for side, action in zip(SIDES, self._ffc_actions()):
            if action is None:
                failed.append(f'{side}: no camera control (source {self.source}, or the camera '
                              f'is not open)')
                continue
            try:
                action()
                done.append(side)
            except (CciError, OSError, PureThermalError, ValueError) as error:
                failed.append(f'{side}: {error}')
            except Exception as error:   # noqa: B902 - a service call never ends the node
                failed.append(f'{side}: {type(error).__name__}: {error}')
        response.success = not failed
        response.message = '; '.join(([f'FFC started on {" and ".join(done)}'] if done else [])
                                     + failed)
        if failed:
            self.get_logger().warning(f'trigger_ffc: {response.message}')
        return response

    def _set_camera_info(self, index, request, response):
        url = self.info_urls[index]
        try:
            calibration = calibration_from_camera_info(request.camera_info,
                                                       self.camera_names[index])
            if (calibration.width, calibration.height) != (80, 60):
                raise ValueError(f'camera_info is {calibration.width}x{calibration.height}, '
                                 f'the Lepton 2 is 80x60')
            if not url.startswith('file://'):
                raise ValueError(f'{url}: only file:// URLs can be written')
            save_calibration(calibration, resolve_url(url))
        except (OSError, ValueError) as error:
            response.success = False
            response.status_message = str(error)
            return response
        with self._lock:
            self.calibrations[index] = calibration
        response.success = True
        response.status_message = f'stored in {resolve_url(url)}'
        return response

    # --- diagnostics ------------------------------------------------------------------------
    def _publish_diagnostics(self):
        now = time.monotonic()
        if self.live and self.give_up_after > 0 and not self._stop.is_set():
            for side, camera_stream in zip(SIDES, self.streams):
                silent = min(camera_stream.seconds_since_frame(now), now - self.started)
                if silent > self.give_up_after:
                    self._fail(f'{side} camera: no frame for {silent:.0f} s (give_up_after '
                               f'{self.give_up_after:g} s; last error: '
                               f'{camera_stream.counters.last_error or "none"})')
                    return
        statuses = [self._pairs_status(now)]
        for index in range(len(SIDES)):
            statuses.append(self._camera_status(index, now))
        diagnostics.publish(self, self.diagnostics_pub, statuses)

    def _pairs_status(self, now):
        level, summary, values = self.frequency.values(now)
        pairing = self.pairing.counters
        skews = sorted(abs(skew) for skew in list(self.recent_skews))  # list(): one step
        values.update({
            'pairs': pairing.pairs, 'pairs with a camera in FFC': self.ffc_pairs,
            'frames dropped (left unmatched)': pairing.dropped_left,
            'frames dropped (right unmatched)': pairing.dropped_right,
            'frames dropped (queue full)': pairing.overflow_left + pairing.overflow_right,
            'frames dropped (stamp went back)': pairing.backward_left + pairing.backward_right,
            'pair skew mean (ms)': round(1e3 * pairing.skew_mean, 2) if pairing.pairs else 'n/a',
            'pair skew max (ms)': round(1e3 * pairing.skew_abs_max, 2),
            'pair |skew| median, last 256 (ms)':
                round(1e3 * skews[len(skews) // 2], 2) if skews else 'n/a',
            'max_pair_delta (ms)': round(1e3 * self.max_delta, 2)})
        values['frames dropped (acquisition time unknown: first after a gap)'] = \
            sum(self.inexact_drops)
        if self.live:
            values['frames dropped (handover queue full)'] = sum(self.queue_drops)
        if self.source in RECORDED_SOURCES:
            values['replay started short of subscribers on'] = \
                ', '.join(self.replay_started_without) or 'none'
        if self.bag_notes:
            values['bag notes (what reading it worked around)'] = ' | '.join(self.bag_notes)
        if self.source == 'bag':
            zero = sum(getattr(reader, 'zero_stamped', 0) for reader in self.readers)
            values[ZERO_STAMPED] = zero
            if zero and not self.zero_stamps_said:
                self.zero_stamps_said = True
                self.get_logger().warning(f'{self._value("bag")}: images stamped 0: they get '
                                          f'the time the recorder received them (counted: '
                                          f'{ZERO_STAMPED})')
        if self.recorded_pair_info is not None:
            values.update(self.recorded_pair_info.counts)
            if self.recorded_pair_info.last_problem:
                values['recorded pair_info: last problem'] = self.recorded_pair_info.last_problem
        if self.finished.is_set() and not self.live and not self.last_error:
            level = diagnostics.OK if self.published else diagnostics.ERROR
            summary = f'finished: {self.published} pairs published' if self.published else \
                'finished: the source gave no pair'
        if self.last_error:
            level, summary = diagnostics.ERROR, self.last_error
        return diagnostics.status(diagnostics.status_name(self, 'stereo pairs'), self.source,
                                  level, summary, values)

    def _camera_status(self, index, now):
        side = SIDES[index]
        if self.live:
            camera_stream = self.streams[index]
            counters = self.camera_counters[index].as_dict()
            counters.update({f'stream {key}': value for key, value in
                             camera_stream.counters.as_dict().items()
                             if key != 'last_frame_time'})
            reader = camera_stream.reader
            hardware = getattr(getattr(reader, 'transport', None), 'device', f'{side} camera')
            silent = camera_stream.seconds_since_frame(now)
        else:
            reader = self.readers[index]
            counters = reader.counters.as_dict()
            hardware = getattr(reader.transport, 'device', f'{self.source}:{side}')
            silent = 0.0 if counters['unique_frames'] else float('inf')
            if getattr(reader, 'last_problem', ''):
                counters['last frame refused'] = reader.last_problem
        telemetry = self.last_telemetry[index]
        if telemetry is not None:
            counters['FPA temperature (K)'] = telemetry.fpa_temperature_k
            counters['housing temperature (K)'] = telemetry.housing_temperature_k
            counters['FFC state'] = telemetry.ffc_state
            counters['AGC'] = 'on' if telemetry.agc_enabled else 'off'
        rate = self.camera_rates[index].frequency(now)
        counters['unique frames per second'] = round(rate, 3)
        lost = counters['frames_aborted'] + counters['timeouts']
        if not counters['unique_frames'] or silent > 1.0 and not self.finished.is_set():
            level = diagnostics.ERROR
            summary = 'no frames' if not counters['unique_frames'] else \
                f'no frame for {silent:.1f} s'
            if self.live and self.streams[index].counters.last_error:
                summary += f' ({self.streams[index].counters.last_error})'
            elif not self.live and getattr(self.readers[index], 'last_problem', ''):
                summary += f' (last frame refused: {self.readers[index].last_problem})'
        elif self.live and rate < 8.0 and now - self.started > 6.0:
            level, summary = diagnostics.WARN, f'{rate:.2f} unique frames/s, below 8'
        else:
            # WARN while frames are being lost (since the last report), not for ever after.
            recent = lost - self._lost_reported[index]
            level = diagnostics.OK if not recent else diagnostics.WARN
            summary = f'{counters["unique_frames"]} frames, {lost} lost' + \
                (f' ({recent} in the last second)' if recent else '')
        self._lost_reported[index] = lost
        if telemetry is not None and telemetry.agc_enabled and level == diagnostics.OK:
            # The camera's AGC maps the scene to 8 bits: no longer the 14-bit counts that the
            # rectifier's 0 marker, the matcher's noise model and the people stage's warm
            # margin (counts above the background) assume. Said, not refused: the user's call.
            level = diagnostics.WARN
            summary = 'AGC on: 8-bit values, not the 14-bit counts ST expects (disable it ' \
                f'through the CCI: AGC Enable, 0x{CMD_AGC_ENABLE:04X}); ' + summary
        return diagnostics.status(diagnostics.status_name(self, f'{side} camera'), hardware,
                                  level, summary, counters)

    def destroy_node(self):
        """Stop the reading threads and close the devices, then the node."""
        self._stop.set()
        for camera_stream in self.streams or ():
            camera_stream.request_stop()
        for camera_stream in self.streams or ():
            camera_stream.stop()
        self._thread.join(timeout=2.0)
        if not self.live:
            for reader in self.readers or ():
                close = getattr(reader, 'close', None)     # captures hold open files
                if close is not None:
                    close()
        super().destroy_node()


def _stamp_msg(stamp_s):
    """builtin_interfaces/Time of a stamp in seconds (never negative)."""
    return _stamp_of_ns(max(0, int(round(stamp_s * 1e9))))


def _stamp_of_ns(nanoseconds):
    """builtin_interfaces/Time of a stamp in integer nanoseconds."""
    return Time(sec=nanoseconds // 1_000_000_000, nanosec=nanoseconds % 1_000_000_000)


def main(args=None):
    """Run the driver node; exits non-zero when a camera could not recover."""
    return spin_node(DriverNode, args)
