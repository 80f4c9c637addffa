"""
CCI, the Lepton's control interface over I2C (address 0x2A, 16-bit registers and words).

``LeptonCCI(bus)`` runs the command sequence of the datasheet: wait until not busy, write the
data words (SET), the data length and the command, wait until not busy, check the signed error
code, read the data words (GET). A bus has two methods, ``write_words(register, words)`` and
``read_words(register, count)``; ``SMBus2Bus`` is the real one, ``FakeCciRegisters`` a register
file for tests that can drive a simulator (reboot, FFC).

smbus2 rather than raw ioctls: it is pure Python, its ``i2c_rdwr`` does the combined
write-then-read with a repeated start that 16-bit register addresses need, and it is what a
raw-ioctl version would re-implement line by line.
"""

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
CMD_STATUS = 0x0204
CMD_UPTIME = 0x020C
CMD_FPA_TEMPERATURE = 0x0214
CMD_TELEMETRY_ENABLE = 0x0218
CMD_TELEMETRY_LOCATION = 0x021C
CMD_RUN_FFC = 0x0242
CMD_FFC_STATUS = 0x0244
CMD_AGC_ENABLE = 0x0100
CMD_REBOOT = 0x4842
CMD_GPIO_MODE = 0x4854
GPIO_MODE_VSYNC = 5

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

    def wait_ready(self, command=None):
        """Poll the status register until not busy; CciError after ``timeout_s``."""
        deadline = self.clock() + self.timeout_s
        polls = 0
        while True:
            status = self.bus.read_words(REG_STATUS, 1)[0]
            if not status & STATUS_BUSY:
                return status
            polls += 1
            if self.clock() > deadline or polls > 100000:
                name = f'command 0x{command:04X}' if command is not None else 'CCI'
                raise CciError(f'{name}: camera still busy after {self.timeout_s} s')
            self.sleep(self.poll_s)

    def command(self, command, data=(), read_words=0):
        """Run one command; returns the data words read back (GET)."""
        if len(data) > 16 or read_words > 16:
            raise CciError(f'command 0x{command:04X}: at most 16 data words, got '
                           f'{max(len(data), read_words)}')
        self.wait_ready(command)
        if data:
            self.bus.write_words(REG_DATA0, list(data))
        self.bus.write_words(REG_DATA_LENGTH, [max(len(data), read_words)])
        self.bus.write_words(REG_COMMAND, [command])
        status = self.wait_ready(command)
        code = (status >> 8) & 0xFF
        code = code - 256 if code >= 128 else code
        if code != 0:
            raise CciError(f'command 0x{command:04X}: camera error {code} '
                           f'({ERRORS.get(code, "unknown")})')
        return self.bus.read_words(REG_DATA0, read_words) if read_words else []

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

    def enable_vsync(self):
        """Route the VSYNC pulse to GPIO3."""
        self.command(CMD_GPIO_MODE | SET, [GPIO_MODE_VSYNC, 0])

    def reboot(self):
        """OEM reboot; the camera needs about a second before video resumes."""
        self.bus.write_words(REG_DATA_LENGTH, [0])
        self.bus.write_words(REG_COMMAND, [CMD_REBOOT])


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

    def write_words(self, register, words):
        """Write 16-bit words, big-endian, starting at a 16-bit register address."""
        payload = [register >> 8, register & 0xFF]
        for word in words:
            payload += [(word >> 8) & 0xFF, word & 0xFF]
        self._bus.i2c_rdwr(self._msg.write(self.address, payload))

    def read_words(self, register, count):
        """Read ``count`` 16-bit words (big-endian) with a repeated start."""
        write = self._msg.write(self.address, [register >> 8, register & 0xFF])
        read = self._msg.read(self.address, 2 * count)
        self._bus.i2c_rdwr(write, read)
        data = list(read)
        return [(data[2 * i] << 8) | data[2 * i + 1] for i in range(count)]

    def close(self):
        """Close the bus."""
        self._bus.close()


class FakeCciRegisters:
    """
    A Lepton CCI register file for tests: executes commands, reports busy for a few polls.

    Parameters
    ----------
    camera : object, optional
        A simulator with ``reboot()`` and ``run_ffc()``; commands are forwarded to it.
    busy_polls : int
        Status reads that report busy after each command.

    """

    def __init__(self, camera=None, busy_polls=2, fpa_temperature_k=301.25):
        self.camera = camera
        self.busy_polls = busy_polls
        self.registers = {REG_STATUS: STATUS_BOOTED | STATUS_BOOT_MODE, REG_DATA_LENGTH: 0}
        self.values = {CMD_TELEMETRY_ENABLE: [0, 0], CMD_TELEMETRY_LOCATION: [0, 0],
                       CMD_AGC_ENABLE: [0, 0], CMD_GPIO_MODE: [0, 0]}
        self.fpa_temperature_k = fpa_temperature_k
        self.log = []
        self._busy_left = 0
        self.stuck_busy = False

    def read_words(self, register, count):
        """Read registers; the status register reports busy while a command runs."""
        if register == REG_STATUS:
            busy = self.stuck_busy or self._busy_left > 0
            if self._busy_left > 0:
                self._busy_left -= 1
            status = self.registers[REG_STATUS] & ~STATUS_BUSY
            return [status | (STATUS_BUSY if busy else 0)]
        return [self.registers.get(register + 2 * i, 0) for i in range(count)]

    def write_words(self, register, words):
        """Write registers; writing the command register executes the command."""
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
            if self.camera is not None:
                self.camera.run_ffc()
            return
        if command == CMD_REBOOT:
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
            else:
                for i, word in enumerate(self.values[base]):
                    self.registers[REG_DATA0 + 2 * i] = word
            return
        self._set_error(-7)
