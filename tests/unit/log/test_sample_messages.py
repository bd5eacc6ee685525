"""`/imu/samples` messages made a block at a time: the exact text and log times, non-finite values as null."""

from __future__ import annotations

import json

import numpy as np

from bench.log.format import imu_sample_messages
from drivers.imu import ImuSampleBlock


def _block(temperature=25.5, receive=(0.1, 0.105, 0.11)) -> ImuSampleBlock:
    g = np.array([[1.0, -2.0, 0.1], [3.0, 4.0, 5.0], [0.0, 1e-9, 123456.75]])
    return ImuSampleBlock(np.array([20, 21, 22]), np.array(receive, float), g, -g,
                          np.full(3, temperature), np.array([0, 1, 2]), 200.0)


def test_the_text_is_the_recorders():
    (t0, first), (t1, _), (t2, last) = imu_sample_messages(_block())
    assert (t0, t1, t2) == (100_000_000, 105_000_000, 110_000_000)
    assert first == (b'{"counter":20,"time_s":0.1,"imu_time_s":0.1,"gyro_counts":[1.0,-2.0,0.1],'
                     b'"acc_counts":[-1.0,2.0,-0.1],"gyro_rate":[200.0,-400.0,20.0],'
                     b'"acc_rate":[-200.0,400.0,-20.0],"temperature_c":25.5,"status":0}')
    body = json.loads(last)
    assert body["gyro_counts"] == [0.0, 1e-9, 123456.75] and body["gyro_rate"] == [0.0, 1e-9 * 200.0, 123456.75 * 200]
    assert body["imu_time_s"] == 22 / 200.0


def test_non_finite_values_are_null_and_times_before_zero_are_zero():
    block = _block(temperature=float("nan"), receive=(-1.0, float("nan"), 0.2))
    block.gyro_counts[1, 2] = np.inf
    messages = imu_sample_messages(block)
    assert [t for t, _ in messages] == [0, 0, 200_000_000]
    bodies = [json.loads(body) for _, body in messages]
    assert [b["time_s"] for b in bodies] == [-1.0, None, 0.2]
    assert all(b["temperature_c"] is None for b in bodies)
    assert bodies[1]["gyro_counts"] == [3.0, 4.0, None] and bodies[1]["gyro_rate"] == [600.0, 800.0, None]
    assert bodies[0]["gyro_counts"] == [1.0, -2.0, 0.1]


def test_decimation_keeps_every_nth_counter():
    assert [json.loads(body)["counter"] for _, body in imu_sample_messages(_block(), decimation=2)] == [20, 22]
    assert imu_sample_messages(_block(), decimation=50) == []



def _repr_text(block: ImuSampleBlock) -> list[str]:
    """Each sample's four vectors as `repr` prints them (the text every path must give)."""
    def text(v) -> str:
        return ",".join(map(repr, v))

    rate = block.rate_hz
    return [f'"gyro_counts":[{text(g)}],"acc_counts":[{text(a)}],"gyro_rate":[{text([x * rate for x in g])}],'
            f'"acc_rate":[{text([x * rate for x in a])}]'
            for g, a in zip(block.gyro_counts.tolist(), block.acc_counts.tolist())]


def _whole_block(first: list[float]) -> ImuSampleBlock:
    g = np.random.default_rng(7).integers(-40_000, 40_000, (20, 3)).astype(float)
    g[0] = first
    return ImuSampleBlock(np.arange(20), np.linspace(0.1, 0.2, 20), g, g[::-1].copy(), np.full(20, 25.0),
                          np.zeros(20, int), 200.0)


def test_whole_counts_print_as_repr_does():
    # plain whole counts; a negative zero (its repr keeps the sign); whole numbers whose rates pass 1e16
    # (printed with an exponent)
    for first in ([1.0, 2.0, 3.0], [0.0, -0.0, 5.0], [4.9e13, -4.9e13, 1.0], [9.0e14, 0.0, -7.0]):
        block = _whole_block(first)
        bodies = [body.decode() for _, body in imu_sample_messages(block)]
        assert len(bodies) == 20
        for body, expected in zip(bodies, _repr_text(block)):
            assert expected in body
