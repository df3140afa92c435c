"""Sealing (§9.2): the 3-byte tags of control frames, HELLO and SYNC, and the MAC of a
thumbnail object, all from the shared key."""

from __future__ import annotations

from ..radio.auth import mac
from .bodies import SyncBody
from .wire import LABEL_HELLO, LABEL_SYNC, LABEL_THUMB, TAG_BYTES, _split, header


def control_tag(key: bytes, label: bytes, session: bytes, ctr: int, hdr: int, body: bytes) -> bytes:
    return mac(key, label, session, ctr.to_bytes(4, "big") + bytes([hdr]) + body)[:TAG_BYTES]


def seal_control(key: bytes, label: bytes, session: bytes, ctr: int, kind: int, body: bytes) -> list[bytes]:
    hdr = header(kind, ctr)
    return _split(bytes([hdr]) + body + control_tag(key, label, session, ctr, hdr, body))


def seal_hello(key: bytes, challenge: bytes) -> bytes:
    return bytes([0]) + challenge + mac(key, LABEL_HELLO, b"", bytes([0]) + challenge)[:TAG_BYTES]


def seal_sync(key: bytes, challenge: bytes, body: SyncBody) -> list[bytes]:
    raw = body.encode()
    return _split(bytes([0]) + raw + mac(key, LABEL_SYNC, challenge, bytes([0]) + raw)[:TAG_BYTES])


def object_mac(key: bytes, session: bytes, oid: int, obj: bytes) -> bytes:
    return mac(key, LABEL_THUMB, session, bytes([oid]) + obj)[:TAG_BYTES]
