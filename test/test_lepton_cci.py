"""CCI over I2C: the command sequence against a fake register file."""

import pytest
from st_stereo.lepton.cci import (CciError, CMD_PING, CMD_REBOOT, CMD_RUN_FFC,
                                  LeptonCCI, RUN, SMBus2Bus)
from st_stereo.lepton.fakes import FakeCciRegisters


class FakeCamera:
    def __init__(self):
        self.reboots = 0
        self.ffcs = 0

    def reboot(self):
        self.reboots += 1

    def run_ffc(self):
        self.ffcs += 1


def make(camera=None, **kwargs):
    registers = FakeCciRegisters(camera, **kwargs)
    return LeptonCCI(registers, sleep=lambda s: None), registers


def test_ping_waits_for_not_busy():
    cci, registers = make(busy_polls=5)
    cci.ping()
    assert registers.log == [CMD_PING | RUN]


def test_run_ffc_and_reboot_reach_the_camera():
    camera = FakeCamera()
    cci, registers = make(camera)
    cci.run_ffc()
    cci.reboot()
    assert camera.ffcs == 1 and camera.reboots == 1
    assert registers.log == [CMD_RUN_FFC, CMD_REBOOT]


def test_telemetry_settings_round_trip():
    cci, _ = make()
    cci.set_telemetry(True, 'footer')
    assert cci.telemetry() == (True, 'footer')
    cci.set_telemetry(False, 'header')
    assert cci.telemetry() == (False, 'header')
    with pytest.raises(ValueError, match='telemetry location'):
        cci.set_telemetry(True, 'middle')


def test_fpa_temperature():
    cci, _ = make(fpa_temperature_k=299.87)
    assert cci.fpa_temperature_k() == pytest.approx(299.87)


def test_camera_error_codes_are_reported():
    cci, _ = make()
    with pytest.raises(CciError, match='0x0ABC: camera error -7 \\(undefined function\\)'):
        cci.command(0x0ABC)


def test_busy_forever_times_out_instead_of_hanging():
    clock = iter(range(1000))
    registers = FakeCciRegisters()
    registers.stuck_busy = True
    cci = LeptonCCI(registers, timeout_s=5, clock=lambda: next(clock), sleep=lambda s: None)
    with pytest.raises(CciError, match='still busy after 5 s'):
        cci.ping()


def test_missing_i2c_bus_is_a_clear_error():
    with pytest.raises(OSError, match='/dev/i2c-97: cannot open the I2C bus'):
        SMBus2Bus(97)
