"""VoSPI packets and telemetry: CRC test vectors, parsing, encoding round trips."""

import numpy as np
import pytest
from st_stereo.lepton.packets import (encode_frame_packets, is_discard, make_discard_packet,
                                      make_packet, packet_crc, parse_packet,
                                      RAW14_PACKET_BYTES, segment_number)
from st_stereo.lepton.telemetry import encode_telemetry_row_a, parse_telemetry_row_a


def test_crc_test_vectors_of_the_datasheet():
    first = make_packet(0x0005, np.full(80, 8000))
    assert (first[2] << 8) | first[3] == 0x1961
    second = bytes((0x30, 0x14, 0, 0)) + np.arange(8000, 8080).astype('>u2').tobytes()
    assert packet_crc(second) == 0x9B98      # the ID's top 4 bits are masked


def test_parse_round_trip_and_crc_check():
    packet = make_packet(17, np.arange(80))
    parsed = parse_packet(packet)
    assert parsed.number == 17 and parsed.crc_ok and not parsed.discard
    assert np.array_equal(np.frombuffer(parsed.payload, '>u2'), np.arange(80))
    broken = bytearray(packet)
    broken[50] ^= 1
    assert not parse_packet(bytes(broken)).crc_ok


def test_discard_packets():
    packet = make_discard_packet(0x12)
    assert is_discard((packet[0] << 8) | packet[1])
    assert parse_packet(packet).discard and parse_packet(packet).crc_ok


def test_lepton3_segment_field_is_parsed():
    packet = make_packet(20, np.zeros(80), segment=3)
    assert parse_packet(packet).segment == 3 and parse_packet(packet).number == 20
    assert segment_number(0x3014) == 3


def test_wrong_packet_size_is_named():
    with pytest.raises(ValueError, match='expected 164 bytes, got 163'):
        parse_packet(bytes(163))
    with pytest.raises(ValueError, match='expected 80 pixels'):
        make_packet(0, np.zeros(81))


def test_frame_encoder_matches_the_single_packet_encoder(rng):
    payloads = rng.integers(0, 16384, (63, 80))
    blob = encode_frame_packets(payloads)
    assert len(blob) == 63 * RAW14_PACKET_BYTES
    for number in (0, 20, 62):
        assert blob[number * 164:(number + 1) * 164] == make_packet(number, payloads[number])


def test_telemetry_row_a_round_trip():
    row = encode_telemetry_row_a(123456, uptime_ms=98765, fpa_temperature_k=301.23,
                                 housing_temperature_k=302.5, ffc_state='in_progress',
                                 ffc_desired=True, agc=True, serial=0xABCDEF)
    telemetry = parse_telemetry_row_a(row)
    assert telemetry.frame_counter == 123456 and telemetry.uptime_ms == 98765
    assert telemetry.fpa_temperature_k == pytest.approx(301.23)
    assert telemetry.housing_temperature_k == pytest.approx(302.5)
    assert telemetry.ffc_state == 'in_progress' and telemetry.ffc_desired
    assert telemetry.agc_enabled and not telemetry.overtemperature
    assert telemetry.serial.endswith('abcdef')
