"""
Telemetry row A of the Lepton 2 (80 big-endian words; 32-bit values least-significant word first).

Word map (``../shared/notes/lepton.md``): 0 revision; 1-2 uptime ms; 3-4 status (bit 3 FFC
desired, bits 4-5 FFC state, bit 12 AGC, bit 15 shutter lockout, bit 20 over-temperature);
5-12 serial; 13-16 software revision; 20-21 frame counter; 22 frame mean; 23 FPA temperature
counts; 24 FPA temperature K x 100; 25 housing temperature counts; 26 housing temperature
K x 100.
"""

import dataclasses

import numpy as np

from st_stereo.lepton.packets import PAYLOAD_BYTES

FFC_STATES = ('never_commanded', 'imminent', 'in_progress', 'complete')


@dataclasses.dataclass(frozen=True)
class Telemetry:
    """Decoded telemetry row A."""

    revision: int
    uptime_ms: int
    status: int
    serial: str
    software_revision: str
    frame_counter: int
    frame_mean: int
    fpa_temperature_counts: int
    fpa_temperature_k: float
    housing_temperature_counts: int
    housing_temperature_k: float

    @property
    def ffc_desired(self):
        """Status bit 3: the camera asks for a flat-field correction."""
        return bool(self.status & (1 << 3))

    @property
    def ffc_state(self):
        """Status bits 4-5: never_commanded, imminent, in_progress or complete."""
        return FFC_STATES[(self.status >> 4) & 0x3]

    @property
    def agc_enabled(self):
        """Status bit 12."""
        return bool(self.status & (1 << 12))

    @property
    def shutter_lockout(self):
        """Status bit 15."""
        return bool(self.status & (1 << 15))

    @property
    def overtemperature(self):
        """Status bit 20."""
        return bool(self.status & (1 << 20))


def _u32(words, index):
    return int(words[index]) | (int(words[index + 1]) << 16)


def parse_telemetry_row_a(payload):
    """Decode telemetry row A from a 160-byte payload."""
    if len(payload) != PAYLOAD_BYTES:
        raise ValueError(f'telemetry row A: expected {PAYLOAD_BYTES} bytes, got {len(payload)}')
    words = np.frombuffer(payload, dtype='>u2')
    return Telemetry(
        revision=int(words[0]), uptime_ms=_u32(words, 1), status=_u32(words, 3),
        serial=words[5:13].astype('>u2').tobytes().hex(),
        software_revision=words[13:17].astype('>u2').tobytes().hex(),
        frame_counter=_u32(words, 20), frame_mean=int(words[22]),
        fpa_temperature_counts=int(words[23]), fpa_temperature_k=int(words[24]) / 100.0,
        housing_temperature_counts=int(words[25]),
        housing_temperature_k=int(words[26]) / 100.0)


def encode_telemetry_row_a(frame_counter, uptime_ms=0, fpa_temperature_k=300.0,
                           housing_temperature_k=301.0, ffc_state='complete',
                           ffc_desired=False, agc=False, serial=0x1234, frame_mean=0,
                           revision=14):
    """Encode telemetry row A (the camera's side; for the simulator and tests)."""
    words = np.zeros(PAYLOAD_BYTES // 2, dtype=np.uint32)
    status = (FFC_STATES.index(ffc_state) << 4) | (int(ffc_desired) << 3) | (int(agc) << 12)
    words[0] = revision
    words[1], words[2] = uptime_ms & 0xFFFF, (uptime_ms >> 16) & 0xFFFF
    words[3], words[4] = status & 0xFFFF, (status >> 16) & 0xFFFF
    words[5:13] = [(serial >> (16 * i)) & 0xFFFF for i in range(8)][::-1]
    words[20], words[21] = frame_counter & 0xFFFF, (frame_counter >> 16) & 0xFFFF
    words[22] = frame_mean & 0xFFFF
    words[23] = int(round(fpa_temperature_k * 10)) & 0xFFFF
    words[24] = int(round(fpa_temperature_k * 100)) & 0xFFFF
    words[25] = int(round(housing_temperature_k * 10)) & 0xFFFF
    words[26] = int(round(housing_temperature_k * 100)) & 0xFFFF
    return words.astype('>u2').tobytes()
