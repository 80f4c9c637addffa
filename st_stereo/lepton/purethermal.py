"""
PureThermal USB boards (VID:PID 1e4e:0100): discovery by serial, Y16 frames, FFC over UVC.

Video comes through the kernel's UVC driver (V4L2 GRAY16 / Y16, 80x60 or 80x63 with footer
telemetry) read with OpenCV without RGB conversion; pyusb serves to find a board by its serial
number and to send CCI commands through the UVC extension units (AGC=3, OEM=4, RAD=5, SYS=6,
VID=7; control selector ``((command & 0xFF) >> 2) + 1``; SET_CUR 0x01, GET_CUR 0x81; wIndex =
unit << 8 | interface).

What was verified without hardware: the discovery filter, the serial matching and its errors,
the no-backend error, the control-transfer arguments (against a fake device), and the Y16
frame checks (against a fake capture). Not verified: a real board's enumeration, its V4L2
device naming, and the extension-unit numbering of a given firmware.
"""

import time

import numpy as np

VENDOR_ID = 0x1E4E
PRODUCT_ID = 0x0100
# Module IDs without the OEM/RAD protection bit 0x4000: AGC, OEM, RAD, SYS, VID.
UNIT_FOR_MODULE = {0x0100: 3, 0x0800: 4, 0x0E00: 5, 0x0200: 6, 0x0300: 7}
SET_CUR, GET_CUR = 0x01, 0x81


class PureThermalError(RuntimeError):
    """A board is missing, ambiguous, or its stream is not what we expect."""


def _usb_core():
    import usb.core
    return usb.core


def find_boards(find=None):
    """
    List connected PureThermal boards as (serial, device) pairs.

    ``find`` defaults to ``usb.core.find``; a missing libusb backend is a clear error.
    """
    if find is None:
        core = _usb_core()
        find = core.find
        no_backend = core.NoBackendError
    else:
        no_backend = ()
    try:
        devices = list(find(find_all=True, idVendor=VENDOR_ID, idProduct=PRODUCT_ID))
    except no_backend or ImportError:
        raise PureThermalError('pyusb found no libusb backend: install libusb-1.0 '
                               '(Debian: apt install libusb-1.0-0)') from None
    boards = []
    for device in devices:
        try:
            serial = device.serial_number
        except (ValueError, OSError):
            serial = None
        boards.append((serial, device))
    return boards


def find_board(serial, find=None):
    """Return the board with this serial number; an error lists what was found."""
    boards = find_boards(find)
    matches = [device for found, device in boards if found == serial]
    if len(matches) == 1:
        return matches[0]
    seen = ', '.join(str(found) for found, _ in boards) or 'none'
    if not matches:
        raise PureThermalError(f'no PureThermal board with serial {serial!r} (found: {seen})')
    raise PureThermalError(f'{len(matches)} boards report serial {serial!r}')


def extension_unit_request(command, get=False, interface=0):
    """
    USB control-transfer arguments of a CCI command through the UVC extension unit.

    Returns
    -------
    dict
        ``bmRequestType``, ``bRequest``, ``wValue``, ``wIndex`` for ``ctrl_transfer``.

    """
    module = command & 0xFF00 & ~0x4000
    if module not in UNIT_FOR_MODULE:
        raise ValueError(f'command 0x{command:04X}: no UVC extension unit for module '
                         f'0x{module:04X}')
    selector = ((command & 0xFF) >> 2) + 1
    return {'bmRequestType': 0xA1 if get else 0x21, 'bRequest': GET_CUR if get else SET_CUR,
            'wValue': selector << 8, 'wIndex': (UNIT_FOR_MODULE[module] << 8) | interface}


def run_ffc(device, interface=0):
    """Trigger a flat-field correction on a board (SYS run FFC through the extension unit)."""
    request = extension_unit_request(0x0242, get=False, interface=interface)
    device.ctrl_transfer(request['bmRequestType'], request['bRequest'], request['wValue'],
                         request['wIndex'], bytes(1))


class PureThermalCapture:
    """
    Y16 frames of a board's V4L2 device, raw 16-bit, never converted to RGB or 8 bits.

    Parameters
    ----------
    device : int or str
        V4L2 index or path (``/dev/videoN``).
    capture_factory : callable, optional
        Builds the OpenCV capture (tests pass a fake).

    """

    def __init__(self, device, capture_factory=None):
        import cv2
        self._cv2 = cv2
        if capture_factory is None:
            def capture_factory(dev):
                return cv2.VideoCapture(dev, cv2.CAP_V4L2)
        self.capture = capture_factory(device)
        if not self.capture.isOpened():
            raise PureThermalError(f'{device}: cannot open the V4L2 device')
        self.capture.set(cv2.CAP_PROP_FOURCC, cv2.VideoWriter_fourcc(*'Y16 '))
        self.capture.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        self.device = device

    def read(self):
        """Return (pixels (60, 80) uint16, footer telemetry rows or None)."""
        ok, frame = self.capture.read()
        if not ok or frame is None:
            raise PureThermalError(f'{self.device}: no frame (device gone or stream stopped)')
        frame = np.asarray(frame)
        if frame.dtype != np.uint16:
            raise PureThermalError(f'{self.device}: expected 16-bit Y16 frames, got '
                                   f'{frame.dtype}; is the stream set to Y16?')
        frame = frame.reshape(frame.shape[0], -1)
        if frame.shape == (60, 80):
            return frame, None
        if frame.shape == (63, 80):
            return frame[:60], frame[60:]
        raise PureThermalError(f'{self.device}: expected 80x60 or 80x63 frames, got '
                               f'{frame.shape[1]}x{frame.shape[0]}')

    def close(self):
        """Release the device."""
        self.capture.release()


class _MonotonicClock:
    """The transport face of a board: the clock of its stamps, and its name."""

    def __init__(self, device):
        self.now = time.monotonic
        self.device = device


class PureThermalReader:
    """
    A PureThermal board with the reader's interface (``read_frame``, ``counters``, ``close``).

    Frames are stamped with ``time.monotonic()`` when V4L2 returned them (the UVC driver's
    buffering adds a delay the host cannot see). Copies and FFC-frozen frames are suppressed
    by content, as for SPI (``DuplicateFilter``).
    """

    def __init__(self, serial, video_device, capture_factory=None, find=None, counters=None):
        from st_stereo.lepton.assembler import LeptonCounters
        from st_stereo.lepton.reader import DuplicateFilter
        self.serial = serial
        self.device = find_board(serial, find) if serial else None   # clear error if absent
        self.capture = PureThermalCapture(video_device, capture_factory)
        self.transport = _MonotonicClock(f'purethermal:{serial or video_device}')
        self.counters = counters if counters is not None else LeptonCounters()
        self.duplicates = DuplicateFilter()
        self._index = 0
        self._previous_stamp = None

    def read_frame(self, timeout_s=1.0):
        """Return the next new frame, or None for a copy (V4L2 reads block)."""
        from st_stereo.lepton.packets import CORE_FRAME_PERIOD_S
        from st_stereo.lepton.reader import count_new_frame, first_copy_known, in_ffc, \
            LeptonFrame
        from st_stereo.lepton.telemetry import parse_telemetry_row_a
        pixels, rows = self.capture.read()
        stamp = time.monotonic()
        previous, self._previous_stamp = self._previous_stamp, stamp
        counters = self.counters
        counters.frames_completed += 1
        telemetry = None
        if rows is not None:
            telemetry = parse_telemetry_row_a(rows[0].astype('>u2').tobytes())
        unique, ffc = count_new_frame(self.duplicates, counters, pixels, in_ffc(telemetry))
        if not unique:
            return None
        # A board that sends every core frame (copies too): the stamp is the first copy's only
        # when the frame before it was read one core period earlier. A board that sends only
        # unique frames: every stamp but the first is as good as V4L2 gives.
        if counters.duplicates:
            exact = first_copy_known(previous, stamp, CORE_FRAME_PERIOD_S)
        else:
            exact = previous is not None
        frame = LeptonFrame(pixels, stamp, self._index, telemetry, ffc, stamp_exact=exact)
        self._index += 1
        return frame

    def run_ffc(self):
        """Run an FFC through the board's UVC extension unit (needs the board's serial)."""
        if self.device is None:
            raise PureThermalError(f'{self.transport.device}: FFC needs the board found by '
                                   f'its serial number (parameter <side>_serial)')
        try:
            run_ffc(self.device)
        except (OSError, ValueError) as error:     # usb.core.USBError is an OSError
            raise PureThermalError(f'{self.transport.device}: FFC failed ({error})') from None

    def close(self):
        """Release the V4L2 device."""
        self.capture.close()
