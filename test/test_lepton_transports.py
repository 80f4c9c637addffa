"""The thin hardware transports, tested against fakes (no camera is attached here)."""

import numpy as np
import pytest
from st_stereo.lepton import purethermal
from st_stereo.lepton.spi import (bufsiz_warning, read_size_for, spidev_buffer_size,
                                  SpiTransport)


def test_spidev_buffer_and_read_size(tmp_path):
    path = tmp_path / 'bufsiz'
    path.write_text('65536\n')
    assert spidev_buffer_size(path) == 65536
    assert spidev_buffer_size(tmp_path / 'missing') == 4096
    # A read is whole packets (a packet split across reads is lost to the assembler) and as
    # large as the kernel buffer allows (each read costs a system call and a chip select).
    for buffer_bytes in (164, 4096, 65536, 164 * 30 + 163):
        size = read_size_for(buffer_bytes)
        assert size % 164 == 0 and 0 < size <= buffer_bytes < size + 164
    with pytest.raises(ValueError, match='raise the spidev bufsiz'):
        read_size_for(100)


def test_spi_transport_errors_are_clear():
    with pytest.raises(ValueError, match='SPI clock'):
        SpiTransport('/dev/spidev0.0', speed_hz=40_000_000)
    # 2 MHz cannot clock a 63-packet frame out within one 37.9 ms core period.
    with pytest.raises(ValueError, match='within one 37.9 ms core period'):
        SpiTransport('/dev/spidev0.0', speed_hz=2_000_000)
    with pytest.raises(FileNotFoundError, match='/dev/spidev9.9: no such SPI device'):
        SpiTransport('/dev/spidev9.9')


def test_bufsiz_below_one_frame_warns_with_the_module_option():
    assert 'spidev.bufsiz=65536' in bufsiz_warning(4096)
    assert 'options spidev bufsiz=65536' in bufsiz_warning(4096)
    assert '3 reads' in bufsiz_warning(4096)
    assert bufsiz_warning(65536) == ''


def test_spi_transport_opens_a_udev_symlink_by_path_and_never_loses_bytes(tmp_path,
                                                                          monkeypatch):
    import os
    import sys
    from st_stereo.lepton.fakes import fake_spidev_module
    closed = []
    monkeypatch.setitem(sys.modules, 'spidev', fake_spidev_module(closed))
    fifo = tmp_path / 'spidev3.1'
    os.mkfifo(fifo)
    link = tmp_path / 'lepton_left'             # as a udev rule names it: no bus.chip in it
    link.symlink_to(fifo)
    writer = os.open(fifo, os.O_RDWR | os.O_NONBLOCK)
    bufsiz = tmp_path / 'bufsiz'
    bufsiz.write_text('65536\n')
    transport = SpiTransport(str(link), 8_000_000, bufsiz_path=bufsiz)
    assert transport.warning == '' and transport.max_read_bytes == 399 * 164
    packets = bytes(i % 251 for i in range(164 * 3))           # three packets
    os.write(writer, packets[:100])              # a short read: a partial packet waits
    os.write(writer, packets[100:400])
    first = transport.read(164 * 3)
    os.write(writer, packets[400:])
    second = transport.read(164 * 3)
    assert first + second == packets and len(first) % 164 == 0
    transport.close()
    transport.close()                            # idempotent
    os.close(writer)
    assert closed == [(str(link), {'mode': 3, 'max_speed_hz': 8_000_000, 'bits_per_word': 8})]


class FakeUsbDevice:
    def __init__(self, serial):
        self.serial_number = serial
        self.transfers = []

    def ctrl_transfer(self, *args):
        self.transfers.append(args)


def fake_find(devices):
    def find(find_all, idVendor, idProduct):       # noqa: N803 - pyusb's keyword names
        assert (idVendor, idProduct) == (0x1E4E, 0x0100)
        return iter(devices)
    return find


def test_boards_are_found_by_serial():
    boards = [FakeUsbDevice('PT-A'), FakeUsbDevice('PT-B')]
    assert purethermal.find_board('PT-B', fake_find(boards)) is boards[1]
    with pytest.raises(purethermal.PureThermalError, match="'PT-C' \\(found: PT-A, PT-B\\)"):
        purethermal.find_board('PT-C', fake_find(boards))
    with pytest.raises(purethermal.PureThermalError, match='2 boards report'):
        purethermal.find_board('X', fake_find([FakeUsbDevice('X'), FakeUsbDevice('X')]))


def test_no_libusb_backend_is_a_clear_error(monkeypatch):
    import usb.core

    def no_backend(**kwargs):
        raise usb.core.NoBackendError('No backend available')
    monkeypatch.setattr(usb.core, 'find', no_backend)
    with pytest.raises(purethermal.PureThermalError, match='no libusb backend'):
        purethermal.find_boards()


def test_ffc_goes_through_the_sys_extension_unit():
    request = purethermal.extension_unit_request(0x0242)
    assert request == {'bmRequestType': 0x21, 'bRequest': 0x01, 'wValue': (0x42 >> 2) + 1 << 8,
                       'wIndex': 6 << 8}
    device = FakeUsbDevice('PT')
    purethermal.run_ffc(device)
    assert device.transfers[0][:4] == (0x21, 0x01, 17 << 8, 6 << 8)
    assert purethermal.extension_unit_request(0x4842)['wIndex'] == 4 << 8   # OEM
    with pytest.raises(ValueError, match='no UVC extension unit'):
        purethermal.extension_unit_request(0x0942)


class FakeCapture:
    def __init__(self, frames):
        self.frames = list(frames)
        self.settings = {}

    def isOpened(self):                       # noqa: N802 - OpenCV's method name
        return True

    def set(self, key, value):                # noqa: A003 - OpenCV's method name
        self.settings[key] = value

    def read(self):
        if not self.frames:
            return False, None
        return True, self.frames.pop(0)

    def release(self):
        pass


def test_y16_frames_with_and_without_telemetry_rows():
    import cv2
    frames = [np.full((60, 80), 8000, np.uint16), np.full((63, 80), 9000, np.uint16)]
    capture = purethermal.PureThermalCapture(0, lambda dev: FakeCapture(frames))
    assert capture.capture.settings[cv2.CAP_PROP_CONVERT_RGB] == 0
    pixels, telemetry = capture.read()
    assert pixels.dtype == np.uint16 and telemetry is None
    pixels, telemetry = capture.read()
    assert pixels.shape == (60, 80) and telemetry.shape == (3, 80)
    with pytest.raises(purethermal.PureThermalError, match='no frame'):
        capture.read()


def test_8_bit_streams_are_refused():
    capture = purethermal.PureThermalCapture(
        0, lambda dev: FakeCapture([np.zeros((60, 80, 3), np.uint8)]))
    with pytest.raises(purethermal.PureThermalError, match='expected 16-bit Y16'):
        capture.read()


def test_purethermal_reader_stamps_new_frames_and_counts_copies():
    first = np.full((63, 80), 8000, np.uint16)
    second = first.copy()
    second[5, 5] = 8100
    frames = [first, first.copy(), second]
    reader = purethermal.PureThermalReader(
        'PT-A', 0, capture_factory=lambda dev: FakeCapture(frames),
        find=fake_find([FakeUsbDevice('PT-A')]))
    got = [reader.read_frame(), reader.read_frame(), reader.read_frame()]
    assert got[0].pixels.shape == (60, 80) and got[1] is None and got[2].index == 1
    assert reader.counters.duplicates == 1 and reader.counters.unique_frames == 2
    with pytest.raises(purethermal.PureThermalError, match='no PureThermal board'):
        purethermal.PureThermalReader('PT-Z', 0, lambda dev: FakeCapture(frames),
                                      fake_find([FakeUsbDevice('PT-A')]))


def test_purethermal_reader_flags_the_first_frame_after_a_frozen_ffc():
    # A board sending unique frames: one announced "imminent", frozen copies of it while the
    # FFC runs (not published), then a new frame with telemetry 'complete' whose level moved.
    from st_stereo.lepton.telemetry import encode_telemetry_row_a

    def frame(level, state, counter):
        out = np.zeros((63, 80), np.uint16)
        out[:60] = level + np.arange(80, dtype=np.uint16)
        row_a = encode_telemetry_row_a(counter, ffc_state=state)
        out[60] = np.frombuffer(row_a, dtype='>u2')
        return out

    frames = [frame(8000, 'complete', 0), frame(8010, 'imminent', 1),
              frame(8010, 'in_progress', 2), frame(8010, 'in_progress', 3),
              frame(8010, 'in_progress', 4), frame(8040, 'complete', 5),
              frame(8050, 'complete', 6)]
    reader = purethermal.PureThermalReader(
        'PT-A', 0, capture_factory=lambda dev: FakeCapture(frames),
        find=fake_find([FakeUsbDevice('PT-A')]))
    got = [reader.read_frame() for _ in frames]
    published = [(f.telemetry.frame_counter, f.ffc_in_progress) for f in got if f is not None]
    assert published == [(0, False), (1, True), (5, True), (6, False)]
    assert reader.counters.ffc_frames == 4
