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


class BootingCamera:
    """NACKs for ``nack_polls`` transfers, then reports booting for ``busy_polls`` more."""

    def __init__(self, nack_polls, busy_polls):
        self.nack_left, self.busy_left = nack_polls, busy_polls
        self.layout = None

    def cci_acknowledges(self):
        if self.nack_left > 0:
            self.nack_left -= 1
            return False
        return True

    def cci_booted(self):
        if self.busy_left > 0:
            self.busy_left -= 1
            return False
        return True

    def set_telemetry(self, enabled, location):
        self.layout = location if enabled else 'off'


def test_start_waits_through_nacks_and_busy_then_sets_telemetry():
    camera = BootingCamera(nack_polls=5, busy_polls=4)
    registers = FakeCciRegisters(camera)
    cci = LeptonCCI(registers, sleep=lambda s: None)
    cci.start('footer')
    assert camera.nack_left == 0 and camera.busy_left == 0
    assert camera.layout == 'footer' and cci.telemetry() == (True, 'footer')
    cci.start('off')
    assert camera.layout == 'off'


def test_start_names_what_a_camera_that_never_boots_said():
    clock = iter(range(100))
    cci = LeptonCCI(FakeCciRegisters(BootingCamera(10 ** 6, 0)), clock=lambda: next(clock),
                    sleep=lambda s: None)
    with pytest.raises(CciError, match=r'not booted after 5 s \(no answer on I2C'):
        cci.wait_booted(timeout_s=5)
    cci = LeptonCCI(FakeCciRegisters(BootingCamera(0, 10 ** 6)), clock=lambda: next(clock),
                    sleep=lambda s: None)
    with pytest.raises(CciError, match='status 0x0001: booting'):
        cci.wait_booted(timeout_s=5)


def test_start_refuses_a_camera_that_does_not_take_the_telemetry_setting():
    registers = FakeCciRegisters()
    real_execute = registers._execute

    def ignore_location(command):
        real_execute(command)
        registers.values[0x021C] = [0, 0]        # the camera stays on 'header'
    registers._execute = ignore_location
    with pytest.raises(CciError, match='telemetry: set to footer, the camera reports header'):
        LeptonCCI(registers, sleep=lambda s: None).start('footer')


def test_a_nack_mid_command_is_a_cci_error_naming_the_command():
    camera = BootingCamera(0, 0)
    cci = LeptonCCI(FakeCciRegisters(camera), sleep=lambda s: None)
    camera.nack_left = 10 ** 6
    with pytest.raises(CciError, match='command 0x0242: no answer on I2C'):
        cci.run_ffc()


def test_commands_from_two_threads_keep_their_register_sequences_whole():
    # Without the lock, one thread's command word lands between the other's data length and
    # command writes (the fake yields between register writes, as a real bus would).
    import threading
    import time as time_module

    class SlowRegisters(FakeCciRegisters):
        def write_words(self, register, words):
            time_module.sleep(0.0005)
            super().write_words(register, words)

    registers = SlowRegisters(busy_polls=0)
    cci = LeptonCCI(registers, sleep=lambda s: None)
    errors = []

    def hammer(action):
        try:
            for _ in range(40):
                action()
        except CciError as error:
            errors.append(error)

    def set_footer():
        cci.set_telemetry(True, 'footer')
    threads = [threading.Thread(target=hammer, args=(set_footer,)),
               threading.Thread(target=hammer, args=(cci.run_ffc,))]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors
    assert cci.telemetry() == (True, 'footer')
