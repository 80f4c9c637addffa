"""The driver's parameters: one list that the node declares and ``params --yaml`` documents."""

SIDES = ('left', 'right')

DRIVER_PARAMETERS = [
    ('source', 'sim', 'frame source: sim (two simulated cameras), capture (two raw capture '
     'files), spi (two Leptons on spidev), purethermal (two PureThermal USB boards) or bag '
     '(the raw image topics of a rosbag2)'),
    ('bag', '', 'bag: rosbag2 directory holding left/image_raw and right/image_raw'),
    ('telemetry', 'off', 'camera telemetry rows: off, header or footer (a capture says its '
     'own, or it is detected from its data)'),
    ('max_pair_delta', 0.06, 'largest difference of the two acquisition times of a stereo '
     'pair, seconds: two free-running Leptons drift through every phase, so their frames are '
     'up to half a unique-frame period (56.8 ms) apart; 0.06 pairs every frame (the matcher '
     'corrects the skew of moving features, docs/skew.md); 0.05 gives no pair 12 % of the '
     'time (see docs/lepton.md)'),
    ('duration', 0.0, 'stop after this many seconds of stream (0 = until the source ends)'),
    ('sim_depth', 3.5, 'sim: depth of the textured plane the cameras see, metres'),
    ('sim_texture', '', 'sim: texture image (empty = a shared thermal frame)'),
    ('spi_hz', 16000000, 'spi: SPI clock, Hz (4 to 20 MHz: a frame must be clocked out well '
     'within one 37.9 ms core period)'),
    ('spi_reader', 'process', 'spi: where each camera is read: process (its own process, never '
     'waiting for the GIL of this one: the default, measured to survive a busy neighbour) or '
     'thread (a thread of this process; enough when nothing else here holds the GIL)'),
    ('boot_timeout', 10.0, 'spi: seconds to wait for a camera to boot (I2C NACKs, then busy) '
     'before its start-up counts as failed and is retried'),
    ('give_up_after', 60.0, 'spi, purethermal: exit the node (non-zero, for launch respawn) '
     'when a camera has delivered no frame for this many seconds (0 = never)'),
] + [
    item for index, side in enumerate(SIDES) for item in (
        (f'{side}_capture', '', f'capture: raw capture file of the {side} camera'),
        (f'{side}_device', f'/dev/spidev0.{index}', f'spi: spidev device of the {side} camera'),
        (f'{side}_i2c_bus', index, f'spi: I2C bus number of the {side} camera CCI'),
        (f'{side}_serial', '', f'purethermal: serial number of the {side} board'),
        (f'{side}_video_device', f'/dev/video{2 * index}',
         f'purethermal: V4L2 device of the {side} board'),
        (f'{side}_camera_info_url', f'package://st_stereo/config/calibration/{side}.yaml',
         f'{side} camera_calibration YAML (file:// or package://)'),
        (f'{side}_frame_id', f'stereo_{side}_optical_frame', f'{side} optical frame id'),
    )
]
