"""
VoSPI packets of the FLIR Lepton 2: IDs, discard packets, CRC-16, Raw14 payloads.

A packet is a 2-byte ID, a 2-byte CRC and a payload, big-endian (Lepton datasheet 500-0659-00-09
pp. 46-48). Raw14 packets are 164 bytes: 80 pixels of 16 bits. Pure functions on bytes: no I/O.
"""

import binascii
import dataclasses

import numpy as np

PIXELS_PER_ROW = 80
PAYLOAD_BYTES = 2 * PIXELS_PER_ROW
RAW14_PACKET_BYTES = 4 + PAYLOAD_BYTES
RGB888_PACKET_BYTES = 244
IMAGE_ROWS = 60
TELEMETRY_ROWS = 3
DISCARD_MASK = 0x0F00
NUMBER_MASK = 0x0FFF

# Timing (../shared/notes/lepton.md): the core makes a frame about 26.4 times a second and
# sends every unique frame three times, so unique frames come at just under 9 Hz.
CORE_FRAME_HZ = 26.4
COPIES_PER_UNIQUE_FRAME = 3
CORE_FRAME_PERIOD_S = 1.0 / CORE_FRAME_HZ
UNIQUE_FRAME_HZ = CORE_FRAME_HZ / COPIES_PER_UNIQUE_FRAME
UNIQUE_FRAME_PERIOD_S = 1.0 / UNIQUE_FRAME_HZ


def is_discard(packet_id):
    """Discard packets fill idle time: ``(id & 0x0F00) == 0x0F00``."""
    return (packet_id & DISCARD_MASK) == DISCARD_MASK


def packet_number(packet_id):
    """Packet (row) number of a Lepton 2 packet: the low 12 bits of the ID."""
    return packet_id & NUMBER_MASK


def segment_number(packet_id):
    """Lepton 3 segment field, bits 14..12 of the ID (valid on packet 20 only; 0 = invalid)."""
    return (packet_id >> 12) & 0x7


# CRC of the masked 4-byte head (ID with its top 4 bits cleared, CRC field zeroed) for every
# 12-bit ID value: the payload's CRC continues from it (crc_hqx chains).
_HEAD_CRC = [binascii.crc_hqx(bytes((i >> 8, i & 0xFF, 0, 0)), 0) for i in range(4096)]


def packet_crc(packet):
    """
    CRC-16 of a packet as the camera computes it (datasheet p. 48).

    CRC-16/XMODEM (polynomial 0x1021, initial value 0, no reflection) over the whole packet
    with the four most significant bits of the ID and the CRC field itself set to zero.
    """
    head = ((packet[0] & 0x0F) << 8) | packet[1]
    return binascii.crc_hqx(memoryview(packet)[4:], _HEAD_CRC[head])


@dataclasses.dataclass(frozen=True)
class Packet:
    """One parsed packet."""

    packet_id: int
    number: int
    segment: int
    discard: bool
    crc: int
    crc_ok: bool
    payload: bytes


def parse_packet(packet, packet_bytes=RAW14_PACKET_BYTES):
    """
    Parse one packet; the CRC is checked unless it is a discard packet.

    Raises
    ------
    ValueError
        When ``packet`` is not ``packet_bytes`` long.

    """
    if len(packet) != packet_bytes:
        raise ValueError(f'VoSPI packet: expected {packet_bytes} bytes, got {len(packet)}')
    packet_id = (packet[0] << 8) | packet[1]
    crc = (packet[2] << 8) | packet[3]
    discard = is_discard(packet_id)
    crc_ok = discard or packet_crc(packet) == crc
    return Packet(packet_id, packet_number(packet_id), segment_number(packet_id), discard, crc,
                  crc_ok, bytes(packet[4:]))


def make_packet(number, payload, segment=0):
    """Encode a packet with a valid CRC (the camera's side; used by the simulator and tests)."""
    payload = _payload_bytes(payload)
    packet_id = ((segment & 0x7) << 12) | (number & NUMBER_MASK)
    head = bytes(((packet_id >> 8) & 0xFF, packet_id & 0xFF, 0, 0))
    crc = packet_crc(head + payload)
    return head[:2] + bytes(((crc >> 8) & 0xFF, crc & 0xFF)) + payload


def make_discard_packet(fill=0):
    """Return a discard packet (ID 0x0Fxx); its CRC and payload are don't-care."""
    return _DISCARDS[fill & 0xFF]


_DISCARDS = [bytes((0x0F, fill, 0, 0)) + bytes(PAYLOAD_BYTES) for fill in range(256)]


def _payload_bytes(payload):
    if isinstance(payload, (bytes, bytearray)):
        if len(payload) != PAYLOAD_BYTES:
            raise ValueError(f'payload: expected {PAYLOAD_BYTES} bytes, got {len(payload)}')
        return bytes(payload)
    pixels = np.asarray(payload)
    if pixels.shape != (PIXELS_PER_ROW,):
        raise ValueError(f'payload: expected {PIXELS_PER_ROW} pixels, got shape {pixels.shape}')
    return pixels.astype('>u2').tobytes()


def packet_heads(chunk, packet_bytes=RAW14_PACKET_BYTES):
    """Return the IDs and CRC fields of every packet of a chunk, as two lists (vectorised)."""
    words = np.frombuffer(chunk, dtype='>u2').reshape(-1, packet_bytes // 2)
    return words[:, 0].tolist(), words[:, 1].tolist()


def crc_matches(view, offset, packet_id, crc_field, packet_bytes=RAW14_PACKET_BYTES):
    """Check one packet of a memoryview against its CRC field (see ``packet_crc``)."""
    return binascii.crc_hqx(view[offset + 4:offset + packet_bytes],
                            _HEAD_CRC[packet_id & NUMBER_MASK]) == crc_field


def encode_frame_packets(payloads, segment=0):
    """
    Encode the packets of a frame at once: packet n carries ``payloads[n]``.

    Parameters
    ----------
    payloads : ndarray, shape (n, 80)
        Pixel words of each packet.
    segment : int
        Lepton 3 segment field to put in the IDs (0 for a Lepton 2).

    Returns
    -------
    bytes
        The n packets, concatenated, with valid CRCs.

    """
    payloads = np.asarray(payloads)
    count = len(payloads)
    words = np.empty((count, 2 + PIXELS_PER_ROW), dtype='>u2')
    words[:, 0] = ((segment & 0x7) << 12) | np.arange(count)
    words[:, 1] = 0
    words[:, 2:] = payloads
    blob = bytearray(words.tobytes())
    size = RAW14_PACKET_BYTES
    view = memoryview(blob)
    for number in range(count):
        offset = number * size
        crc = binascii.crc_hqx(view[offset + 4:offset + size], _HEAD_CRC[number])
        blob[offset + 2] = crc >> 8
        blob[offset + 3] = crc & 0xFF
    return bytes(blob)
