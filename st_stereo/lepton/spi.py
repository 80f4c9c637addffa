"""
The SPI transport of a real rig: Linux spidev, mode 3, whole packets per ``os.read``.

Thin on purpose: configuration through the ``spidev`` module, bulk reads with ``os.read`` on
the device file (``SpiDev.readbytes`` caps at 4096 bytes), each read a whole number of packets
no larger than the spidev buffer (module parameter ``bufsiz``, 4096 by default: 24 packets).
Everything above it (packets, frames, resync) is exercised with the simulator.
"""

import os
import time

from st_stereo.lepton.packets import RAW14_PACKET_BYTES

BUFSIZ_PATH = '/sys/module/spidev/parameters/bufsiz'
MIN_HZ, MAX_HZ = 2_000_000, 20_000_000


def spidev_buffer_size(path=BUFSIZ_PATH, default=4096):
    """Return the spidev buffer size in bytes (``bufsiz`` module parameter) or the default."""
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


class SpiTransport:
    """
    VoSPI over ``/dev/spidevB.C`` (mode 3, MSB first, 8-bit words).

    Parameters
    ----------
    device : str
        Device path, e.g. ``/dev/spidev0.0`` (on a Raspberry Pi not the aux SPI: no mode 3).
    speed_hz : int
        SPI clock, 2 to 20 MHz (datasheet).

    """

    packet_bytes = RAW14_PACKET_BYTES

    def __init__(self, device='/dev/spidev0.0', speed_hz=16_000_000):
        if not MIN_HZ <= speed_hz <= MAX_HZ:
            raise ValueError(f'SPI clock: expected {MIN_HZ} to {MAX_HZ} Hz, got {speed_hz}')
        if not os.path.exists(device):
            raise FileNotFoundError(f'{device}: no such SPI device (is spidev enabled?)')
        import spidev
        bus, _, chip = os.path.basename(device)[len('spidev'):].partition('.')
        self._spi = spidev.SpiDev()
        try:
            self._spi.open(int(bus), int(chip))
        except (OSError, ValueError) as error:
            raise OSError(f'{device}: cannot open ({error})') from None
        self._spi.mode = 3
        self._spi.max_speed_hz = int(speed_hz)
        self._spi.bits_per_word = 8
        self._fd = os.open(device, os.O_RDONLY)
        self.max_read_bytes = read_size_for(spidev_buffer_size())
        self.seconds_per_byte = 8.0 / speed_hz
        self.device = device

    def now(self):
        """Host time for stamps (the ROS clock's source: wall time)."""
        return time.time()

    def read(self, nbytes):
        """Read whole packets (at most the spidev buffer per transfer)."""
        nbytes = min(nbytes, self.max_read_bytes)
        return os.read(self._fd, nbytes)

    def idle(self, seconds):
        """/CS is deasserted between transfers; not clocking for ``seconds`` idles the bus."""
        time.sleep(seconds)

    def wait(self, seconds):
        """Pause between frames."""
        time.sleep(seconds)

    def close(self):
        """Close the device."""
        os.close(self._fd)
        self._spi.close()
