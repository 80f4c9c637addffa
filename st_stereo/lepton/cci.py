"""
CCI, the Lepton's control interface over I2C (address 0x2A, 16-bit registers and words).

``LeptonCCI(bus)`` runs the command sequence of the datasheet: wait until not busy, write the
data words (SET), the data length and the command, wait until not busy, check the signed error
code, read the data words (GET). A bus has two methods, ``write_words(register, words)`` and
``read_words(register, count)``; ``SMBus2Bus`` is the real one (test fakes live in
``st_stereo.lepton.fakes``). One lock per ``LeptonCCI`` (one camera per bus) keeps a command's
register sequence whole when the reading thread (reboot) and a service (FFC) use it at once.
``start`` brings a camera from power-up to video: wait for boot (a booting camera NACKs, then
reports busy), ping, set the telemetry mode and read it back.

smbus2 rather than raw ioctls: it is pure Python, its ``i2c_rdwr`` does the combined
write-then-read with a repeated start that 16-bit register addresses need, and it is what a
raw-ioctl version would re-implement line by line.
"""

import threading
import time

ADDRESS = 0x2A
REG_STATUS = 0x0002
REG_COMMAND = 0x0004
REG_DATA_LENGTH = 0x0006
REG_DATA0 = 0x0008
STATUS_BUSY = 0x0001
STATUS_BOOT_MODE = 0x0002
STATUS_BOOTED = 0x0004

GET, SET, RUN = 0, 1, 2
CMD_PING = 0x0202
CMD_FPA_TEMPERATURE = 0x0214
CMD_TELEMETRY_ENABLE = 0x0218
CMD_TELEMETRY_LOCATION = 0x021C
CMD_RUN_FFC = 0x0242
CMD_AGC_ENABLE = 0x0100
CMD_REBOOT = 0x4842
BOOT_TIMEOUT_S = 10.0        # the datasheet's boot takes about 1 s; USB hubs and cold starts more

ERRORS = {0: 'ok', -1: 'error', -2: 'not ready', -3: 'range error', -4: 'checksum error',
          -5: 'bad argument', -6: 'data size error', -7: 'undefined function',
          -8: 'function not yet implemented'}


class CciError(RuntimeError):
    """A CCI command failed or timed out; the message names the command and the cause."""


class LeptonCCI:
    """The Lepton command interface on a bus (see module docstring)."""

    def __init__(self, bus, timeout_s=1.0, poll_s=0.001, clock=time.monotonic,
                 sleep=time.sleep):
        self.bus = bus
        self.timeout_s = timeout_s
        self.poll_s = poll_s
        self.clock = clock
        self.sleep = sleep
        self.lock = threading.RLock()

    def _read_status(self, command):
        try:
            return self.bus.read_words(REG_STATUS, 1)[0]
        except OSError as error:
            raise CciError(f'{_name(command)}: no answer on I2C ({error})') from None

    def wait_ready(self, command=None):
        """Poll the status register until not busy; CciError after ``timeout_s``."""
        deadline = self.clock() + self.timeout_s
        polls = 0
        while True:
            status = self._read_status(command)
            if not status & STATUS_BUSY:
                return status
            polls += 1
            if self.clock() > deadline or polls > 100000:
                raise CciError(f'{_name(command)}: camera still busy after {self.timeout_s} s')
            self.sleep(self.poll_s)

    def command(self, command, data=(), read_words=0):
        """Run one command; returns the data words read back (GET)."""
        if len(data) > 16 or read_words > 16:
            raise CciError(f'command 0x{command:04X}: at most 16 data words, got '
                           f'{max(len(data), read_words)}')
        with self.lock:
            try:
                self.wait_ready(command)
                if data:
                    self.bus.write_words(REG_DATA0, list(data))
                self.bus.write_words(REG_DATA_LENGTH, [max(len(data), read_words)])
                self.bus.write_words(REG_COMMAND, [command])
                status = self.wait_ready(command)
                code = (status >> 8) & 0xFF
                code = code - 256 if code >= 128 else code
                if code != 0:
                    raise CciError(f'{_name(command)}: camera error {code} '
                                   f'({ERRORS.get(code, "unknown")})')
                return self.bus.read_words(REG_DATA0, read_words) if read_words else []
            except OSError as error:        # a NACK (EREMOTEIO) or a bus that went away
                raise CciError(f'{_name(command)}: I2C transfer failed ({error})') from None

    def ping(self):
        """SYS ping: raises CciError when the camera does not answer correctly."""
        self.command(CMD_PING | RUN)

    def run_ffc(self):
        """Run a flat-field correction now."""
        self.command(CMD_RUN_FFC)

    def fpa_temperature_k(self):
        """Focal-plane-array temperature, kelvin."""
        return self.command(CMD_FPA_TEMPERATURE | GET, read_words=1)[0] / 100.0

    def set_telemetry(self, enabled, location='footer'):
        """Enable or disable telemetry rows and place them in the header or the footer."""
        if location not in ('header', 'footer'):
            raise ValueError(f'telemetry location: expected header or footer, got {location!r}')
        self.command(CMD_TELEMETRY_ENABLE | SET, [int(enabled), 0])
        self.command(CMD_TELEMETRY_LOCATION | SET, [0 if location == 'header' else 1, 0])

    def telemetry(self):
        """Return (enabled, location) as the camera reports them."""
        enabled = self.command(CMD_TELEMETRY_ENABLE | GET, read_words=2)[0]
        location = self.command(CMD_TELEMETRY_LOCATION | GET, read_words=2)[0]
        return bool(enabled), 'header' if location == 0 else 'footer'

    def close(self):
        """Close the bus (when it can be closed)."""
        close = getattr(self.bus, 'close', None)
        if close is not None:
            close()

    def reboot(self):
        """OEM reboot; the camera needs about a second before video resumes."""
        with self.lock:
            try:
                self.bus.write_words(REG_DATA_LENGTH, [0])
                self.bus.write_words(REG_COMMAND, [CMD_REBOOT])
            except OSError as error:
                raise CciError(f'{_name(CMD_REBOOT)}: I2C transfer failed ({error})') from None

    def wait_booted(self, timeout_s=BOOT_TIMEOUT_S, poll_s=0.05):
        """
        Wait until the camera has booted: status bits 1 (boot mode) and 2 (booted), not busy.

        A camera that is still powering up does not acknowledge its address; those NACKs
        (``OSError``) are retried until ``timeout_s``. Returns the seconds waited.
        """
        started = self.clock()
        status, last_problem = None, 'no answer yet'
        while True:
            try:
                with self.lock:
                    status = self.bus.read_words(REG_STATUS, 1)[0]
                booted = STATUS_BOOTED | STATUS_BOOT_MODE
                if status & booted == booted and not status & STATUS_BUSY:
                    return self.clock() - started
                last_problem = f'status 0x{status:04X}: booting'
            except OSError as error:
                last_problem = f'no answer on I2C ({error})'
            if self.clock() - started > timeout_s:
                raise CciError(f'camera not booted after {timeout_s:g} s ({last_problem})')
            self.sleep(poll_s)

    def start(self, telemetry, boot_timeout_s=BOOT_TIMEOUT_S):
        """
        Bring a camera to video with the telemetry mode the reader expects.

        Waits for boot, pings, sets telemetry (``off``, ``header`` or ``footer``; the camera's
        power-up default is off) and reads it back: a camera that does not take the setting is
        a CciError naming what it reports. Returns the seconds spent waiting for boot.
        """
        if telemetry not in ('off', 'header', 'footer'):
            raise ValueError(f'telemetry: expected off, header or footer, got {telemetry!r}')
        waited = self.wait_booted(boot_timeout_s)
        with self.lock:
            self.ping()
            enabled = telemetry != 'off'
            self.set_telemetry(enabled, telemetry if enabled else 'footer')
            got_enabled, got_location = self.telemetry()
        if got_enabled != enabled or enabled and got_location != telemetry:
            got = got_location if got_enabled else 'off'
            raise CciError(f'telemetry: set to {telemetry}, the camera reports {got}')
        return waited


class SMBus2Bus:
    """The real I2C bus (``/dev/i2c-N``) through smbus2."""

    def __init__(self, bus_number, address=ADDRESS):
        try:
            from smbus2 import i2c_msg, SMBus
        except ImportError as error:   # pragma: no cover - smbus2 is a pinned dependency
            raise RuntimeError('smbus2 is not installed') from error
        self._msg = i2c_msg
        try:
            self._bus = SMBus(bus_number)
        except OSError as error:
            raise OSError(f'/dev/i2c-{bus_number}: cannot open the I2C bus ({error})') from None
        self.address = address
        self.bus_number = bus_number

    def _open_bus(self):
        if self._bus is None:
            raise OSError(f'/dev/i2c-{self.bus_number}: the bus is closed')
        return self._bus

    def write_words(self, register, words):
        """Write 16-bit words, big-endian, starting at a 16-bit register address."""
        bus = self._open_bus()
        payload = [register >> 8, register & 0xFF]
        for word in words:
            payload += [(word >> 8) & 0xFF, word & 0xFF]
        bus.i2c_rdwr(self._msg.write(self.address, payload))

    def read_words(self, register, count):
        """Read ``count`` 16-bit words (big-endian) with a repeated start."""
        bus = self._open_bus()
        write = self._msg.write(self.address, [register >> 8, register & 0xFF])
        read = self._msg.read(self.address, 2 * count)
        bus.i2c_rdwr(write, read)
        data = list(read)
        return [(data[2 * i] << 8) | data[2 * i + 1] for i in range(count)]

    def close(self):
        """Close the bus (idempotent; using it afterwards is an OSError)."""
        if self._bus is not None:
            self._bus.close()
            self._bus = None


def _name(command):
    return f'command 0x{command:04X}' if command is not None else 'CCI'
