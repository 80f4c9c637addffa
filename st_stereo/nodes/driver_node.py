"""
``lepton_driver``: two Leptons -> one synchronised raw pair.

Sources: ``sim`` (two simulated cameras looking at a textured plane at ``sim_depth`` metres),
``capture`` (two raw capture files), ``spi`` (two spidev devices, CCI on two I2C buses),
``purethermal`` (two boards by serial number) and ``bag`` (the raw image topics of a bag).
Publishes ``left/image_raw``, ``right/image_raw`` (mono16 raw counts, never rescaled) and
``left/camera_info``, ``right/camera_info`` from camera_calibration YAML (file:// or
package:// URLs), one identical stamp per pair; every Lepton counter, the pairing and the
camera telemetry go to ``/diagnostics``. Services: ``trigger_ffc`` (std_srvs/Trigger) and
``left/set_camera_info``, ``right/set_camera_info`` (sensor_msgs/SetCameraInfo).
"""

import os
import pathlib
import threading
import time

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import CameraInfo, Image
from sensor_msgs.srv import SetCameraInfo
from st_stereo.core.camera_calibration import load_calibration, save_calibration
from st_stereo.lepton.pairing import PairSynchronizer
from st_stereo.lepton.reader import EndOfStream, LeptonReader
from st_stereo.nodes import conversions, diagnostics
from st_stereo.nodes.driver_parameters import DRIVER_PARAMETERS, SIDES
from st_stereo.nodes.runtime import spin_node, with_default_namespace
from std_msgs.msg import Header
from std_srvs.srv import Trigger

RELIABLE = QoSProfile(depth=5, reliability=ReliabilityPolicy.RELIABLE)


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


class DriverNode(Node):
    """Thin wrapper: Lepton readers + pairing -> image / camera_info messages."""

    def __init__(self, **kwargs):
        super().__init__('lepton_driver', **with_default_namespace(kwargs))
        for name, default, description in DRIVER_PARAMETERS:
            self.declare_parameter(name, default, ParameterDescriptor(description=description))
        value = self._value
        self.source = value('source')
        self.publish_wall_times = {}
        self.telemetry = value('telemetry')
        self.max_delta = value('max_pair_delta')
        self.duration = value('duration')
        self.sim_depth = value('sim_depth')
        self.sim_texture = value('sim_texture')
        captures = [value(f'{side}_capture') for side in SIDES]
        devices = [value(f'{side}_device') for side in SIDES]
        buses = [value(f'{side}_i2c_bus') for side in SIDES]
        spi_hz = value('spi_hz')
        self.info_urls = [value(f'{side}_camera_info_url') for side in SIDES]
        self.frame_ids = [value(f'{side}_frame_id') for side in SIDES]
        self.calibrations = [self._load_calibration(url) for url in self.info_urls]
        opened = self._open_source(captures, devices, buses, spi_hz)
        self.readers, self.cameras, self.ccis = opened
        overriding = QoSOverridingOptions.with_default_policies()
        self.image_pubs = [self.create_publisher(Image, f'{side}/image_raw', RELIABLE,
                                                 qos_overriding_options=overriding)
                           for side in SIDES]
        self.info_pubs = [self.create_publisher(CameraInfo, f'{side}/camera_info', RELIABLE,
                                                qos_overriding_options=overriding)
                          for side in SIDES]
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_service(Trigger, 'trigger_ffc', self._trigger_ffc)
        for index, side in enumerate(SIDES):
            self.create_service(
                SetCameraInfo, f'{side}/set_camera_info',
                lambda request, response, i=index: self._set_camera_info(i, request, response))
        self.pairing = PairSynchronizer(self.max_delta, min_period=0.1)
        self.frequency = diagnostics.FrequencyTracker(26.4 / 3)
        self.published = 0
        self.last_telemetry = [None, None]
        self.finished = threading.Event()
        self.last_error = ''
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name='lepton_reader', daemon=True)
        self._thread.start()
        self.create_timer(1.0, self._publish_diagnostics)

    def _value(self, name):
        return self.get_parameter(name).value

    def _load_calibration(self, url):
        path = resolve_url(url)
        calibration = load_calibration(path)      # CalibrationError names file and field
        if (calibration.width, calibration.height) != (80, 60):
            raise ValueError(f'{path}: image size {calibration.width}x{calibration.height}, '
                             f'the Lepton 2 is 80x60')
        return calibration

    def _open_source(self, captures, devices, buses, spi_hz):
        telemetry = self.telemetry
        if self.source == 'sim':
            from st_stereo.core.triangulation import StereoModel
            from st_stereo.lepton.simulator import LeptonSimulator
            from st_stereo.tools.sim_scene import plane_scene_sources
            model = StereoModel.from_projection_matrices(self.calibrations[0].projection,
                                                         self.calibrations[1].projection)
            sources = plane_scene_sources(model, self.sim_depth, self.sim_texture or None)
            cameras = [LeptonSimulator(sources[0], telemetry=telemetry, drift_ppm=30.0,
                                       phase_s=0.004, seed=1),
                       LeptonSimulator(sources[1], telemetry=telemetry, drift_ppm=-20.0,
                                       phase_s=0.011, seed=2)]
            readers = [LeptonReader(camera, telemetry=telemetry) for camera in cameras]
            return readers, cameras, [None, None]
        if self.source == 'capture':
            from st_stereo.lepton.capture import read_capture, ReplayTransport
            readers = []
            for path, side in zip(captures, SIDES):
                if not path:
                    raise ValueError(f'source capture: parameter {side}_capture is empty')
                header, data, times = read_capture(path)
                mode = header.get('telemetry', telemetry)
                readers.append(LeptonReader(ReplayTransport(data, times), telemetry=mode,
                                            frame_gap_wait=False, no_video_s=1e9))
            return readers, [None, None], [None, None]
        if self.source == 'bag':
            from st_stereo.nodes.bag_source import open_bag_sides
            return open_bag_sides(self._value('bag')), [None, None], [None, None]
        if self.source == 'purethermal':
            from st_stereo.lepton.purethermal import PureThermalReader
            readers = [PureThermalReader(self._value(f'{side}_serial'),
                                         self._value(f'{side}_video_device')) for side in SIDES]
            return readers, [None, None], [None, None]
        if self.source == 'spi':
            from st_stereo.lepton.cci import LeptonCCI, SMBus2Bus
            from st_stereo.lepton.spi import SpiTransport
            ccis = [LeptonCCI(SMBus2Bus(bus)) for bus in buses]
            readers = [LeptonReader(SpiTransport(device, spi_hz), telemetry=telemetry, cci=cci)
                       for device, cci in zip(devices, ccis)]
            return readers, [None, None], ccis
        raise ValueError(f'source: expected sim, capture, spi, purethermal or bag, got '
                         f'{self.source!r}')

    # --- the reading thread -----------------------------------------------------------------
    def _run(self):
        clock_start = self.get_clock().now().nanoseconds * 1e-9
        wall_start = time.monotonic()
        simulated = self.source in ('sim', 'bag')     # paced at real time
        base = None
        try:
            while not self._stop.is_set():
                # Read from the camera that is behind, so the streams stay interleaved.
                side = min(range(2), key=lambda i: self.readers[i].transport.now())
                reader = self.readers[side]
                frame = reader.read_frame(timeout_s=1.0)
                if simulated:
                    # Pace the simulated cameras at real time: a frame is released when the
                    # wall clock reaches the simulated moment its last packet was read.
                    lag = reader.transport.now() - (time.monotonic() - wall_start)
                    if 0 < lag < float('inf'):       # inf: that side's recording has ended
                        time.sleep(lag)
                if frame is None:
                    continue
                self.last_telemetry[side] = frame.telemetry
                if base is None:
                    base = frame.stamp
                if self.duration and frame.stamp - base > self.duration:
                    break
                for pair in self.pairing.push(SIDES[side], frame):
                    restamp = self.source in ('sim', 'capture')
                    self._publish_pair(pair, clock_start if restamp else 0.0, base)
        except EndOfStream:
            pass
        except Exception as error:      # noqa: B902 - reported, the node stays up
            self.last_error = f'{type(error).__name__}: {error}'
            self.get_logger().error(f'reading stopped: {self.last_error}')
        finally:
            self.finished.set()

    def _publish_pair(self, pair, clock_start, base):
        # Simulated streams and raw captures are re-stamped onto the node clock; SPI and
        # PureThermal stamps are already wall time (read times); a bag keeps its stamps.
        stamp_s = clock_start + (pair.stamp - base) if clock_start else pair.stamp
        header = Header()
        header.stamp.sec = int(stamp_s)
        header.stamp.nanosec = int(round((stamp_s - int(stamp_s)) * 1e9)) % 1_000_000_000
        for index, frame in enumerate((pair.left, pair.right)):
            header_side = Header(stamp=header.stamp, frame_id=self.frame_ids[index])
            self.image_pubs[index].publish(conversions.image_to_msg(frame.pixels, header_side))
            with self._lock:
                calibration = self.calibrations[index]
            self.info_pubs[index].publish(conversions.camera_info_from_calibration(
                calibration, header_side))
        self.published += 1
        now = time.time()
        self.frequency.tick(now)
        # Wall time each stamp went out (bag stamps are not wall time): for latency monitors.
        self.publish_wall_times[(header.stamp.sec, header.stamp.nanosec)] = now
        while len(self.publish_wall_times) > 256:
            self.publish_wall_times.pop(next(iter(self.publish_wall_times)))

    # --- services ---------------------------------------------------------------------------
    def _trigger_ffc(self, request, response):
        done = []
        for camera, cci in zip(self.cameras, self.ccis):
            if cci is not None:
                cci.run_ffc()
                done.append('cci')
            elif camera is not None:
                camera.run_ffc()
                done.append('sim')
        response.success = bool(done)
        response.message = 'FFC started on both cameras' if done else \
            f'source {self.source} has no camera control'
        return response

    def _set_camera_info(self, index, request, response):
        url = self.info_urls[index]
        try:
            calibration = conversions.calibration_from_camera_info(request.camera_info,
                                                                   f'lepton_{SIDES[index]}')
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
        statuses = []
        level, summary, values = self.frequency.values(time.time())
        pairing = self.pairing.counters
        values.update({'pairs': pairing.pairs, 'frames dropped (left unmatched)':
                       pairing.dropped_left, 'frames dropped (right unmatched)':
                       pairing.dropped_right, 'pair skew mean (ms)':
                       round(1e3 * pairing.skew_mean, 2) if pairing.pairs else 'n/a',
                       'pair skew max (ms)': round(1e3 * pairing.skew_abs_max, 2)})
        if self.last_error:
            level, summary = diagnostics.ERROR, self.last_error
        statuses.append(diagnostics.status(f'{self.get_name()}: stereo pairs', self.source,
                                           level, summary, values))
        for index, reader in enumerate(self.readers):
            counters = reader.counters.as_dict()
            hardware = getattr(reader.transport, 'device', f'{self.source}:{SIDES[index]}')
            telemetry = self.last_telemetry[index]
            if telemetry is not None:
                counters['FPA temperature (K)'] = telemetry.fpa_temperature_k
                counters['housing temperature (K)'] = telemetry.housing_temperature_k
                counters['FFC state'] = telemetry.ffc_state
            lost = counters['frames_aborted'] + counters['timeouts']
            level = diagnostics.OK if not lost else diagnostics.WARN
            statuses.append(diagnostics.status(
                f'{self.get_name()}: {SIDES[index]} camera', hardware, level,
                f'{counters["unique_frames"]} frames, {lost} lost', counters))
        diagnostics.publish(self, self.diagnostics_pub, statuses)

    def destroy_node(self):
        """Stop the reading thread, then the node."""
        self._stop.set()
        self._thread.join(timeout=2.0)
        super().destroy_node()


def main(args=None):
    """Run the driver node."""
    spin_node(DriverNode, args)
