"""Running the driver (or the whole pipeline) against the wall-clock rig emulator."""

import collections
import dataclasses
import time

from diagnostic_msgs.msg import DiagnosticArray
import numpy as np
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Image
from st_stereo.lepton.emulator import pixels_digest

UNIQUE_PERIOD_S = 3 / 26.4


@dataclasses.dataclass
class Published:
    """What a subscriber received from the driver."""

    images: dict = dataclasses.field(default_factory=lambda: {'left': [], 'right': []})
    pair_info: list = dataclasses.field(default_factory=list)
    statuses: dict = dataclasses.field(default_factory=dict)
    arrivals: list = dataclasses.field(default_factory=list)   # (monotonic, side)


class RigSubscriber(Node):
    """Records every raw image (stamp, digest of its pixels), pair_info and diagnostics."""

    def __init__(self, context, namespace='stereo'):
        super().__init__('rig_subscriber', context=context, namespace=namespace)
        self.got = Published()
        qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
        for side in ('left', 'right'):
            self.create_subscription(Image, f'{side}/image_raw',
                                     lambda msg, side=side: self._on_image(side, msg), qos)
        self.create_subscription(DiagnosticArray, 'pair_info', self.got.pair_info.append, qos)
        self.create_subscription(DiagnosticArray, '/diagnostics', self._on_diagnostics, 10)

    def _on_image(self, side, msg):
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        pixels = np.frombuffer(bytes(msg.data), dtype='<u2').reshape(msg.height, msg.width)
        self.got.images[side].append((stamp, pixels_digest(pixels), msg.header.frame_id))
        self.got.arrivals.append((time.monotonic(), side))

    def _on_diagnostics(self, msg):
        for status in msg.status:
            self.got.statuses[status.name] = (status.level, status.message,
                                              {kv.key: kv.value for kv in status.values})


def spi_parameters(rig, **extra):
    """Driver parameters for the emulated rig on SPI (CCI on buses 0 and 1)."""
    values = {'source': 'spi', 'left_device': rig.devices['left'],
              'right_device': rig.devices['right'], 'telemetry': 'footer',
              'left_i2c_bus': 0, 'right_i2c_bus': 1}
    values.update(extra)
    return [Parameter(name, value=value) for name, value in values.items()]


def pairs_of(got):
    """Stamp -> {side: (digest, frame_id)} of every received image."""
    pairs = collections.defaultdict(dict)
    for side, images in got.images.items():
        for stamp, digest, frame_id in images:
            pairs[stamp].setdefault(side, []).append((digest, frame_id))
    return pairs


def check_stream(got, sent, min_pairs_per_s, window):
    """
    Assert what the issue asks of a published stream against what the cameras sent.

    Every image equals a frame its camera sent, no frame twice, one left and one right image
    per stamp, the two of a pair within one unique frame of each other, and at least
    ``min_pairs_per_s`` pairs per second over ``window`` (monotonic start, end).
    """
    by_digest = {}
    for side, frames in sent.items():
        # An FFC repeats a frame's pixels: the first frame sent with them is the original.
        by_digest[side] = {}
        for frame in frames:
            by_digest[side].setdefault(frame.digest, frame)
    for side, images in got.images.items():
        digests = [digest for _, digest, _ in images]
        unknown = [d for d in digests if d not in by_digest[side]]
        where = [digests.index(d) for d in unknown]
        assert not unknown, f'{side}: images {where} of {len(digests)} were never sent'
        assert len(set(digests)) == len(digests), f'{side}: a frame was published twice'
    pairs = pairs_of(got)
    for stamp, sides in pairs.items():
        assert set(sides) == {'left', 'right'}, f'stamp {stamp}: only {set(sides)}'
        assert len(sides['left']) == len(sides['right']) == 1, f'stamp {stamp} used twice'
        left = by_digest['left'][sides['left'][0][0]]
        right = by_digest['right'][sides['right'][0][0]]
        assert abs(left.stamp - right.stamp) <= UNIQUE_PERIOD_S, \
            f'stamp {stamp}: left frame {left.unique} at {left.stamp:.3f} s, right frame ' \
            f'{right.unique} at {right.stamp:.3f} s: more than one unique frame apart'
    start, end = window
    arrivals = [t for t, side in got.arrivals if side == 'left' and start <= t <= end]
    rate = len(arrivals) / (end - start)
    assert rate >= min_pairs_per_s, f'{rate:.2f} pairs/s between {start:.1f} and {end:.1f}'
    return rate
