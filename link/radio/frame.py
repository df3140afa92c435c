"""Framing of docs/PROTOCOL.md §1: start byte, length, payload, CRC-16/CCITT-FALSE.

Goals: never lose a true frame to line noise, never hand up a frame whose CRC
fails, and never block on bytes that may never come.

Plan: `encode_frame` builds one frame.  `FrameDecoder` keeps a small receive
buffer; every `feed` scans it for a start byte, checks the candidate when all
its bytes are there, and on a CRC failure drops only that start byte and hunts
again from the next byte.  (1.1) A `LEN` above `max_len` (the largest
payload the receiver expects: the ROV's largest poll, the operator's largest
reply for its last poll's SIZE, within the link's frame limit) is no start,
so a noise 0x55 can hold a true frame back only until enough bytes follow.
Version 1.1 delivers no frame early: a CRC-valid frame inside an incomplete
candidate waits until that candidate fails (version 2's early delivery of
authentic frames is `link.auth.AuthFrameDecoder`).
"""

from __future__ import annotations

from dataclasses import dataclass

START = 0x55
MAX_PAYLOAD = 255
MAX_FRAME = MAX_PAYLOAD + 4
OVERHEAD = 4  # start, length, two CRC bytes


def _make_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1021) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _make_table()


def crc16(data: bytes, crc: int = 0xFFFF) -> int:
    """CRC-16/CCITT-FALSE: poly 0x1021, init 0xFFFF, no reflection, no final XOR."""
    table = _CRC_TABLE
    for byte in data:
        crc = ((crc << 8) & 0xFFFF) ^ table[(crc >> 8) ^ byte]
    return crc


def frame_contents(frame: bytes) -> bytes:
    """The bytes between a whole frame's LEN and its CRC (its payload; in version 2 with COUNT and TAG)."""
    return frame[2:-2]


def encode_frame(payload: bytes) -> bytes:
    """Wrap a payload of 1..255 bytes into a frame."""
    n = len(payload)
    if not 1 <= n <= MAX_PAYLOAD:
        raise ValueError(f"frame payload must be 1..{MAX_PAYLOAD} bytes, got {n}")
    body = bytes((n,)) + bytes(payload)
    return bytes((START,)) + body + crc16(body).to_bytes(2, "big")


@dataclass
class DecoderCounters:
    frames: int = 0  # valid frames delivered
    crc_errors: int = 0  # candidates whose CRC failed (or whose LEN was 0)
    bytes_skipped: int = 0  # bytes dropped while hunting for a start byte
    oversize: int = 0  # start bytes whose LEN exceeded max_len (no start, §1 (1.1))


class FrameDecoder:
    """Turns a byte stream (or datagrams) into the payloads of valid frames."""

    def __init__(self, max_len: int = MAX_PAYLOAD) -> None:
        self._buf = bytearray()
        self.counters = DecoderCounters()
        self.max_len = max_len  # the receiver may lower it per poll (§1 (1.1))

    @property
    def max_len(self) -> int:
        return self._max_len

    @max_len.setter
    def max_len(self, value: int) -> None:
        if not 1 <= value <= MAX_PAYLOAD:
            raise ValueError(f"max_len must be 1..{MAX_PAYLOAD}, got {value}")
        self._max_len = value

    @property
    def frames(self) -> int:
        return self.counters.frames

    @property
    def crc_errors(self) -> int:
        return self.counters.crc_errors

    @property
    def bytes_skipped(self) -> int:
        return self.counters.bytes_skipped

    @property
    def pending(self) -> int:
        """Bytes held while waiting for the rest of a candidate frame."""
        return len(self._buf)

    def reset(self) -> None:
        """Forget a partial frame (after a transport was reopened)."""
        self.counters.bytes_skipped += len(self._buf)
        self._buf.clear()

    def feed(self, data: bytes) -> list[bytes]:
        """Add received bytes; return the payloads of the frames they completed."""
        buf = self._buf
        buf.extend(data)
        out: list[bytes] = []
        while True:
            start = buf.find(START)
            if start < 0:
                self._skip(len(buf))
                break
            if start:
                self._skip(start)
            if len(buf) < 2:
                break
            status = self._check(0)
            if status is True:
                out.append(self._take(0))
                continue
            if status is False:
                self._skip(1)
                continue
            break  # incomplete candidate: wait for its bytes
        return out

    # -- helpers -----------------------------------------------------------

    def _check(self, i: int) -> bool | None:
        """True: valid frame at i; False: no start (LEN 0 or over max_len) or bad CRC; None: incomplete."""
        buf = self._buf
        if i + 1 >= len(buf):
            return None
        n = buf[i + 1]
        if n == 0:
            self.counters.crc_errors += 1
            return False
        if n > self._max_len:
            self.counters.oversize += 1
            return False
        end = i + 2 + n + 2
        if end > len(buf):
            return None
        crc = crc16(buf[i + 1 : i + 2 + n])
        if crc != (buf[end - 2] << 8 | buf[end - 1]):
            self.counters.crc_errors += 1
            return False
        return True

    def _take(self, i: int) -> bytes:
        buf = self._buf
        n = buf[i + 1]
        payload = bytes(buf[i + 2 : i + 2 + n])
        del buf[: i + 4 + n]
        self.counters.frames += 1
        return payload

    def _skip(self, n: int) -> None:
        del self._buf[:n]
        self.counters.bytes_skipped += n
