"""
Fakes of the hardware around a Lepton, for tests and benchmarks only (never used by a node).

- ``FakeCciRegisters``: a CCI register file that executes commands (ping, FFC, reboot,
  telemetry settings) and forwards them to a simulated or emulated camera; NACKs and reports
  booting when the camera says so.
- ``fake_spidev_module`` / ``fake_smbus2_module``: stand-ins for the ``spidev`` and ``smbus2``
  modules with the calls ``SpiTransport`` and ``SMBus2Bus`` make, so the production classes run
  unchanged against the wall-clock rig emulator (``st_stereo.lepton.emulator``): spidev
  configuration succeeds (the data comes through ``os.read`` on the emulator's FIFO), and I2C
  transfers go to the emulated camera's register file.
  ``RigEmulator.installed()`` puts them first on ``sys.path``.
- ``FakeV4L2Board``: a PureThermal board's V4L2 stream on the wall clock.
"""

import dataclasses
import errno
import hashlib
import types

import numpy as np

from st_stereo.lepton.cci import (CMD_AGC_ENABLE, CMD_FPA_TEMPERATURE, CMD_PING, CMD_REBOOT,
                                  CMD_RUN_FFC, CMD_TELEMETRY_ENABLE, CMD_TELEMETRY_LOCATION, GET,
                                  REG_COMMAND, REG_DATA0, REG_DATA_LENGTH, REG_STATUS, RUN, SET,
                                  STATUS_BOOT_MODE, STATUS_BOOTED, STATUS_BUSY)
from st_stereo.lepton.packets import CORE_FRAME_HZ


class FakeCciRegisters:
    """
    A Lepton CCI register file for tests: executes commands, reports busy for a few polls.

    Parameters
    ----------
    camera : object, optional
        A simulator with ``reboot()`` and ``run_ffc()``; commands are forwarded to it. It may
        also have ``cci_acknowledges()`` (False: every transfer NACKs, a camera powering up
        or unplugged), ``cci_booted()`` (False: status reports booting) and
        ``set_telemetry(enabled, location)`` (the VoSPI layout follows the CCI setting).
    busy_polls : int
        Status reads that report busy after each command.

    """

    def __init__(self, camera=None, busy_polls=2, fpa_temperature_k=301.25):
        self.camera = camera
        self.busy_polls = busy_polls
        self.registers = {REG_STATUS: STATUS_BOOTED | STATUS_BOOT_MODE, REG_DATA_LENGTH: 0}
        self.values = {CMD_TELEMETRY_ENABLE: [0, 0], CMD_TELEMETRY_LOCATION: [0, 0],
                       CMD_AGC_ENABLE: [0, 0]}
        self.fpa_temperature_k = fpa_temperature_k
        self.log = []
        self._busy_left = 0
        self.stuck_busy = False
        self.ffc_error = 0           # a camera error code RUN FFC answers with (0 = works)

    def _acknowledge(self):
        answers = getattr(self.camera, 'cci_acknowledges', None)
        if answers is not None and not answers():
            raise OSError(errno.EREMOTEIO, 'Remote I/O error (no acknowledge from 0x2A)')

    def power_on_defaults(self):
        """Restore the registers and settings of a power-up or reboot (telemetry off)."""
        self.values[CMD_TELEMETRY_ENABLE] = [0, 0]
        self.values[CMD_TELEMETRY_LOCATION] = [0, 0]
        self._busy_left = 0

    def read_words(self, register, count):
        """Read registers; the status register reports busy while a command runs."""
        self._acknowledge()
        if register == REG_STATUS:
            booted = getattr(self.camera, 'cci_booted', None)
            if booted is not None and not booted():
                return [STATUS_BUSY]
            busy = self.stuck_busy or self._busy_left > 0
            if self._busy_left > 0:
                self._busy_left -= 1
            status = self.registers[REG_STATUS] & ~STATUS_BUSY
            return [status | (STATUS_BUSY if busy else 0)]
        return [self.registers.get(register + 2 * i, 0) for i in range(count)]

    def write_words(self, register, words):
        """Write registers; writing the command register executes the command."""
        self._acknowledge()
        for i, word in enumerate(words):
            self.registers[register + 2 * i] = word & 0xFFFF
        if register == REG_COMMAND:
            self._execute(words[0])

    def _set_error(self, code):
        status = self.registers[REG_STATUS] & 0x00FF
        self.registers[REG_STATUS] = status | ((code & 0xFF) << 8)

    def _execute(self, command):
        self.log.append(command)
        self._busy_left = self.busy_polls
        self._set_error(0)
        base, kind = command & ~0x3, command & 0x3
        length = self.registers.get(REG_DATA_LENGTH, 0)
        data = [self.registers.get(REG_DATA0 + 2 * i, 0) for i in range(length)]
        if command == CMD_PING | RUN:
            return
        if command == CMD_RUN_FFC:
            if self.ffc_error:
                self._set_error(self.ffc_error)
            elif self.camera is not None:
                self.camera.run_ffc()
            return
        if command == CMD_REBOOT:
            self.power_on_defaults()
            if self.camera is not None:
                self.camera.reboot()
            return
        if command == CMD_FPA_TEMPERATURE | GET:
            self.registers[REG_DATA0] = int(round(self.fpa_temperature_k * 100))
            return
        if base in self.values and kind in (GET, SET):
            if kind == SET:
                if length != 2:
                    self._set_error(-6)
                    return
                self.values[base] = data
                follow = getattr(self.camera, 'set_telemetry', None)
                if follow is not None and base in (CMD_TELEMETRY_ENABLE, CMD_TELEMETRY_LOCATION):
                    enabled = bool(self.values[CMD_TELEMETRY_ENABLE][0])
                    location = 'header' if self.values[CMD_TELEMETRY_LOCATION][0] == 0 \
                        else 'footer'
                    follow(enabled, location)
            else:
                for i, word in enumerate(self.values[base]):
                    self.registers[REG_DATA0 + 2 * i] = word
            return
        self._set_error(-7)


# --- module stand-ins ------------------------------------------------------------------------
def fake_spidev_module(opened=None):
    """
    Return a ``spidev`` stand-in: ``SpiDev`` takes ``open``/``open_path`` and the settings.

    ``opened`` (a list) receives ``(path or (bus, chip), settings dict)`` of every device closed,
    so tests can check what the transport configured.
    """
    module = types.ModuleType('spidev')

    class SpiDev:
        def __init__(self):
            self.mode, self.max_speed_hz, self.bits_per_word = 0, 500000, 8
            self.target = None

        def open(self, bus, chip):  # noqa: A003 - the real module's name
            self.target = (bus, chip)

        def open_path(self, path):
            self.target = path

        def close(self):
            if opened is not None and self.target is not None:
                opened.append((self.target, {'mode': self.mode, 'max_speed_hz':
                                             self.max_speed_hz, 'bits_per_word':
                                             self.bits_per_word}))
            self.target = None

    module.SpiDev = SpiDev
    return module


def fake_smbus2_module(buses):
    """
    Return a ``smbus2`` stand-in whose ``SMBus(n)`` talks to ``buses[n]``.

    ``buses[n]`` has ``write_words(register, words)`` and ``read_words(register, count)`` (a
    ``FakeCciRegisters``), or is a function returning such an object for each ``SMBus`` opened
    (an emulated camera's ``RemoteCci``); a missing bus number is the ``FileNotFoundError`` the
    real module raises for a missing ``/dev/i2c-N``.
    """
    module = types.ModuleType('smbus2')

    class _Message:
        def __init__(self, kind, address, data=(), length=0):
            self.kind, self.address, self.data, self.length = kind, address, list(data), length
            self.result = []

        def __iter__(self):
            return iter(self.result)

    class i2c_msg:  # noqa: N801 - the real module's name
        @staticmethod
        def write(address, data):
            return _Message('write', address, data)

        @staticmethod
        def read(address, length):
            return _Message('read', address, length=length)

    class SMBus:
        def __init__(self, number):
            if number not in buses:
                raise FileNotFoundError(errno.ENOENT, f'No such file or directory: '
                                        f"'/dev/i2c-{number}'")
            target = buses[number]
            self.target = target() if callable(target) else target

        def i2c_rdwr(self, *messages):
            first = messages[0]
            register = (first.data[0] << 8) | first.data[1]
            if len(messages) == 1:
                payload = first.data[2:]
                words = [(payload[2 * i] << 8) | payload[2 * i + 1]
                         for i in range(len(payload) // 2)]
                self.target.write_words(register, words)
                return
            read = messages[1]
            words = self.target.read_words(register, read.length // 2)
            read.result = [byte for word in words for byte in ((word >> 8) & 0xFF, word & 0xFF)]

        def close(self):
            close = getattr(self.target, 'close', None)
            if close is not None:
                close()
            self.target = None

    module.i2c_msg = i2c_msg
    module.SMBus = SMBus
    return module


# --- PureThermal / V4L2 on the wall clock ----------------------------------------------------
class FakeV4L2Board:
    """
    A PureThermal board's V4L2 stream on the wall clock, in the calling process.

    Core frames come every ``1 / CORE_FRAME_HZ`` of the board's own clock (``phase_s``,
    ``drift_ppm``), each unique frame three times, Y16 80x60 (80x63 with a telemetry footer).
    A read blocks until the next frame; a reader that falls behind gets the newest frame (the
    UVC queue drops the rest). ``unplug`` makes reads fail and new opens fail until ``replug``.
    Every unique frame sent is recorded in ``sent`` (``SentFrame``: index, ready time, digest).
    """

    def __init__(self, name, scene, phase_s=0.0, drift_ppm=0.0, footer=False):
        import threading
        import time
        self._time = time
        self.name = name
        self.scene = scene
        self.period = 1.0 / (CORE_FRAME_HZ * (1.0 + drift_ppm * 1e-6))
        self.epoch = time.monotonic() + phase_s
        self.footer = footer
        self.plugged = True
        self.sent = []
        self.lock = threading.Lock()
        self._cache = (None, None)

    def unplug(self):
        """Take the board away (reads fail, the device cannot be opened)."""
        self.plugged = False

    def replug(self):
        """Bring the board back."""
        self.plugged = True

    def open(self, device, api=None):  # noqa: A003 - as cv2.VideoCapture opens
        """Return what ``cv2.VideoCapture(device, cv2.CAP_V4L2)`` gives for this board."""
        return _FakeV4L2Capture(self)

    def frame_at(self, core):
        """Return the Y16 frame of core frame ``core`` (records the unique frame once)."""
        from st_stereo.lepton.telemetry import encode_telemetry_row_a
        unique = core // 3
        with self.lock:
            cached, pixels = self._cache
            if cached != unique:
                ready = self.epoch + 3 * unique * self.period
                counts = self.scene.frame(ready - self.epoch, unique)
                pixels = np.clip(np.round(counts), 0, 16383).astype(np.uint16)
                self._cache = (unique, pixels)
                self.sent.append(SentFrame(unique, ready, pixels_digest(pixels), False))
        if not self.footer:
            return pixels.copy()
        row_a = np.frombuffer(encode_telemetry_row_a(core, uptime_ms=core * 38,
                                                     fpa_temperature_k=300.0), dtype='>u2')
        footer = np.zeros((3, 80), np.uint16)
        footer[0] = row_a
        return np.vstack([pixels, footer])


class _FakeV4L2Capture:
    def __init__(self, board):
        self.board = board
        self.opened = board.plugged
        self.next_core = None

    def isOpened(self):  # noqa: N802 - OpenCV's name
        return self.opened

    def set(self, prop, value):  # noqa: A003 - OpenCV's name
        return True

    def read(self):
        board, clock = self.board, self.board._time
        if not self.opened or not board.plugged:
            clock.sleep(0.05)
            return False, None
        now = clock.monotonic()
        ready = int((now - board.epoch) // board.period)
        if self.next_core is None or self.next_core <= ready - 1:
            self.next_core = max(ready + 1, 0)
        wait = board.epoch + self.next_core * board.period - now
        if wait > 0:
            clock.sleep(wait)
        core = self.next_core
        self.next_core += 1
        if not board.plugged:
            return False, None
        return True, board.frame_at(core)

    def release(self):
        self.opened = False


def pixels_digest(pixels):
    """Digest identifying a frame's pixels (little-endian uint16 bytes, as in a mono16 Image)."""
    data = np.ascontiguousarray(pixels, dtype='<u2').tobytes()
    return hashlib.blake2b(data, digest_size=10).hexdigest()


@dataclasses.dataclass(frozen=True)
class SentFrame:
    """A unique frame an emulated camera sent: its index, acquisition time and pixel digest."""

    unique: int
    stamp: float              # time.monotonic() at which the frame was ready
    digest: str
    ffc: bool
