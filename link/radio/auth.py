"""Version 2 of the link: every frame authenticated (docs/PROTOCOL.md §8), without I/O.

Goals: a frame made without the key is refused (about 2^-28 per try); a
recorded frame is refused anywhere but at its one place in its one chain;
a poll held back is refused once a newer one has been taken; the ROV's
restarts are known to the operator (BOOT).  No new dependency: hashlib's
BLAKE2s.

Plan: the chain is one sequence of MACs.  `mac(key, kind, prev, data)` is
BLAKE2s(KIND || PREV || DATA) keyed with K; a frame's TAG is the first 4
bytes, its chain value the whole 32.  Two small state machines keep the
chain values each end must remember and decide what is authentic, fresh
and late; they take the bytes between a frame's LEN and its CRC (what
`AuthFrameDecoder` delivers) and the current time, and build whole frames:

- `RovChain` (the slave's end): `check_poll` -> a `HelloIn`, a `PollIn`, or
  None (inauthentic, replayed, stale); the caller parses a PollIn's payload
  and then calls `take(poll, now)`, so that an authentic poll that does not
  parse moves no reference (§8).  `seal_reply` / `seal_sync` build the answer.
- `OperatorChain` (the master's end): `seal_hello`, `seal_poll` build what it
  sends; `open_reply` -> a `ReplyIn` (SYNC or reply, `late` or not) or None.
- `AuthFrameDecoder`: §1's framing with version 2's early delivery: while a
  candidate is incomplete, a complete authentic frame at a later 0x55 is
  delivered at once, and the earlier candidate still completes.

Decisions where §8 is silent (safe side, few bytes):
- A kept chain value older than the ROV's failsafe time is never matched,
  even if fewer than 8 are kept (§8 "there too ... older than the failsafe
  time"); expiry is checked on every poll.
- A HELLO with a CHALLENGE seen before is counted as a replay; the ROV's
  record of challenges is a FIFO of the last 4096.
- The operator's COUNT starts at a random value (an operator may start it
  anywhere; a random start makes a restarted operator's polls unlike the
  previous process's).
- The operator pairs every reply with the frame it answers by the chain
  value its tag was made on, never with "the poll it awaits".  One poll or
  HELLO is out at a time (the token rule, §2), so a reply is timely only
  when it answers the last frame sent, for the first time, by that frame's
  own deadline (the master's timeout for that very poll or HELLO, given
  when it is sealed); anything else is late: counted, never used.
"""

from __future__ import annotations

import collections
import hashlib
import hmac
import math
import os
import stat
from dataclasses import dataclass
from typing import Callable

from .frame import START
from .messages import FAILSAFE_S, HELLO_BIT, ORDER_BITS, POLL_HEADER, REPLY_HEADER, ProtocolError, is_sync
from .wire2 import V2_MAX_CONTENTS, V2_OVERHEAD, encode_frame2

KEY_BYTES = 32
TAG_BYTES = 4
MAC_BYTES = 32
CHALLENGE_BYTES = 8
NONCE_BYTES = 12  # BOOT (4) then 8 new bytes
BOOT_BYTES = 4
COUNT_BYTES = 1
HELLO_PAYLOAD = POLL_HEADER  # a HELLO: a poll's header, HELLO set, no order (then its CHALLENGE)
SYNC_PAYLOAD = REPLY_HEADER  # a SYNC: a reply without image data, SYNC set (then its NONCE)

KIND_HELLO, KIND_SYNC, KIND_POLL, KIND_REPLY = b"H", b"S", b"P", b"R"

ROV_KEEP_REPLIES = 8
ROV_KEEP_SYNCS = 8
ROV_CHALLENGES_SEEN = 4096
OPERATOR_KEEP_HELLOS = 4
OPERATOR_KEEP_POLLS = 8
COUNT_WINDOW = 127  # a poll is taken when its COUNT is 1..127 ahead of the last taken
KEEP_FAILSAFES = 2  # §8.1: a kept chain value lives at most this many failsafe times


class KeyFileError(ValueError):
    """A key file or key that cannot be used."""


def mac(key: bytes, kind: bytes, prev: bytes, data: bytes) -> bytes:
    """The 32-byte chain value of a frame: BLAKE2s(KIND || PREV || DATA, key=K)."""
    return hashlib.blake2s(kind + prev + data, key=key, digest_size=MAC_BYTES).digest()


def _check_key(key: bytes) -> bytes:
    if not isinstance(key, (bytes, bytearray)) or len(key) != KEY_BYTES:
        raise KeyFileError(f"a link key is {KEY_BYTES} bytes")
    return bytes(key)


def _tag_matches(key: bytes, kind: bytes, prev: bytes, signed: bytes, tag: bytes) -> bytes | None:
    value = mac(key, kind, prev, signed)
    return value if hmac.compare_digest(value[:TAG_BYTES], tag) else None


# ---------------------------------------------------------------------------
# Keys on disk
# ---------------------------------------------------------------------------


def new_key() -> bytes:
    return os.urandom(KEY_BYTES)


def write_key_file(path: str, key: bytes | None = None) -> bytes:
    """Write a new key as 64 hex digits to a new file of mode 0600; never overwrite."""
    key = _check_key(new_key() if key is None else key)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(key.hex() + "\n")
    return key


def read_key_file(path: str) -> bytes:
    """The key in `path`; KeyFileError when it is missing, readable by others or malformed."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise KeyFileError(f"no such key file: {path}") from None
    except OSError as exc:
        raise KeyFileError(f"cannot read key file {path}: {exc.strerror}") from None
    if stat.S_ISDIR(st.st_mode):
        raise KeyFileError(f"{path} is a directory, not a key file: name the key file itself "
                           f"(make one with rovlink keygen FILE)")
    if st.st_mode & 0o077:
        raise KeyFileError(f"key file {path} is readable by others (mode {st.st_mode & 0o777:o}); "
                        f"chmod 600 {path}, or make a new key with rovlink keygen")
    try:
        with open(path, encoding="ascii") as f:
            text = f.read().strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise KeyFileError(f"cannot read key file {path}: {exc}") from None
    try:
        key = bytes.fromhex(text)
    except ValueError:
        key = b""
    if len(key) != KEY_BYTES:
        raise KeyFileError(f"key file {path} does not hold {2 * KEY_BYTES} hex digits")
    return key


# ---------------------------------------------------------------------------
# The ROV's end
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class HelloIn:
    payload: bytes  # 3 bytes
    challenge: bytes
    chain: bytes  # the HELLO's chain value: the SYNC's PREV


@dataclass(frozen=True)
class PollIn:
    payload: bytes
    count: int
    chain: bytes  # the poll's chain value: the reply's PREV
    matched: bytes  # the kept chain value it was made on
    on_sync: bool  # matched a SYNC whose reference is not set yet
    info: object = None  # what the caller kept with that value (`seal_reply`, `seal_sync`)


@dataclass
class RovCounters:
    hellos: int = 0
    syncs: int = 0
    polls_taken: int = 0
    inauthentic: int = 0  # no kept chain value (or no key) makes its tag
    replayed_hellos: int = 0
    stale_count: int = 0  # authentic, but its COUNT is not ahead of the last taken
    expired: int = 0  # authentic on a chain value older than the failsafe time
    bad_hellos: int = 0  # authentic HELLOs with an ORDER other than NONE: a protocol error, no answer


class RovChain:
    def __init__(self, key: bytes, *, failsafe_s: float = FAILSAFE_S, boot: bytes | None = None,
                 random_bytes: Callable[[int], bytes] = os.urandom) -> None:
        self.key = _check_key(key)
        self.failsafe_s = failsafe_s
        self._random = random_bytes
        self.boot = boot if boot is not None else random_bytes(BOOT_BYTES)
        if len(self.boot) != BOOT_BYTES:
            raise ValueError("BOOT is 4 bytes")
        # (chain value, time sent); oldest first.
        self._replies: collections.deque = collections.deque(maxlen=ROV_KEEP_REPLIES)
        self._syncs: collections.deque = collections.deque(maxlen=ROV_KEEP_SYNCS)
        self._sync_unreferenced: set[bytes] = set()
        self._last_count: int | None = None
        self._challenges: collections.deque = collections.deque()
        self._challenge_set: set[bytes] = set()
        self._info: dict[bytes, object] = {}  # what the caller keeps with each kept chain value
        self._taken_at: float | None = None  # when the last poll was taken
        self.counters = RovCounters()

    def _expire(self, now: float) -> None:
        """§8.1: a kept value is matched while it is at most twice the failsafe time
        old and the chain is alive: it was made, or a poll was taken, within the
        failsafe time.  A ROV whose failsafe engaged answers nothing but HELLOs."""
        alive_since = now - self.failsafe_s
        chain_alive = self._taken_at is not None and self._taken_at >= alive_since
        for kept in (self._replies, self._syncs):
            while kept and (now - kept[0][1] > KEEP_FAILSAFES * self.failsafe_s
                            or (not chain_alive and kept[0][1] < alive_since)):
                value, _ = kept.popleft()
                self._sync_unreferenced.discard(value)
                self._info.pop(value, None)

    def is_authentic(self, contents: bytes) -> bool:
        """Whether a HELLO or a poll carries a tag this end accepts (no state moves:
        the framing asks this; `check_poll` decides what to do with the frame)."""
        if len(contents) <= TAG_BYTES:
            return False
        signed, tag = contents[:-TAG_BYTES], contents[-TAG_BYTES:]
        if contents[0] & HELLO_BIT and _tag_matches(self.key, KIND_HELLO, b"", signed, tag):
            return True
        return any(_tag_matches(self.key, KIND_POLL, prev, signed, tag)
                   for prev, _ in (*self._replies, *self._syncs))

    def check_poll(self, contents: bytes, now: float) -> HelloIn | PollIn | None:
        """Whether the frame contents (payload, extra, TAG) are an authentic
        HELLO to answer or an authentic poll to take (after it parses)."""
        if len(contents) < 1 + COUNT_BYTES + TAG_BYTES:
            self.counters.inauthentic += 1
            return None
        signed, tag = contents[:-TAG_BYTES], contents[-TAG_BYTES:]
        if contents[0] & HELLO_BIT and len(signed) == HELLO_PAYLOAD + CHALLENGE_BYTES:
            value = _tag_matches(self.key, KIND_HELLO, b"", signed, tag)
            if value is not None and signed[0] & ORDER_BITS:
                self.counters.bad_hellos += 1  # §8: a HELLO carries no order
                return None
            if value is not None:
                challenge = signed[HELLO_PAYLOAD:]
                if challenge in self._challenge_set:
                    self.counters.replayed_hellos += 1
                    return None
                self._challenges.append(challenge)
                self._challenge_set.add(challenge)
                if len(self._challenges) > ROV_CHALLENGES_SEEN:
                    self._challenge_set.discard(self._challenges.popleft())
                self.counters.hellos += 1
                return HelloIn(signed[:HELLO_PAYLOAD], challenge, value)
        self._expire(now)
        if len(signed) < 1 + COUNT_BYTES:
            self.counters.inauthentic += 1
            return None
        payload, count = signed[:-COUNT_BYTES], signed[-1]
        for kept, kept_syncs in ((self._replies, False), (self._syncs, True)):
            for prev, _ in reversed(kept):
                value = _tag_matches(self.key, KIND_POLL, prev, signed, tag)
                if value is None:
                    continue
                on_sync = kept_syncs and prev in self._sync_unreferenced
                if not on_sync:
                    ahead = (count - self._last_count) % 256 if self._last_count is not None else 0
                    if not 1 <= ahead <= COUNT_WINDOW:
                        self.counters.stale_count += 1
                        return None
                return PollIn(payload, count, value, prev, on_sync, self._info.get(prev))
        self.counters.inauthentic += 1
        return None

    def take(self, poll: PollIn, now: float) -> None:
        """The poll parsed and is acted on: it sets the COUNT reference, and the
        kept values older than the one it matched are forgotten."""
        self._last_count = poll.count
        self._taken_at = now
        self._sync_unreferenced.discard(poll.matched)
        for kept in (self._replies, self._syncs):
            times = [t for v, t in kept if v == poll.matched]
            if times:
                cut = times[0]
                break
        else:
            cut = now
        for kept in (self._replies, self._syncs):
            keep = [(v, t) for v, t in kept if t >= cut]
            kept.clear()
            kept.extend(keep)
        self._sync_unreferenced &= {v for v, _ in self._syncs}
        alive = {v for v, _ in (*self._replies, *self._syncs)}
        self._info = {v: i for v, i in self._info.items() if v in alive}
        self.counters.polls_taken += 1

    def _keep(self, kept: collections.deque, value: bytes, now: float, info: object) -> None:
        if len(kept) == kept.maxlen:
            self._info.pop(kept[0][0], None)
        kept.append((value, now))
        if info is not None:
            self._info[value] = info

    def seal_reply(self, payload: bytes, poll: PollIn, now: float, *, info: object = None) -> bytes:
        """The reply frame to `poll`; `info` is handed back with the next poll made on it."""
        value = mac(self.key, KIND_REPLY, poll.chain, payload)
        self._keep(self._replies, value, now, info)
        return encode_frame2(payload + value[:TAG_BYTES])

    def seal_sync(self, payload: bytes, hello: HelloIn, now: float, *, info: object = None) -> bytes:
        if len(payload) != SYNC_PAYLOAD or not is_sync(payload):
            raise ValueError("a SYNC reply is a 14-byte reply payload with SYNC set")
        signed = payload + self.boot + self._random(NONCE_BYTES - BOOT_BYTES)
        value = mac(self.key, KIND_SYNC, hello.chain, signed)
        if len(self._syncs) == self._syncs.maxlen:
            self._sync_unreferenced.discard(self._syncs[0][0])
        self._keep(self._syncs, value, now, info)
        self._sync_unreferenced.add(value)
        self.counters.syncs += 1
        return encode_frame2(signed + value[:TAG_BYTES])


# ---------------------------------------------------------------------------
# The operator's end
# ---------------------------------------------------------------------------


@dataclass(frozen=True)
class ReplyIn:
    payload: bytes  # the reply payload (14 bytes for a SYNC), without NONCE or TAG
    sync: bool
    boot: bytes | None  # a SYNC's BOOT
    answers: int  # the number of the poll or HELLO it answers (OperatorChain.sent order)
    sent_at: float
    late: bool
    parsed: object = None  # what `open_reply`'s `parse` made of a timely one
    malformed: bool = False  # timely and authentic, but `parse` refused it: not chained to


@dataclass
class OperatorCounters:
    hellos: int = 0
    polls: int = 0
    replies: int = 0
    syncs: int = 0
    late: int = 0
    inauthentic: int = 0
    malformed: int = 0


@dataclass
class _Sent:
    number: int
    value: bytes
    sent_at: float
    deadline: float  # its answer is late after this (the master's timeout for it)
    answered: bool = False


class OperatorChain:
    def __init__(self, key: bytes, *, random_bytes: Callable[[int], bytes] = os.urandom,
                 count: int | None = None) -> None:
        self.key = _check_key(key)
        self._random = random_bytes
        self._hellos: collections.deque = collections.deque(maxlen=OPERATOR_KEEP_HELLOS)
        self._polls: collections.deque = collections.deque(maxlen=OPERATOR_KEEP_POLLS)
        self._number = 0  # frames sealed: the last one sent is number _number - 1
        self.chain_to: bytes | None = None  # the chain value the next poll is made on
        self.count = random_bytes(1)[0] if count is None else count % 256
        self.boot: bytes | None = None  # the ROV's, from the last SYNC taken
        self.last_authentic_at: float | None = None
        self.counters = OperatorCounters()

    @property
    def synced(self) -> bool:
        return self.chain_to is not None

    @property
    def next_number(self) -> int:
        """The number the next HELLO or poll sealed gets (`ReplyIn.answers`)."""
        return self._number

    def seal_hello(self, payload: bytes, now: float, *, deadline: float = math.inf,
                   challenge: bytes | None = None) -> bytes:
        """A HELLO frame; its SYNC is late after `deadline`."""
        if len(payload) != HELLO_PAYLOAD or not payload[0] & HELLO_BIT or payload[0] & ORDER_BITS:
            raise ValueError("a HELLO is a 3-byte poll payload with HELLO set and ORDER NONE")
        challenge = self._random(CHALLENGE_BYTES) if challenge is None else challenge
        signed = payload + challenge
        value = mac(self.key, KIND_HELLO, b"", signed)
        self._hellos.append(_Sent(self._number, value, now, deadline))
        self._number += 1
        self.counters.hellos += 1
        return encode_frame2(signed + value[:TAG_BYTES])

    def seal_poll(self, payload: bytes, now: float, *, deadline: float = math.inf) -> bytes:
        """A poll frame chained to the last timely answer; its reply is late after `deadline`."""
        if self.chain_to is None:
            raise RuntimeError("no chain yet: send a HELLO and wait for its SYNC")
        signed = payload + bytes((self.count,))
        self.count = (self.count + 1) % 256
        value = mac(self.key, KIND_POLL, self.chain_to, signed)
        self._polls.append(_Sent(self._number, value, now, deadline))
        self._number += 1
        self.counters.polls += 1
        return encode_frame2(signed + value[:TAG_BYTES])

    def is_authentic(self, contents: bytes) -> bool:
        """Whether a reply or SYNC carries a tag this end accepts (no state moves)."""
        if len(contents) <= TAG_BYTES:
            return False
        signed, tag = contents[:-TAG_BYTES], contents[-TAG_BYTES:]
        return (any(_tag_matches(self.key, KIND_REPLY, s.value, signed, tag) for s in self._polls)
                or any(_tag_matches(self.key, KIND_SYNC, s.value, signed, tag) for s in self._hellos))

    def open_reply(self, contents: bytes, now: float,
                   parse: Callable[[bytes, bool, int], object] | None = None) -> ReplyIn | None:
        """An authentic reply or SYNC (possibly `late`: count it, never use it),
        or None for an inauthentic one (counted).  Timely: it answers the last
        poll or HELLO sent, for the first time, by that frame's deadline.
        `parse(payload, sync, answers)` reads a timely one before it is chained
        to; a ProtocolError from it leaves the chain where it was (`malformed`)."""
        if len(contents) > TAG_BYTES:
            signed, tag = contents[:-TAG_BYTES], contents[-TAG_BYTES:]
            # A reply may be as long as a SYNC and have its bit 0 set (DELTA,
            # §8.1): only the tag's KIND tells them apart.
            if len(signed) == SYNC_PAYLOAD + NONCE_BYTES and is_sync(signed):
                for sent in reversed(self._hellos):
                    value = _tag_matches(self.key, KIND_SYNC, sent.value, signed, tag)
                    if value is not None:
                        return self._answered(sent, value, signed[:SYNC_PAYLOAD], True,
                                              signed[SYNC_PAYLOAD:SYNC_PAYLOAD + BOOT_BYTES], now, parse)
            for sent in reversed(self._polls):
                value = _tag_matches(self.key, KIND_REPLY, sent.value, signed, tag)
                if value is not None:
                    return self._answered(sent, value, signed, False, None, now, parse)
        self.counters.inauthentic += 1
        return None

    def _answered(self, sent: _Sent, value: bytes, payload: bytes, sync: bool, boot: bytes | None,
                  now: float, parse: Callable[[bytes, bool, int], object] | None) -> ReplyIn:
        self.last_authentic_at = now
        late = sent.answered or sent.number != self._number - 1 or now > sent.deadline
        parsed = None
        if not late and parse is not None:
            try:
                parsed = parse(payload, sync, sent.number)
            except ProtocolError:
                self.counters.malformed += 1
                return ReplyIn(payload, sync, boot, sent.number, sent.sent_at, False, None, True)
        if late:
            self.counters.late += 1
        else:
            sent.answered = True
            self.chain_to = value
            if sync:
                self.boot = boot
                self.counters.syncs += 1
            else:
                self.counters.replies += 1
        return ReplyIn(payload, sync, boot, sent.number, sent.sent_at, late, parsed)


# ---------------------------------------------------------------------------
# Framing with early delivery of authentic frames (§1, version 2)
# ---------------------------------------------------------------------------


@dataclass
class AuthDecoderCounters:
    frames: int = 0
    rejected: int = 0  # candidates dropped: LEN out of bounds, or not authentic
    inauthentic: int = 0  # of those: complete, but the tag did not hold (noise, forged, replayed, stale)
    bytes_skipped: int = 0


class AuthFrameDecoder:
    """§1 framing for version 2 (§8.1: no CRC; the tag is the check).
    `authentic(contents)` says whether a frame's contents (the LEN bytes
    after LEN) carry a tag the receiver accepts; a complete candidate whose
    tag does not is dropped like a CRC failure in version 1.1: only its 0x55.
    `max_len`: the largest LEN this receiver expects (a callable, since the
    operator's depends on its last poll)."""

    def __init__(self, authentic: Callable[[bytes], bool],
                 max_len: Callable[[], int] | int = V2_MAX_CONTENTS) -> None:
        self._authentic = authentic
        self._max_len = max_len if callable(max_len) else (lambda: max_len)
        self._buf = bytearray()
        self._delivered_starts: set[int] = set()  # buffer positions of early frames' starts
        self.counters = AuthDecoderCounters()

    @property
    def crc_errors(self) -> int:
        """Start bytes dropped for a LEN out of bounds (a frame that fails its tag is `inauthentic`)."""
        return self.counters.rejected - self.counters.inauthentic

    def _valid_at(self, i: int, end_limit: int, count: bool = False) -> bytes | None:
        """The contents of a complete, authentic frame starting at i, if any.
        `count`: count a complete frame whose tag fails as inauthentic."""
        buf = self._buf
        if i + 1 >= len(buf):
            return None
        n = buf[i + 1]
        if not 1 <= n <= self._max_len():
            return None
        end = i + V2_OVERHEAD + n
        if end > end_limit:
            return None
        contents = bytes(buf[i + V2_OVERHEAD:end])
        if self._authentic(contents):
            return contents
        if count:
            self.counters.inauthentic += 1
        return None

    def feed(self, data: bytes) -> list[bytes]:
        """Bytes in, the contents of every frame now complete out."""
        self._buf += data
        out: list[bytes] = []
        buf = self._buf
        while True:
            start = buf.find(START)
            if start < 0:
                self.counters.bytes_skipped += len(buf)
                buf.clear()
                self._delivered_starts.clear()
                break
            if start:
                self.counters.bytes_skipped += start
                del buf[:start]
                self._delivered_starts = {p - start for p in self._delivered_starts if p >= start}
            if len(buf) < 2:
                break
            n = buf[0 + 1]
            if not 1 <= n <= self._max_len():
                self.counters.rejected += 1
                self._drop_first()
                continue
            end = V2_OVERHEAD + n
            if len(buf) >= end:
                contents = self._valid_at(0, len(buf), count=0 not in self._delivered_starts)
                if contents is not None:
                    if 0 not in self._delivered_starts:
                        out.append(contents)
                        self.counters.frames += 1
                    self._delivered_starts = {p - end for p in self._delivered_starts if p >= end}
                    del buf[:end]
                else:
                    self.counters.rejected += 1
                    self._drop_first()
                continue
            # The first candidate is incomplete: deliver a complete authentic
            # frame further on at once, once; the candidate stays.
            j = buf.find(START, 1)
            while j >= 0:
                if j not in self._delivered_starts:
                    contents = self._valid_at(j, len(buf))
                    if contents is not None:
                        out.append(contents)
                        self.counters.frames += 1
                        self._delivered_starts.add(j)
                j = buf.find(START, j + 1)
            break
        return out

    def _drop_first(self) -> None:
        del self._buf[:1]
        self._delivered_starts = {p - 1 for p in self._delivered_starts if p >= 1}
