"""
One camera, read continuously by its own thread, restarted with back-off when it fails.

A Lepton must be clocked out every core frame (37.9 ms) or it loses sync, so each camera of a
rig gets its own ``CameraStream``: a thread that opens the camera (``open_camera()`` returns a
reader with ``read_frame(timeout_s)`` and ``close()``; for SPI that includes the CCI start-up),
reads frames and hands each to ``on_frame(name, frame)``, which must return quickly. When the
camera fails (an ``OSError``, a CCI error, a PureThermal error, or no frame for
``silence_s``), the reader is closed and the camera reopened after a back-off that doubles
from ``backoff_s`` up to ``max_backoff_s``; every restart and its reason are counted. Any
other exception is a bug, not a camera fault: the stream stops and calls ``on_fatal(error)``
(the node then exits non-zero, so ``respawn`` in a launch file can act). All times are
``time.monotonic()``.
"""

import dataclasses
import threading
import time

from st_stereo.lepton.cci import CciError
from st_stereo.lepton.purethermal import PureThermalError


class CameraSilent(RuntimeError):
    """A camera delivered no frame for too long (its reader is restarted)."""


RECOVERABLE = (OSError, CciError, PureThermalError, CameraSilent)


@dataclasses.dataclass
class StreamCounters:
    """What happened to one camera stream."""

    frames: int = 0
    opens: int = 0
    restarts: int = 0
    open_failures: int = 0
    last_error: str = ''
    last_frame_time: float = -1.0     # time.monotonic() of the last frame, -1 = none yet

    def as_dict(self):
        """Return the counters as a plain dict."""
        return dataclasses.asdict(self)


class CameraStream:
    """A camera and the thread that reads it (see the module docstring)."""

    def __init__(self, name, open_camera, on_frame, on_fatal=None, silence_s=3.0,
                 backoff_s=0.25, max_backoff_s=1.0, read_timeout_s=0.5, log=None):
        self.name = name
        self.open_camera = open_camera
        self.on_frame = on_frame
        self.on_fatal = on_fatal
        self.silence_s = silence_s
        self.backoff_s = backoff_s
        self.max_backoff_s = max_backoff_s
        self.read_timeout_s = read_timeout_s
        self.log = log or (lambda message: None)
        self.counters = StreamCounters()
        self.reader = None              # the current reader (its counters feed diagnostics)
        self.fatal = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f'lepton_{name}', daemon=True)

    def start(self):
        """Start the reading thread."""
        self._thread.start()
        return self

    def stop(self, timeout_s=3.0):
        """Stop the thread and close the camera."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    @property
    def alive(self):
        """Whether the reading thread runs."""
        return self._thread.is_alive()

    def seconds_since_frame(self, now=None):
        """Seconds since the last frame (inf before the first)."""
        last = self.counters.last_frame_time
        if last < 0:
            return float('inf')
        return (time.monotonic() if now is None else now) - last

    def _run(self):
        backoff = self.backoff_s
        counters = self.counters
        logged_at = -1e9
        while not self._stop.is_set():
            reader = None
            try:
                reader = self.open_camera()
                self.reader = reader
                counters.opens += 1
                opened_at = time.monotonic()
                while not self._stop.is_set():
                    frame = reader.read_frame(timeout_s=self.read_timeout_s)
                    now = time.monotonic()
                    if frame is None:
                        since = now - max(counters.last_frame_time, opened_at)
                        if since > self.silence_s:
                            raise CameraSilent(f'no frame for {since:.1f} s')
                        continue
                    counters.frames += 1
                    counters.last_frame_time = now
                    backoff = self.backoff_s
                    self.on_frame(self.name, frame)
            except RECOVERABLE as error:
                counters.last_error = f'{type(error).__name__}: {error}'
                if reader is None:
                    counters.open_failures += 1
                else:
                    counters.restarts += 1
                now = time.monotonic()
                if now - logged_at > 30.0:
                    self.log(f'{self.name} camera: {counters.last_error}; retrying every '
                             f'{self.max_backoff_s:g} s at most (logged every 30 s)')
                    logged_at = now
            except Exception as error:   # noqa: B902 - a bug: stop and let the node exit
                counters.last_error = f'{type(error).__name__}: {error}'
                self.fatal = error
                if self.on_fatal is not None:
                    self.on_fatal(self.name, error)
                return
            finally:
                if reader is not None:
                    try:
                        reader.close()
                    except OSError:
                        pass
            if self._stop.wait(backoff):
                break
            backoff = min(2.0 * backoff, self.max_backoff_s)


class _RestartingCci:
    """The CCI the reader reboots a stuck camera with: a reboot is followed by the start-up."""

    def __init__(self, cci, telemetry, boot_timeout_s):
        self.cci = cci
        self.telemetry = telemetry
        self.boot_timeout_s = boot_timeout_s

    def reboot(self):
        """Reboot, wait for boot, set telemetry again (a reboot restores power-up defaults)."""
        self.cci.reboot()
        self.cci.start(self.telemetry, self.boot_timeout_s)

    def close(self):
        """Close the bus."""
        self.cci.close()


def open_spi_camera(device, spi_hz, i2c_bus, telemetry, counters=None, boot_timeout_s=10.0,
                    log=None):
    """
    Open a Lepton on spidev + I2C: CCI start-up (boot, ping, telemetry), then a resync.

    Returns a ``LeptonReader`` whose ``cci.reboot()`` re-runs the start-up. ``log`` receives
    the spidev buffer warning (see ``st_stereo.lepton.spi.bufsiz_warning``) once per open.
    """
    from st_stereo.lepton.cci import LeptonCCI, SMBus2Bus
    from st_stereo.lepton.reader import LeptonReader
    from st_stereo.lepton.spi import SpiTransport
    cci = LeptonCCI(SMBus2Bus(i2c_bus))
    try:
        cci.start(telemetry, boot_timeout_s)
        transport = SpiTransport(device, spi_hz)
    except BaseException:
        cci.close()
        raise
    if transport.warning and log is not None:
        log(f'{device}: {transport.warning}')
    reader = LeptonReader(transport, telemetry=telemetry, counters=counters,
                          cci=_RestartingCci(cci, telemetry, boot_timeout_s), reboot_wait_s=0.2)
    reader.resync()          # a clean start whatever the camera was doing
    reader.control = cci
    return reader


def open_purethermal_camera(serial, video_device, counters=None):
    """Open a PureThermal board (by serial when given) and its V4L2 device."""
    from st_stereo.lepton.purethermal import PureThermalReader
    return PureThermalReader(serial, video_device, counters=counters)
