"""
A wall-clock rig emulator: two Lepton 2 cameras on real time, for tests and benchmarks.

Unlike ``LeptonSimulator`` (a transport on a virtual clock that the reader drives), each
emulated camera runs in its own process on ``time.monotonic()``, free-running with its own
phase and drift, and is read by the production ``SpiTransport`` through a FIFO with
``os.read``, exactly as ``/dev/spidevB.C`` is read; its CCI answers through the ``smbus2``
stand-in of ``st_stereo.lepton.fakes``. Nothing in the driver knows it is not a rig.

What a camera does (Lepton 2 datasheet behaviour, ``../shared/notes/lepton.md``):

- core frames every ``1 / CORE_FRAME_HZ`` of its own clock; every unique frame is sent three
  times; the telemetry frame counter counts core frames (so copies carry new counts: only
  their pixels show that they are copies); power-up telemetry is off until set over CCI;
- bytes leave the camera only when the host clocks them: the emulator puts one host transfer
  (``transfer_bytes``, the host's spidev ``bufsiz``) into the FIFO when the FIFO is empty, no
  faster than the SPI clock; the FIFO (16 KiB) holds a little over one frame;
- sync is lost, and the camera sends garbage, when a frame is not finished before the next
  one is ready, when a frame is skipped, or when the host pauses more than
  ``max_packet_gap_s`` (about three line periods, 1.5 ms) between transfers inside a frame;
  sync returns only after the host leaves the bus idle for >= 185 ms (stale bytes dropped);
- one SPI controller serves ``/dev/spidevB.0`` and ``/dev/spidevB.1``: the kernel runs one
  transfer at a time, so cameras with the same ``controller`` never transfer at once (one
  camera's long transfer can hold the other's next one past its 1.5 ms);
- boot: the I2C address does not acknowledge for ``nack_s``, then the status register reports
  busy until ``boot_s``; video starts after boot;
- events the tests produce: ``unplug`` (MISO floats high: 0xFF bytes, I2C NACKs), ``replug``
  (a power-up: boot, telemetry off), a failing FFC command, and an FFC (23 frozen core frames,
  then a level jump).

``RigEmulator`` starts both cameras, makes the FIFOs, and records every unique frame each
camera sent (a hash of its pixels and its acquisition time) so tests can check what the driver
published against what the cameras sent. ``RigEmulator.installed()`` puts stand-in ``spidev``
and ``smbus2`` modules first on ``sys.path`` (a directory the emulator writes), so the driver
finds them in its own process and in the reader processes it spawns; each ``SMBus(n)`` opens
its own connection to camera ``n``'s CCI socket.
"""

import collections
import contextlib
import dataclasses
import errno
import fcntl
import json
import math
import multiprocessing
from multiprocessing.connection import Client, Listener
import os
import pathlib
import queue
import shutil
import sys
import tempfile
import termios
import threading
import time

import numpy as np

from st_stereo.lepton.assembler import FrameLayout
from st_stereo.lepton.fakes import pixels_digest, SentFrame
from st_stereo.lepton.packets import (CORE_FRAME_HZ, encode_frame_packets,
                                      make_discard_packet, RAW14_PACKET_BYTES)
from st_stereo.lepton.telemetry import encode_telemetry_row_a

PACKET = RAW14_PACKET_BYTES
RESYNC_IDLE_S = 0.185
F_SETPIPE_SZ = 1031
PIPE_BYTES = 16384                   # a little over one 63-packet frame (10,332 bytes)
FFC_CORE_FRAMES = 23
FFC_LEVEL_JUMP = 25
AUTHKEY = b'st_stereo rig emulator'

_SHIM_SPIDEV = '''"""spidev stand-in of the wall-clock rig emulator (tests and benchmarks only)."""
from st_stereo.lepton.fakes import fake_spidev_module as _make
SpiDev = _make().SpiDev
'''
_SHIM_SMBUS2 = '''"""smbus2 stand-in of the wall-clock rig emulator (tests and benchmarks only)."""
import json as _json
import pathlib as _pathlib
from st_stereo.lepton.emulator import RemoteCci as _RemoteCci
from st_stereo.lepton.fakes import fake_smbus2_module as _make
_BUSES = _json.loads(_pathlib.Path(__file__).with_name('rig_buses.json').read_text())
_module = _make({int(n): (lambda a=a: _RemoteCci(a)) for n, a in _BUSES.items()})
SMBus, i2c_msg = _module.SMBus, _module.i2c_msg
'''


@dataclasses.dataclass
class CameraConfig:
    """One emulated camera."""

    name: str = 'left'
    seed: int = 1
    phase_s: float = 0.004
    drift_ppm: float = 0.0
    spi_hz: float = 16e6
    transfer_bytes: int = 4096       # the host's spidev bufsiz (whole packets per transfer)
    max_packet_gap_s: float = 0.0015
    boot_s: float = 0.8              # power-up to video
    nack_s: float = 0.3              # power-up to the first I2C acknowledge
    start_booting: bool = False      # powered up when the emulator starts (slow boot)
    disparity_px: float = 0.0        # the scene shifted left by this much (a right camera)
    serial: int = 0x1234
    crc_fault_rate: float = 0.0      # probability per core frame of one packet with a bad CRC
    controller: int = 0              # cameras on one SPI controller take turns on the bus


class TimedScene:
    """
    A thermal scene as a function of time: a textured room and a warm blob walking across.

    Every frame has its own temporal noise, so no two unique frames have equal pixels; the
    right camera sees the same scene shifted by ``disparity_px``.
    """

    def __init__(self, disparity_px=0.0, noise_seed=0):
        self.y, self.x = np.mgrid[0:60, 0:80].astype(np.float64)
        self.shift = disparity_px
        self.noise_seed = noise_seed
        rng = np.random.default_rng(12345)           # the same room for both cameras
        self.texture = rng.normal(0.0, 12.0, (60, 200))
        self.texture_x = np.arange(200) - 60.0

    def frame(self, t, index):
        """Return counts (float) at scene time ``t`` s; ``index`` seeds the temporal noise."""
        x = self.x + self.shift
        columns = np.interp(x[0], self.texture_x, np.arange(200))
        lo = np.clip(np.floor(columns).astype(int), 0, 198)
        w = columns - lo
        background = (1 - w) * self.texture[:, lo] + w * self.texture[:, lo + 1]
        background += 8000.0 + 40.0 * np.sin(x / 7.0) + 25.0 * np.cos(self.y / 5.0)
        cx = 40.0 + 28.0 * math.sin(0.6 * t) + self.shift * 0.5
        cy = 30.0 + 8.0 * math.cos(0.4 * t)
        blob = 450.0 * np.exp(-((x - cx) ** 2 / 40.0 + (self.y - cy) ** 2 / 90.0))
        noise = np.random.default_rng((self.noise_seed, index)).normal(0.0, 4.0, (60, 80))
        return background + blob + noise


class _Camera:
    """The state of one emulated camera (runs inside its process)."""

    def __init__(self, config, fd, records, epoch, bus=None):
        from st_stereo.lepton.fakes import FakeCciRegisters
        self.config = config
        self.bus = bus                    # (lock, shared "free at" time) of the controller
        self.fd = fd
        self.records = records
        self.epoch = epoch
        self.period = 1.0 / (CORE_FRAME_HZ * (1.0 + config.drift_ppm * 1e-6))
        # One host transfer; never more than a frame (the reader asks for at most one frame,
        # and the FIFO holds a little over one).
        self.transfer_packets = min(63, max(1, config.transfer_bytes // PACKET))
        self.lock = threading.Lock()
        self.cci_lock = threading.Lock()      # one register file, several I2C clients
        self.scene = TimedScene(config.disparity_px, config.seed)
        self.registers = FakeCciRegisters(self, busy_polls=2)
        self.rng = np.random.default_rng(config.seed + 1000)
        self.discards = make_discard_packet() * self.transfer_packets
        self.floating = b'\xff' * (PACKET * self.transfer_packets)
        self.powered = True
        now = time.monotonic()
        self.power_on_at = now if config.start_booting else now - 10.0
        self.layout = FrameLayout.for_mode('off')
        self.ffc_start_core = None
        self.imminent_from = None
        self.ffc_error = 0
        self.level_offset = 0.0
        self.frozen = None
        self.sync_lost = False
        self.frame = None                 # [core, packets, written, start_offset, end_offset]
        self.frame_read_any = False
        self.next_core = self._ready_index(now) + 1
        self.written = 0
        self.consumed = 0
        self.last_consume_t = now
        self.last_write_t = -math.inf
        self.last_write_s = 0.0
        self.pause_deadline = math.inf    # the host must clock the frame on by then
        self.pixels_cache = (None, None, False)
        self.last_recorded = -1
        self.stats = collections.Counter()

    # --- hooks of the CCI register file (called from the I2C thread) -------------------
    def cci_acknowledges(self):
        return self.powered and time.monotonic() >= self.power_on_at + self.config.nack_s

    def cci_booted(self):
        return time.monotonic() >= self.power_on_at + self.config.boot_s

    def set_telemetry(self, enabled, location):
        with self.lock:
            self.layout = FrameLayout.for_mode(location if enabled else 'off')

    def run_ffc(self, announce_frames=0):
        """Start an FFC: at once (a CCI command), or after ``announce_frames`` "imminent"."""
        with self.lock:
            next_core = self._ready_index(time.monotonic()) + 1
            self.imminent_from = next_core
            self.ffc_start_core = next_core + 3 * announce_frames
            self.stats['ffc'] += 1

    def reboot(self):
        with self.lock:
            self._power_up(time.monotonic())
            self.stats['reboots'] += 1

    def _power_up(self, now):
        self.power_on_at = now
        self.layout = FrameLayout.for_mode('off')
        self.sync_lost = False
        self.frame = None
        self.next_core = self._ready_index(now + self.config.boot_s) + 1
        self.registers.power_on_defaults()

    # --- events -------------------------------------------------------------------------
    def unplug(self):
        with self.lock:
            self.powered = False
            self.frame = None
            self.stats['unplugs'] += 1

    def replug(self):
        with self.lock:
            self.powered = True
            self._power_up(time.monotonic())

    # --- the camera -----------------------------------------------------------------------
    def _core_time(self, core):
        return self.epoch + self.config.phase_s + core * self.period

    def _ready_index(self, now):
        return math.floor((now - self.epoch - self.config.phase_s) / self.period)

    def _lose_sync(self, reason):
        self.sync_lost = True
        self.frame = None
        self.stats['sync_lost'] += 1
        self.stats[f'sync_lost: {reason}'] += 1

    def _unique_pixels(self, unique):
        """Pixels of a unique frame and whether it is a frozen frame of an FFC."""
        cached, previous, cached_ffc = self.pixels_cache
        if cached == unique:
            return previous, cached_ffc
        start = self.ffc_start_core
        ffc = start is not None and start <= 3 * unique + 2 and 3 * unique < start + \
            FFC_CORE_FRAMES
        if start is not None and self.imminent_from is not None and \
                self.imminent_from <= 3 * unique + 2 and 3 * unique + 2 < start:
            out = self._render(unique)           # new pixels, the camera says "imminent"
            self.pixels_cache = (unique, out, 'imminent')
            return out, 'imminent'
        if ffc:
            if self.frozen is None:
                self.frozen = previous if previous is not None else self._render(unique - 1)
            out = self.frozen
        else:
            if self.frozen is not None or (start is not None and 3 * unique >= start):
                self.frozen = None
                self.level_offset += FFC_LEVEL_JUMP
                self.ffc_start_core = None
            out = self._render(unique)
        state = 'in_progress' if ffc else False
        self.pixels_cache = (unique, out, state)
        return out, state

    def _render(self, unique):
        counts = self.scene.frame(self._core_time(3 * unique) - self.epoch, unique)
        return np.clip(np.round(counts + self.level_offset), 0, 16383).astype(np.uint16)

    def _frame_packets(self, core):
        unique = core // 3
        pixels, ffc = self._unique_pixels(unique)
        layout = self.layout
        payloads = np.zeros((layout.packets, 80), dtype=np.uint16)
        payloads[list(layout.image_packets)] = pixels
        if layout.telemetry_packets:
            row_a = encode_telemetry_row_a(
                core, uptime_ms=int((time.monotonic() - self.power_on_at) * 1000),
                fpa_temperature_k=300.0, ffc_state=ffc or 'complete',
                agc=False, serial=self.config.serial, frame_mean=int(pixels.mean()))
            payloads[layout.telemetry_packets[0]] = np.frombuffer(row_a, dtype='>u2')
        if unique > self.last_recorded:       # the first copy of it the camera sends
            self.last_recorded = unique
            self.records.put((self.config.name, unique, self._core_time(3 * unique),
                              pixels_digest(pixels), bool(ffc)))
            self.stats['unique_sent'] += 1
        self.stats['frames_started'] += 1
        blob = encode_frame_packets(payloads)
        packets = [blob[i * PACKET:(i + 1) * PACKET] for i in range(layout.packets)]
        if self.config.crc_fault_rate and self.rng.random() < self.config.crc_fault_rate:
            position = int(self.rng.integers(1, layout.packets))
            damaged = bytearray(packets[position])
            damaged[3] ^= 0x5A
            packets[position] = bytes(damaged)
            self.stats['crc_faults'] += 1
        return packets

    def _garbage(self, packets):
        return self.rng.integers(0, 256, PACKET * packets, dtype=np.uint8).tobytes()

    def _next_transfer(self, now):
        """Return the bytes the host's next transfer clocks out (decided now)."""
        n = self.transfer_packets
        if not self.powered:
            return self.floating
        if now < self.power_on_at + self.config.boot_s:
            return self.discards                       # VoSPI not running yet
        if self.sync_lost:
            return self._garbage(n)
        frame = self.frame
        if frame is not None and frame[2] < len(frame[1]):
            take = frame[1][frame[2]:frame[2] + n]
            frame[2] += len(take)
            return b''.join(take)
        ready = self._ready_index(now)
        if ready >= self.next_core:
            if ready > self.next_core:
                self._lose_sync('frame skipped')
                return self._garbage(n)
            packets = self._frame_packets(self.next_core)
            self.frame = [self.next_core, packets, 0, self.written,
                          self.written + PACKET * len(packets)]
            self.frame_read_any = False
            self.next_core += 1
            take = packets[:n]
            self.frame[2] = len(take)
            return b''.join(take)
        packet_s = PACKET * 8.0 / self.config.spi_hz
        count = min(n, max(1, math.ceil((self._core_time(self.next_core) - now) / packet_s)))
        return self.discards[:PACKET * count]

    def step(self, now):
        """One turn of the camera loop: watch the host, apply the timing rules, write."""
        level = int.from_bytes(fcntl.ioctl(self.fd, termios.FIONREAD, b'\0\0\0\0'), 'little')
        consumed = self.written - level
        if consumed > self.consumed:
            # The host's transfer of these bytes ends their clock time after it started (the
            # FIFO hands them over at once); its next transfer must start within the gap.
            self.pause_deadline = now + self.config.max_packet_gap_s + \
                (consumed - self.consumed) * 8.0 / self.config.spi_hz
            self.consumed = consumed
            self.last_consume_t = now
        with self.lock:
            frame = self.frame
            if frame is not None:
                if consumed >= frame[4]:
                    self.frame = None
                    self.stats['frames_read'] += 1
                else:
                    if consumed > frame[3]:
                        self.frame_read_any = True
                    if now >= self._core_time(frame[0] + 1):
                        self._lose_sync('frame not finished before the next one')
                    elif self.frame_read_any and level > 0 and now > self.pause_deadline:
                        # Bytes of a started frame wait longer than the Lepton allows.
                        self._lose_sync('pause inside a frame')
            if level > 0 and now - self.last_consume_t >= RESYNC_IDLE_S:
                # The host left the bus idle: the camera restarts VoSPI at the next frame,
                # and what it had shifted out is gone.
                self._drain(level)
                level = 0
                if self.sync_lost:
                    self.stats['resyncs'] += 1
                self.sync_lost = False
                self.frame = None
                self.next_core = max(self.next_core, self._ready_index(now) + 1)
                self.last_consume_t = now
            if level == 0 and now >= self.last_write_t + self.last_write_s and \
                    self._take_bus(now):
                data = self._next_transfer(now)
                if self.bus is not None:
                    self.bus[1].value = now + len(data) * 8.0 / self.config.spi_hz
                    self.bus[0].release()
                self.written += os.write(self.fd, data)   # fits: the FIFO is empty
                self.last_write_t = now
                self.last_write_s = len(data) * 8.0 / self.config.spi_hz
                # Written when the previous transfer's clock time is over: the host's next
                # read must come within the gap.
                self.pause_deadline = max(self.pause_deadline,
                                          now + self.config.max_packet_gap_s)

    def _take_bus(self, now):
        """Hold the controller for a transfer (True), or False while the other camera's runs."""
        if self.bus is None:
            return True
        lock, free_at = self.bus
        lock.acquire()
        if now < free_at.value:
            lock.release()
            self.stats['waits for the shared bus'] += 1
            return False
        return True

    def _drain(self, level):
        try:
            os.read(self.fd, level)
        except BlockingIOError:
            pass
        self.consumed = self.written


def _serve(camera, connection, stop, control=True):
    """Answer I2C transfers (and, from the parent, control requests): a thread per client."""
    registers = camera.registers
    while not stop.is_set():
        try:
            request = connection.recv()
        except (EOFError, OSError):
            if control:
                stop.set()
            return
        kind = request[0]
        try:
            if kind == 'read':
                with camera.cci_lock:
                    reply = ('ok', registers.read_words(request[1], request[2]))
            elif kind == 'write':
                with camera.cci_lock:
                    registers.write_words(request[1], request[2])
                reply = ('ok', None)
            elif not control:
                reply = ('error', f"{kind!r} is a request of the emulator's parent only")
            elif kind == 'unplug':
                camera.unplug()
                reply = ('ok', None)
            elif kind == 'replug':
                camera.replug()
                reply = ('ok', None)
            elif kind == 'auto_ffc':
                camera.run_ffc(announce_frames=request[1])
                reply = ('ok', None)
            elif kind == 'ffc_error':
                registers.ffc_error = request[1]
                reply = ('ok', None)
            elif kind == 'stats':
                with camera.lock:
                    reply = ('ok', dict(camera.stats))
            elif kind == 'stop':
                stop.set()
                reply = ('ok', None)
            else:
                reply = ('error', f'unknown request {kind!r}')
        except OSError as error:
            reply = ('nack', str(error))
        try:
            connection.send(reply)
        except OSError:
            return


def _accept(camera, listener, stop):
    """Serve each I2C client (an ``SMBus`` of any process) on its own thread."""
    while not stop.is_set():
        try:
            connection = listener.accept()
        except (OSError, EOFError):
            return
        threading.Thread(target=_serve, args=(camera, connection, stop, False),
                         daemon=True).start()


def _camera_main(config, fifo, connection, records, epoch, address, bus=None):
    """Entry point of a camera process."""
    fd = os.open(fifo, os.O_RDWR | os.O_NONBLOCK)     # never blocks, never EOF for the host
    fcntl.fcntl(fd, F_SETPIPE_SZ, PIPE_BYTES)
    camera = _Camera(config, fd, records, epoch, bus)
    stop = threading.Event()
    listener = Listener(address, family='AF_UNIX', authkey=AUTHKEY)
    threading.Thread(target=_accept, args=(camera, listener, stop), daemon=True).start()
    server = threading.Thread(target=_serve, args=(camera, connection, stop), daemon=True)
    server.start()
    while not stop.is_set():
        now = time.monotonic()
        camera.step(now)
        time.sleep(0.0002)
    listener.close()
    os.close(fd)


class RemoteCci:
    """An I2C client of one emulated camera's CCI (what the ``smbus2`` stand-in talks to)."""

    def __init__(self, address):
        self.address = address
        self._connection = None
        self._lock = threading.Lock()

    def _request(self, *request):
        with self._lock:
            try:
                if self._connection is None:
                    self._connection = Client(self.address, family='AF_UNIX', authkey=AUTHKEY)
                self._connection.send(request)
                status, value = self._connection.recv()
            except (OSError, EOFError) as error:
                self._connection = None
                raise OSError(errno.ENODEV, f'emulated I2C bus gone ({error})') from None
        if status == 'nack':
            raise OSError(errno.EREMOTEIO, f'Remote I/O error ({value})')
        if status != 'ok':
            raise RuntimeError(f'emulated camera at {self.address}: {value}')
        return value

    def read_words(self, register, count):
        """I2C read of ``count`` words."""
        return self._request('read', register, count)

    def write_words(self, register, words):
        """I2C write of words."""
        self._request('write', register, list(words))

    def close(self):
        """Close the connection."""
        with self._lock:
            if self._connection is not None:
                self._connection.close()
                self._connection = None


class CameraProxy:
    """The parent's handle on one emulated camera: events and counters."""

    def __init__(self, name, connection):
        self.name = name
        self._connection = connection
        self._lock = threading.Lock()

    def _request(self, *request):
        with self._lock:
            self._connection.send(request)
            status, value = self._connection.recv()
        if status != 'ok':
            raise RuntimeError(f'emulated camera {self.name}: {value}')
        return value

    def unplug(self):
        """Power the camera off: SPI floats high, I2C NACKs."""
        self._request('unplug')

    def replug(self):
        """Power the camera up again (boot, telemetry off)."""
        self._request('replug')

    def auto_ffc(self, announce_frames=3):
        """Start an automatic FFC: ``announce_frames`` unique frames "imminent", then frozen."""
        self._request('auto_ffc', int(announce_frames))

    def set_ffc_error(self, code):
        """Make RUN FFC answer with a camera error code (0 = works again)."""
        self._request('ffc_error', int(code))

    def stats(self):
        """Counters of the camera: sync losses by reason, resyncs, frames, FFCs."""
        return self._request('stats')

    def stop(self):
        """End the camera process."""
        try:
            self._request('stop')
        except (EOFError, OSError, RuntimeError):
            pass


class RigEmulator:
    """
    Two emulated cameras on the wall clock; use as a context manager.

    Parameters
    ----------
    configs : sequence of CameraConfig, optional
        Default: a left camera and a right one (10 px disparity), 11 ms apart in phase, drifting
        +30 / -20 ppm, both on one SPI controller at 16 MHz (as ``/dev/spidev0.0`` and
        ``/dev/spidev0.1``) with the spidev default buffer of 4096 bytes.
    directory : path, optional
        Where the FIFOs go (default: a new temporary directory, removed on exit).

    Attributes
    ----------
    devices : dict
        Camera name -> FIFO path (the driver's ``<side>_device``).
    buses : dict
        I2C bus number (0 left, 1 right) -> the camera's CCI socket address.
    module_dir : pathlib.Path
        The directory of the ``spidev`` and ``smbus2`` stand-ins (see ``installed``).

    """

    def __init__(self, configs=None, directory=None):
        if configs is None:
            configs = [CameraConfig('left', seed=1, phase_s=0.004, drift_ppm=30.0),
                       CameraConfig('right', seed=2, phase_s=0.015, drift_ppm=-20.0,
                                    disparity_px=10.0)]
        self.configs = list(configs)
        self._own_directory = directory is None
        self.directory = pathlib.Path(directory or tempfile.mkdtemp(prefix='st_rig_'))
        self.devices = {}
        self.cameras = {}
        self.buses = {}
        self.sent = {config.name: [] for config in self.configs}
        self._processes = []
        self._records = None

    def __enter__(self):
        """Start both cameras."""
        context = multiprocessing.get_context('spawn')
        self._records = context.Queue()
        epoch = time.monotonic()
        controllers = collections.Counter(config.controller for config in self.configs)
        buses = {number: (context.Lock(), context.Value('d', 0.0))
                 for number, count in controllers.items() if count > 1}
        for index, config in enumerate(self.configs):
            fifo = self.directory / f'spidev0.{index}'
            if fifo.exists():
                fifo.unlink()
            os.mkfifo(fifo)
            address = str(self.directory / f'cci-{index}.socket')
            parent, child = context.Pipe()
            process = context.Process(target=_camera_main, name=f'lepton-{config.name}',
                                      args=(config, str(fifo), child, self._records, epoch,
                                            address, buses.get(config.controller)),
                                      daemon=True)
            process.start()
            self._processes.append(process)
            proxy = CameraProxy(config.name, parent)
            self.cameras[config.name] = proxy
            self.devices[config.name] = str(fifo)
            self.buses[index] = address
        for proxy in self.cameras.values():
            proxy.stats()                 # wait until each process answers
        self.module_dir = self.directory / 'modules'
        self.module_dir.mkdir(exist_ok=True)
        (self.module_dir / 'spidev.py').write_text(_SHIM_SPIDEV)
        (self.module_dir / 'smbus2.py').write_text(_SHIM_SMBUS2)
        (self.module_dir / 'rig_buses.json').write_text(json.dumps(self.buses))
        return self

    def __exit__(self, *exc):
        """Stop the cameras and remove the FIFOs."""
        for proxy in self.cameras.values():
            proxy.stop()
        for process in self._processes:
            process.join(timeout=5.0)
            if process.is_alive():
                process.kill()
        self.collect()
        if self._own_directory:
            shutil.rmtree(self.directory, ignore_errors=True)
        return False

    def collect(self, settle_s=0.5):
        """
        Move the records of sent unique frames into ``sent`` (name -> list); returns it.

        Records travel through a queue: waits up to ``settle_s`` for the last ones.
        """
        while True:
            try:
                name, unique, stamp, digest, ffc = self._records.get(timeout=settle_s)
            except (queue.Empty, OSError, ValueError):
                break
            self.sent[name].append(SentFrame(unique, stamp, digest, ffc))
        return self.sent

    @contextlib.contextmanager
    def installed(self):
        """
        Make ``import spidev`` and ``import smbus2`` find this rig's stand-ins in the block.

        The stand-ins' directory goes first on ``sys.path`` (reader processes spawned in the
        block inherit it); modules already imported under those names are set aside.
        """
        saved = {name: sys.modules.pop(name) for name in ('spidev', 'smbus2')
                 if name in sys.modules}
        sys.path.insert(0, str(self.module_dir))
        try:
            yield self
        finally:
            sys.path.remove(str(self.module_dir))
            for name in ('spidev', 'smbus2'):
                sys.modules.pop(name, None)
            sys.modules.update(saved)
