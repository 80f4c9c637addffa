"""
The SPI transport of a real rig: Linux spidev, mode 3, whole packets per ``os.read``.

Thin on purpose: configuration through the ``spidev`` module (the device opened by its path, so
udev symlinks such as ``/dev/lepton_left`` work), bulk reads with ``os.read`` on the device file
(``SpiDev.readbytes`` caps at 4096 bytes), each read a whole number of packets no larger than
the spidev buffer (module parameter ``bufsiz``, 4096 bytes by default: 24 packets, so a
63-packet frame takes three reads with Python running between them; a Lepton tolerates about
1.5 ms between packets, so a buffer that holds a whole frame is much safer). All times are
``time.monotonic()``: deadlines and stamps never step with NTP.
"""

import os
import time

from st_stereo.lepton.packets import RAW14_PACKET_BYTES

# Where the kernel tells the spidev buffer size; ST_STEREO_SPIDEV_BUFSIZ_PATH overrides it
# (emulated rigs: the value must reach reader processes, which read it themselves).
BUFSIZ_PATH = os.environ.get('ST_STEREO_SPIDEV_BUFSIZ_PATH',
                             '/sys/module/spidev/parameters/bufsiz')
# 63 packets (telemetry on) of 164 bytes in one 37.9 ms core period needs 2.2 MHz of pure
# transfer; the frame must also leave time for Python between reads and for the gap to the
# next frame, so the floor is twice that. The datasheet's own minimum (about 2 MHz) is not
# enough for a frame within its period.
MIN_HZ, MAX_HZ = 4_000_000, 20_000_000
FRAME_BYTES = 63 * RAW14_PACKET_BYTES
RECOMMENDED_BUFSIZ = 65536


def spidev_buffer_size(path=None, default=4096):
    """Return the spidev buffer size in bytes (``bufsiz`` module parameter) or the default."""
    path = BUFSIZ_PATH if path is None else path
    try:
        with open(path, encoding='ascii') as stream:
            return int(stream.read().strip())
    except (OSError, ValueError):
        return default


def read_size_for(buffer_bytes, packet_bytes=RAW14_PACKET_BYTES):
    """Largest whole number of packets that fits the buffer (at least one)."""
    if buffer_bytes < packet_bytes:
        raise ValueError(f'spidev buffer of {buffer_bytes} bytes cannot hold one '
                         f'{packet_bytes}-byte packet: raise the spidev bufsiz parameter')
    return (buffer_bytes // packet_bytes) * packet_bytes


def bufsiz_warning(buffer_bytes):
    """Return the warning for a spidev buffer under one frame, or '' when it holds one."""
    if buffer_bytes >= FRAME_BYTES:
        return ''
    reads = -(-FRAME_BYTES // read_size_for(buffer_bytes))
    return (f'spidev bufsiz is {buffer_bytes} bytes, less than one Lepton frame '
            f'({FRAME_BYTES} bytes): every frame takes {reads} reads and a pause over about '
            f'1.5 ms between them loses sync. Raise it: add spidev.bufsiz={RECOMMENDED_BUFSIZ} '
            f'to the kernel command line (Raspberry Pi: /boot/firmware/cmdline.txt), or '
            f'"options spidev bufsiz={RECOMMENDED_BUFSIZ}" to /etc/modprobe.d/spidev.conf '
            f'for a loadable module, and reboot.')


class SpiTransport:
    """
    VoSPI over a spidev device (mode 3, MSB first, 8-bit words).

    Parameters
    ----------
    device : str
        Device path, e.g. ``/dev/spidev0.0`` or a udev symlink to it (on a Raspberry Pi not the
        aux SPI: no mode 3).
    speed_hz : int
        SPI clock, 4 to 20 MHz (see ``MIN_HZ``).
    bufsiz_path : str, optional
        Where the spidev buffer size is read (default ``BUFSIZ_PATH``; 4096 when absent).

    Attributes
    ----------
    warning : str
        Non-empty when the spidev buffer is smaller than one frame (see ``bufsiz_warning``).

    """

    packet_bytes = RAW14_PACKET_BYTES

    def __init__(self, device='/dev/spidev0.0', speed_hz=16_000_000, bufsiz_path=None):
        if not MIN_HZ <= speed_hz <= MAX_HZ:
            raise ValueError(f'SPI clock: expected {MIN_HZ} to {MAX_HZ} Hz, got {speed_hz} (a '
                             f'63-packet frame must be clocked out well within one 37.9 ms '
                             f'core period; the Lepton allows at most 20 MHz)')
        if not os.path.exists(device):
            raise FileNotFoundError(f'{device}: no such SPI device (is spidev enabled?)')
        import spidev
        self._spi = spidev.SpiDev()
        try:
            self._spi.open_path(device)
        except (OSError, ValueError) as error:
            raise OSError(f'{device}: cannot open ({error})') from None
        try:
            self._spi.mode = 3
            self._spi.max_speed_hz = int(speed_hz)
            self._spi.bits_per_word = 8
            self._fd = os.open(device, os.O_RDONLY)
        except (OSError, ValueError) as error:
            self._spi.close()
            raise OSError(f'{device}: cannot configure SPI mode 3 at {speed_hz} Hz '
                          f'({error})') from None
        buffer_bytes = spidev_buffer_size(bufsiz_path)
        self.max_read_bytes = read_size_for(buffer_bytes)
        self.warning = bufsiz_warning(buffer_bytes)
        self.seconds_per_byte = 8.0 / speed_hz
        self.device = device
        self._carry = b''

    def now(self):
        """Monotonic host time, seconds (stamps are mapped onto the node clock above)."""
        return time.monotonic()

    def read(self, nbytes):
        """
        Read whole packets (at most the spidev buffer per transfer).

        A spidev read returns every byte it clocked; a short read (a FIFO or a driver that
        splits transfers) keeps its partial packet for the next call, so no byte is lost. An
        empty read means the device went away: ``OSError``.
        """
        size = self.packet_bytes
        nbytes = max(size, min(nbytes, self.max_read_bytes) // size * size)
        data = self._carry
        while len(data) < size:
            more = os.read(self._fd, nbytes - len(data))
            if not more:
                raise OSError(f'{self.device}: read returned no data (device closed)')
            data += more
        whole = len(data) - len(data) % size
        self._carry = data[whole:]
        return data[:whole]

    def idle(self, seconds):
        """/CS is deasserted between transfers; not clocking for ``seconds`` idles the bus."""
        time.sleep(seconds)

    def wait(self, seconds):
        """Pause between frames."""
        time.sleep(seconds)

    def close(self):
        """Close the device (idempotent)."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None
            self._spi.close()
