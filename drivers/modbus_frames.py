"""Modbus framing that every Modbus device shares, no I/O: the RTU CRC, the exception codes' names, and why
bytes received in reply to a request did not decode (the turntable's and the chamber's register maps sit above
this; the request machinery, `drivers.modbus_link`, uses it)."""

from __future__ import annotations

from drivers.errors import DeviceChecksumError, DeviceProtocolError, quote_bytes

#: the exception codes of the Modbus application protocol specification
EXCEPTION_NAMES = {
    1: "illegal function",
    2: "illegal data address",
    3: "illegal data value",
    4: "server device failure",
    5: "acknowledge",
    6: "server device busy",
    7: "negative acknowledge",
    8: "memory parity error",
    10: "gateway path unavailable",
    11: "gateway target device failed to respond",
}

def exception_name(code: int | None) -> str:
    """'illegal data address' for 2, ...; 'unknown exception' for codes Modbus does not define (or none)."""
    if code is None:
        return "unknown exception"
    return EXCEPTION_NAMES.get(code, "unknown exception")


def crc16(data: bytes) -> bytes:
    """The Modbus RTU CRC of `data`, as the two bytes that follow it on the wire (low byte first)."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc.to_bytes(2, "little")


def explain_bad_reply(raw: bytes, framing: str, unit: int, function_code: int,
                      transaction_id: int | None = None) -> DeviceProtocolError:
    """Why bytes received in reply to a request did not decode: a typed error to raise.

    `framing` is 'rtu' or 'tcp'. A reply that looks like ours (unit and function code,
    or MBAP transaction id) with a wrong CRC -> `DeviceChecksumError`; a malformed
    MBAP header -> `DeviceProtocolError` naming the field; anything else is garbage.
    """
    raw = bytes(raw)
    if framing == "rtu":
        if len(raw) >= 4 and raw[0] == unit and raw[1] & 0x7F == function_code:
            if crc16(raw[:-2]) != raw[-2:]:
                return DeviceChecksumError(
                    f"reply CRC {raw[-2:].hex(' ')} does not match its content (expected "
                    f"{crc16(raw[:-2]).hex(' ')}): {quote_bytes(raw, hex_dump=True)}", raw)
            return DeviceProtocolError(f"reply frame does not decode: {quote_bytes(raw, hex_dump=True)}", raw)
        return DeviceProtocolError(f"garbage instead of a Modbus RTU reply: {quote_bytes(raw, hex_dump=True)}", raw)
    if framing != "tcp":
        raise ValueError(f"framing must be 'rtu' or 'tcp', got {framing!r}")
    if len(raw) >= 8 and (transaction_id is None or int.from_bytes(raw[0:2], "big") == transaction_id):
        protocol = int.from_bytes(raw[2:4], "big")
        length = int.from_bytes(raw[4:6], "big")
        if protocol != 0:
            return DeviceProtocolError(f"malformed MBAP header: protocol id {protocol} (must be 0): "
                                          f"{quote_bytes(raw, hex_dump=True)}", raw)
        if length != len(raw) - 6:
            return DeviceProtocolError(f"malformed MBAP header: length field {length} but {len(raw) - 6} "
                                          f"bytes follow it: {quote_bytes(raw, hex_dump=True)}", raw)
        return DeviceProtocolError(f"reply PDU does not decode: {quote_bytes(raw, hex_dump=True)}", raw)
    return DeviceProtocolError(f"garbage instead of a Modbus TCP reply: {quote_bytes(raw, hex_dump=True)}", raw)


__all__ = ["EXCEPTION_NAMES", "crc16", "exception_name", "explain_bad_reply"]
