"""`json_records` lays out the Message records one `orjson.dumps` of each message's dict and a record head
would make, byte for byte, for columns of every kind (issue 33, item 6)."""

from __future__ import annotations

import struct

import numpy as np
import orjson
import pytest

from bench.log.json_records import JsonMessage, json_records

_HEAD = struct.Struct("<BQHIQQ")


def _columns(n: int, seed: int) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    floats = rng.normal(0, 1, (n, 3)) * 10.0 ** rng.integers(-12, 20, (n, 3))
    specials = [np.nan, np.inf, -np.inf, -0.0, 0.0, 1e16, 1e15, 2.0**53, 5e-324, 1e-7]
    at = np.arange(0, floats.size, 7)
    floats.flat[at] = np.resize(specials, len(at))
    whole = np.rint(rng.normal(0, 3000, (n, 3)))      # counts: printed as integers and ".0"
    whole[n // 2:] *= 1000
    return {
        "counter": np.arange(n, dtype=np.int64) + 2**40,
        "time": 0.005 + np.arange(n) / 200,
        "floats": floats,
        "whole": whole,
        "whole_and_minus_zero": np.where(np.arange(n)[:, None] % 3 == 0, -0.0, whole),
        "whole_past_1e16": np.resize([1e16, 2.0**53, -3.0, 1e15, 1e17], n),    # orjson: 1e16, 9007199254740992.0
        "big_unsigned": np.arange(n, dtype=np.uint64) + np.uint64(2**63 + 5),
        "constant": np.full(n, 25.0),
        "constant_vector": np.tile([1.5, -2.0, 0.0], (n, 1)),
        "zeros_of_both_signs": np.where(np.arange(n) % 2 == 0, 0.0, -0.0),
        "nan": np.full(n, np.nan),
        "status": np.zeros(n, np.int32),
    }


def _expected(columns: dict[str, np.ndarray], names: list[str], row: int) -> bytes:
    def value(name: str):
        x = columns[name][row]
        return x.tolist() if isinstance(x, np.ndarray) else x.item()
    return orjson.dumps({name: value(name) for name in names})


def _read(data: bytes) -> list[tuple[int, int, int, int, int, bytes]]:
    """(opcode, channel, sequence, log time, publish time, body) of each record, checking each length."""
    records, at = [], 0
    while at < len(data):
        opcode, length, channel, sequence, log_time, publish_time = _HEAD.unpack_from(data, at)
        records.append((opcode, channel, sequence, log_time, publish_time, data[at + _HEAD.size:at + 9 + length]))
        at += 9 + length
    assert at == len(data)
    return records


def _pieces(columns: dict[str, np.ndarray], names: list[str]) -> tuple[bytes | np.ndarray, ...]:
    """The body of `{name: value, ...}`: the keys and brackets as literals, the values as columns."""
    pieces: list[bytes | np.ndarray] = []
    for k, name in enumerate(names):
        vector = columns[name].ndim == 2
        pieces += [(("{" if k == 0 else ",") + f'"{name}":' + ("[" if vector else "")).encode(), columns[name]]
        pieces += [b"]"] if vector else []
    return (*pieces, b"}")


@pytest.mark.parametrize("n", [0, 1, 2, 9, 2500])
def test_the_records_are_those_of_each_message_alone(n):
    columns = _columns(n, seed=n)
    first = ["counter", "time", "floats", "whole", "whole_and_minus_zero", "whole_past_1e16", "big_unsigned",
             "constant", "constant_vector", "zeros_of_both_signs", "nan", "status"]
    second = ["counter", "time", "whole"]      # the same arrays as the first message's: printed once
    messages = [JsonMessage(3, _pieces(columns, first)), JsonMessage(7, _pieces(columns, second)),
                JsonMessage(4, (b"{}",))]
    times = (np.arange(n, dtype=np.uint64) * np.uint64(10**6) + np.uint64(5))[::-1].copy()   # any order
    data, sizes = json_records(messages, times)
    records = _read(data)
    assert len(records) == len(sizes) == 3 * n
    assert sizes.tolist() == [9 + len(body) + 22 for *_, body in records]
    expected = [(5, channel, 0, int(times[row]), int(times[row]), body)
                for row in range(n)
                for channel, body in [(3, _expected(columns, first, row)), (7, _expected(columns, second, row)),
                                      (4, b"{}")]]
    assert records == expected


def test_a_body_that_starts_with_a_number_and_a_message_of_columns_alone():
    n = 40
    columns = _columns(n, seed=1)
    messages = [JsonMessage(1, (columns["counter"], b",", columns["time"])),
                JsonMessage(2, (columns["whole"],))]
    times = np.arange(n, dtype=np.uint64)
    records = _read(json_records(messages, times)[0])
    texts = [(r[1], r[5]) for r in records]
    assert texts == [pair for row in range(n) for pair in
                     [(1, orjson.dumps([int(columns["counter"][row]), float(columns["time"][row])])[1:-1]),
                      (2, orjson.dumps(columns["whole"][row].tolist())[1:-1])]]


def test_a_column_that_is_not_one_of_numbers_is_refused():
    with pytest.raises(ValueError, match="column of numbers"):
        json_records([JsonMessage(1, (b"{", np.array(["a", "b"]), b"}"))], np.zeros(2, np.uint64))
    with pytest.raises(ValueError, match="rows for 3 log times"):
        json_records([JsonMessage(1, (b"{", np.zeros(2), b"}"))], np.zeros(3, np.uint64))
