"""MCAP Message records whose JSON bodies are laid out from numpy columns, many rows at once, without a Python
step per message.

A body is a template: literal texts and columns alternating, e.g. `{"counter":` counter `,"gyro":[` gyro `]}`.
Each column (n,) or (n, k) of integers or floats is printed by orjson in C (an integer's digits, a float's shortest
text that reads back as the same float, null for NaN and infinities; a row of k numbers joined by commas) and split
into one text per row; the record heads are one numpy array whose rows carry the literal texts around them. One
`bytes.join` then lays out every record of the rows: a message costs a few list slots, and the numbers orjson's
printing. The bytes are those of printing each message's JSON document alone (`orjson.dumps` of its dict), which
the tests hold.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import orjson

from bench.log.bulk_messages import message_heads

#: a record's head: opcode, length, channel, sequence, log time, publish time
HEAD_BYTES = 31


@dataclass(frozen=True)
class JsonMessage:
    """One message of each row: its channel and its body's pieces, literal `bytes` and columns (arrays of the
    rows' numbers, n rows first) in the order of the text."""

    channel_id: int
    pieces: tuple[bytes | np.ndarray, ...]


def _check(column: np.ndarray) -> None:
    if column.dtype.kind not in "iuf" or column.ndim not in (1, 2) or (column.ndim == 2 and not column.shape[1]):
        raise ValueError(f"a column of numbers (n,) or (n, k) to print as JSON, not {column.dtype} {column.shape}")


def _kind(column: np.ndarray) -> tuple[str, np.dtype]:
    """How a column is printed: ("float", its dtype) by orjson's float printing; ("integral", int64) for float64
    whole numbers that orjson prints as an integer's digits and ".0" (below 1e16 it does; -0.0 excepted), printed
    so (an integer's digits cost a fraction of a float's); ("int", int64 or uint64) for integers."""
    if column.dtype.kind == "i" or (column.dtype.kind == "u" and (not column.size or column.max() < 2**63)):
        return "int", np.dtype(np.int64)
    if column.dtype.kind == "u":
        return "int", np.dtype(np.uint64)
    if column.dtype == np.float64 and column.size and float(column.flat[-1]).is_integer() and \
            -INTEGRAL_BELOW < column.min() <= column.max() < INTEGRAL_BELOW:
        # (the last number first: a column of fractions is told by it) NaN fails the bounds; a whole number is
        # its own integer part; a zero may be -0.0 (printed so)
        if (column == np.trunc(column)).all() and not np.signbit(column).any(where=column == 0.0):
            return "integral", np.dtype(np.int64)
    return "float", column.dtype


#: float64 whole numbers below this are printed by orjson as an integer's digits and ".0" (10**16 as 1e16)
INTEGRAL_BELOW = 1e15


def _print_table(columns: Sequence[np.ndarray], kind: str, dtype: np.dtype,
                 n: int) -> list[tuple[list[bytes], np.ndarray]]:
    """Each column's rows as JSON text (a row of several numbers comma-joined) and their lengths, the columns
    (of one `_kind`) printed by one orjson call on the rows laid side by side: one number after the other, the
    commas that end a column's row marked to split there."""
    widths = [1 if c.ndim == 1 else c.shape[1] for c in columns]
    table = np.empty((n, sum(widths)), dtype)
    at = 0
    for column, width in zip(columns, widths):
        table[:, at:at + width] = column.reshape(n, width)
        at += width
    text = orjson.dumps(table.reshape(-1), option=orjson.OPT_SERIALIZE_NUMPY)     # [x,x,...]
    if kind == "integral":
        text = text[:-1].replace(b",", b".0,") + b".0]"
    buf = np.frombuffer(text, np.uint8)
    # where each number ends (the comma after it; the last one at the "]")
    ends = np.append(np.flatnonzero(buf == 44), len(text) - 1).reshape(n, -1)
    column_ends = ends[:, np.cumsum(widths) - 1]        # (n, columns)
    starts = np.empty_like(column_ends)
    starts[:, 1:] = column_ends[:, :-1] + 1
    starts[1:, 0] = column_ends[:-1, -1] + 1
    starts[0, 0] = 1
    marked = buf.copy()
    marked[column_ends.reshape(-1)] = 10                 # the "]" too: the split's last piece is empty
    pieces = marked[1:].tobytes().split(b"\n")
    count = len(columns)
    lengths = column_ends - starts
    return [(pieces[k:n * count:count], lengths[:, k]) for k in range(count)]


def _print(columns: Sequence[np.ndarray], n: int) -> dict[int, tuple[list[bytes], np.ndarray]]:
    """`_print_table` of the columns by kind, keyed by the id of each column."""
    groups: dict[tuple[str, np.dtype], list[np.ndarray]] = {}
    for column in columns:
        groups.setdefault(_kind(column), []).append(column)
    printed: dict[int, tuple[list[bytes], np.ndarray]] = {}
    for (kind, dtype), group in groups.items():
        for column, texts in zip(group, _print_table(group, kind, dtype, n)):
            printed[id(column)] = texts
    return printed


def _constant_text(column: np.ndarray) -> bytes | None:
    """The JSON text of a column's rows when they all hold the same numbers (None otherwise)."""
    if len(column) < 2 or not np.array_equal(column[0], column[-1]) or not (column == column[0]).all():
        return None             # (the first and the last row first: most columns differ there)
    if column.dtype.kind == "f" and not (np.signbit(column) == np.signbit(column[0])).all():
        return None             # 0.0 and -0.0: equal, printed apart
    text = orjson.dumps(np.ascontiguousarray(column[:1]), option=orjson.OPT_SERIALIZE_NUMPY)
    return text[1:-1] if column.ndim == 1 else text[2:-2]


def _layout(pieces: Sequence[bytes | np.ndarray]) -> tuple[list[bytes], list[np.ndarray]]:
    """(literals, columns) with len(literals) == len(columns) + 1: adjacent literals merged, an empty literal
    between adjacent columns and at the ends."""
    literals: list[bytes] = [b""]
    columns: list[np.ndarray] = []
    for piece in pieces:
        if isinstance(piece, bytes):
            literals[-1] += piece
        else:
            columns.append(piece)
            literals.append(b"")
    return literals, columns


def _items(trail: bytes, heads: np.ndarray, lead: bytes) -> list[bytes]:
    """Per row: `trail` (the end of the message before), the head, `lead` (the body's first literal)."""
    fields = ([("trail", f"S{len(trail)}")] if trail else []) + [("head", heads.dtype)] + \
        ([("lead", f"S{len(lead)}")] if lead else [])
    rows = np.zeros(len(heads), fields)
    rows["head"] = heads
    if trail:
        rows["trail"] = trail
    if lead:
        rows["lead"] = lead
    width = rows.dtype.itemsize
    if lead and lead[-1] != 0:      # numpy's bytes drop trailing NULs only: a row as one bytes, in C
        return rows.view(f"S{width}").tolist()
    packed = rows.tobytes()
    return [packed[k:k + width] for k in range(0, len(packed), width)]


def json_records(messages: Sequence[JsonMessage], log_times_ns: np.ndarray) -> tuple[bytes, np.ndarray]:
    """The Message records of every row's messages (row 0's in the order of `messages`, then row 1's, ...), each
    at its row's log time (also its publish time), sequence 0, back to back; and each record's size in bytes.
    A column that appears in several messages (the same array) is printed once."""
    n = len(log_times_ns)
    constants: dict[int, bytes | None] = {}
    for message in messages:
        for piece in message.pieces:
            if not isinstance(piece, bytes) and id(piece) not in constants:
                _check(piece)
                if len(piece) != n:
                    raise ValueError(f"a column of {len(piece)} rows for {n} log times")
                constants[id(piece)] = _constant_text(piece)
    if not n:
        return b"", np.zeros(0, np.int64)
    # a column of one value in every row is printed once, as a literal (a status word, a missing temperature)
    layouts = [_layout([constants.get(id(p)) or p if not isinstance(p, bytes) else p for p in m.pieces])
               for m in messages]
    distinct = {id(c): c for _literals, columns in layouts for c in columns}
    printed = _print(list(distinct.values()), n)
    sizes = np.zeros((n, len(messages)), np.int64)
    for k, (literals, columns) in enumerate(layouts):
        sizes[:, k] = HEAD_BYTES + sum(map(len, literals))
        for column in columns:
            sizes[:, k] += printed[id(column)][1]
    # a row's list slots: per message its head item (with the literals around it), then column, literal, ...,
    # column; the message's last literal opens the next message's head item
    row: list[bytes] = []                 # the literals in place, b"" where the rows' texts go
    slots: list[tuple[int, list[bytes]]] = []
    trails = [literals[-1] if columns else b"" for literals, columns in layouts]
    for k, (message, (literals, columns)) in enumerate(zip(messages, layouts)):
        heads = message_heads(message.channel_id, log_times_ns, sizes[:, k])
        trail = trails[k - 1]             # the row's last message's, for the first one (none before row 0)
        slots.append((len(row), _items(trail, heads, literals[0])))
        row.append(b"")
        for j, column in enumerate(columns):
            slots.append((len(row), printed[id(column)][0]))
            row += [b"", literals[j + 1]] if j + 1 < len(columns) else [b""]
    parts = row * n
    for at, texts in slots:
        parts[at::len(row)] = texts
    parts[0] = parts[0][len(trails[-1]):]
    parts.append(trails[-1])
    return b"".join(parts), sizes.reshape(-1)


__all__ = ["HEAD_BYTES", "JsonMessage", "json_records"]
