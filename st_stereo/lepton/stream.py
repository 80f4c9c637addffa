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
``time.monotonic()`` (system-wide, so stamps taken in another process compare).

``ProcessCameraStream`` runs the same in a child process: the node's other threads (the
matcher, a user's node in the same process) then never make the reader wait for the GIL
between two transfers of a frame, which loses sync (measured: ``st-stereo rig-bench``).
Frames come back through a pipe; the child's counters are mirrored every half second.
"""

import dataclasses
import multiprocessing
import signal
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

    def request_stop(self):
        """Ask the thread to stop (returns at once; ``stop`` waits for it)."""
        self._stop.set()

    def stop(self, timeout_s=3.0):
        """Stop the thread and close the camera."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout_s)

    @property
    def alive(self):
        """Whether the reading thread runs."""
        return self._thread.is_alive()

    def run_ffc(self):
        """Start an FFC on the camera (CciError / PureThermalError when it cannot)."""
        reader = self.reader
        control = getattr(reader, 'control', reader)
        if control is None or not hasattr(control, 'run_ffc'):
            raise CciError(f'{self.name} camera: not open (starting or restarting)')
        control.run_ffc()

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
                    self.reader = None          # no FFC or diagnostics on a closed camera
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


def _stream_process_main(name, arguments, connection):
    """Entry point of a camera's reader process: a CameraStream, frames sent to the parent."""
    from st_stereo.lepton.assembler import LeptonCounters
    # Ctrl-C and a service stop reach the whole process group: the parent stops this process
    # (or its pipe closes when the parent dies), so a shutdown never looks like a crash.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    lock = threading.Lock()

    def send(message):
        with lock:
            connection.send(message)

    counters = LeptonCounters()
    log = lambda message: send(('log', message))           # noqa: E731

    def open_camera():
        return open_spi_camera(counters=counters, log=log, **arguments)

    stream = CameraStream(name, open_camera, lambda side, frame: send(('frame', frame)),
                          lambda side, error: send(('fatal', f'{type(error).__name__}: '
                                                             f'{error}')), log=log)
    stream.start()
    try:
        while stream.alive:
            if connection.poll(0.5):
                request = connection.recv()
                if request[0] == 'stop':
                    break
                if request[0] == 'ffc':
                    try:
                        stream.run_ffc()
                        send(('reply', True, ''))
                    except Exception as error:   # noqa: B902 - an FFC never ends the reader
                        send(('reply', False, f'{type(error).__name__}: {error}'))
            device = getattr(getattr(stream.reader, 'transport', None), 'device', '')
            send(('counters', counters.as_dict(), stream.counters.as_dict(), device))
    except (EOFError, OSError, KeyboardInterrupt):
        pass
    finally:
        stream.stop()


class ProcessCameraStream:
    """
    A SPI camera read by a ``CameraStream`` in its own process (see the module docstring).

    Same interface as ``CameraStream`` for the driver: ``start``, ``stop``, ``counters``,
    ``run_ffc``, ``seconds_since_frame``, ``device``; ``lepton_counters`` mirrors the child's
    reader counters. ``arguments`` are those of ``open_spi_camera`` but ``counters``/``log``.
    """

    def __init__(self, name, arguments, on_frame, on_fatal=None, lepton_counters=None,
                 log=None):
        from st_stereo.lepton.assembler import LeptonCounters
        self.name = name
        self.arguments = dict(arguments)
        self.on_frame = on_frame
        self.on_fatal = on_fatal
        self.log = log or (lambda message: None)
        self.counters = StreamCounters()
        self.lepton_counters = lepton_counters if lepton_counters is not None else \
            LeptonCounters()
        self.device = self.arguments.get('device', name)
        self._replies = []
        self._reply_ready = threading.Condition()
        self._stopping = False
        context = multiprocessing.get_context('spawn')
        self._connection, self._child_connection = context.Pipe()
        self._process = context.Process(target=_stream_process_main, name=f'lepton_{name}',
                                        args=(name, self.arguments, self._child_connection),
                                        daemon=True)
        self._thread = threading.Thread(target=self._receive, name=f'lepton_{name}_receive',
                                        daemon=True)
        self._send_lock = threading.Lock()

    @property
    def reader(self):
        """Stands for the reader in diagnostics (its device)."""
        return self

    @property
    def transport(self):
        """Stands for the transport in diagnostics (its device)."""
        return self

    def start(self):
        """Start the reader process and the thread that receives its frames."""
        # Ctrl-C reaches the whole process group, also a reader process still importing (a
        # loaded machine: a KeyboardInterrupt traceback out of the spawn bootstrap): it is
        # spawned with SIGINT and SIGTERM blocked, which it inherits across exec, before its
        # own handlers ignore them.
        mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        try:
            self._process.start()
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, mask)
        # The child has its copy: this one closed, the child's exit reaches recv as EOF.
        self._child_connection.close()
        self._thread.start()
        return self

    @property
    def alive(self):
        """Whether the reader process runs."""
        return self._process.is_alive()

    def _receive(self):
        counters = self.counters
        while True:
            try:
                message = self._connection.recv()
            except (EOFError, OSError):
                break
            except (TypeError, ValueError):
                # The connection was closed under this recv: only ``stop`` does that.
                if self._stopping:
                    return
                raise
            kind = message[0]
            if kind == 'frame':
                counters.frames += 1
                counters.last_frame_time = time.monotonic()
                self.on_frame(self.name, message[1])
            elif kind == 'counters':
                for key, value in message[1].items():
                    setattr(self.lepton_counters, key, value)
                for key, value in message[2].items():
                    if key not in ('frames', 'last_frame_time'):
                        setattr(counters, key, value)
                self.device = message[3] or self.device
            elif kind == 'log':
                self.log(message[1])
            elif kind == 'reply':
                with self._reply_ready:
                    self._replies.append(message[1:])
                    self._reply_ready.notify_all()
            elif kind == 'fatal':
                self._fatal(message[1])
                return
        if not self._stopping:
            self._process.join(1.0)
            self._fatal(f'reader process ended (exit code {self._process.exitcode})')

    def _fatal(self, message):
        self.counters.last_error = message
        if self.on_fatal is not None:
            self.on_fatal(self.name, RuntimeError(message))

    def run_ffc(self, timeout_s=3.0):
        """Ask the reader process to start an FFC; CciError with its reason when it fails."""
        with self._reply_ready:
            self._replies.clear()
        with self._send_lock:
            self._connection.send(('ffc',))
        with self._reply_ready:
            if not self._reply_ready.wait_for(lambda: self._replies, timeout_s):
                raise CciError(f'{self.name} camera: no answer from its reader process')
            ok, reason = self._replies.pop(0)
        if not ok:
            raise CciError(reason)

    def seconds_since_frame(self, now=None):
        """Seconds since the last frame (inf before the first)."""
        return CameraStream.seconds_since_frame(self, now)

    def request_stop(self):
        """Ask the reader process to stop (returns at once; ``stop`` waits for it)."""
        self._stopping = True
        if self._process.is_alive():
            try:
                with self._send_lock:
                    self._connection.send(('stop',))
            except OSError:
                pass

    def stop(self, timeout_s=3.0):
        """Stop the reader process (it closes the camera) and the receiving thread."""
        self.request_stop()
        if self._process.is_alive():
            self._process.join(timeout_s)
            if self._process.is_alive():
                self._process.kill()
                self._process.join(1.0)
        # The child's end closes with the process, so the receiving thread sees EOF and ends:
        # wait for it before closing this end (closing under a blocked recv breaks it).
        if self._thread.is_alive():
            self._thread.join(timeout_s)
        self._connection.close()
