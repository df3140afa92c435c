"""docs/PROTOCOL.md is the contract: every test vector it prints is one the tests
check byte for byte, and every vector the tests check is printed there.  A change
of the wire that forgets the page (or a row of the page no test reads) fails here."""

from __future__ import annotations

import re
from pathlib import Path

from rovlink.link.radio.auth import OperatorChain
from rovlink.link.radio.frame import FrameDecoder
from rovlink.link.radio.messages import Mode, Reply
from rovlink.link.radio.secure import SecureSlave, parse_reply
from rovlink.link.radio.slave import Slave

from . import test_auth, test_vectors

DOC = Path(__file__).resolve().parents[2] / "docs" / "PROTOCOL.md"
OUT_OF_RANGE_REPLY = "55 0e 3c 00 78 00 00 00 00 00 00 00 00 69 78 f0 06 16"
HELLO_WITH_ORDER = "55 0f 44 1f ff 01 02 03 04 05 06 07 08 eb 64 74 d6"
# §1, §8.1 (decided): authentic replies to the last vector poll with a structural fault.
LAST_WITHOUT_TRUNK = "55 0c 51 b1 00 00 00 00 00 00 c4 d3 98 32"
LONG_ZERO_DIFFERENCE = "55 0f 51 b1 80 00 00 00 00 00 00 64 65 0e 70 26 6e"


def _section(title_start: str) -> str:
    text = DOC.read_text(encoding="utf-8")
    start = text.index(f"\n## {title_start}")
    end = text.find("\n## ", start + 1)
    return text[start:] if end < 0 else text[start:end]


def _rows(section: str) -> list[list[str]]:
    """Table rows whose second cell is a backticked frame (`55 ...`): the cells' texts."""
    rows = []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) >= 2 and re.fullmatch(r"`55( [0-9a-f]{2})+`", cells[1]):
            rows.append([c.strip("`") for c in cells])
    return rows


def test_the_contract_is_in_the_repository_and_names_itself():
    text = DOC.read_text(encoding="utf-8")
    assert "docs/PROTOCOL.md" in text and "../shared" not in text


def test_section_6_prints_exactly_the_vectors_the_tests_check():
    printed = {row[1] for row in _rows(_section("6."))}
    tested = {wire for _, wire in test_vectors.VECTORS} | {OUT_OF_RANGE_REPLY}
    assert printed == tested


def test_section_8_prints_exactly_the_vectors_and_chain_values_the_tests_check():
    rows = _rows(_section("8."))
    printed = [row[1] for row in rows]
    assert printed == test_auth.FRAMES + [HELLO_WITH_ORDER, LAST_WITHOUT_TRUNK, LONG_ZERO_DIFFERENCE]
    chains = [row[2] for row in rows if row[2] != "—"]
    assert chains == test_auth.CHAINS
    for row in rows:  # each chain value starts with its frame's TAG (its last 4 bytes: no CRC, §8.1)
        if row[2] != "—":
            assert bytes.fromhex(row[1])[-4:] == bytes.fromhex(row[2])[:4]


def test_an_angle_out_of_range_reads_as_attitude_unknown_and_the_rest_as_sent():
    (payload,) = FrameDecoder().feed(bytes.fromhex(OUT_OF_RANGE_REPLY))
    assert Reply.decode(payload) == Reply(ack=1, armed=True, hold=True, mode=Mode.POS_HOLD, x_cm=120,
                                          autopilot=True, failsafe=True, position_valid=True,
                                          attitude_valid=False)


def test_a_hello_carrying_an_order_gets_no_sync_and_is_counted():
    rov = SecureSlave(Slave(), test_auth.K)
    out = rov.receive_bytes(bytes.fromhex(HELLO_WITH_ORDER), 0.0)
    assert out.reply is None
    assert rov.chain.counters.bad_hellos == 1 and rov.slave.stats.protocol_errors == 1
    # The same challenge in a proper HELLO is still answered: it was not remembered.
    out = rov.receive_bytes(bytes.fromhex(test_auth.HELLO), 0.1)
    assert out.reply is not None and rov.chain.counters.syncs == 1


def test_a_reply_with_a_structural_fault_is_authentic_counted_and_never_chained_to():
    # The operator's chain through §8's vectors up to the last poll, from their bytes.
    def contents(vector):
        return bytes.fromhex(vector)[2:]

    op = OperatorChain(test_auth.K, count=0)
    op.seal_hello(bytes.fromhex("40 1f ff"), 0.0, challenge=bytes.fromhex("01 02 03 04 05 06 07 08"))
    assert not op.open_reply(contents(test_auth.SYNC), 0.0).late
    for poll, reply in ((test_auth.POLL, test_auth.REPLY), (test_auth.POLL2, test_auth.REPLY2)):
        op.seal_poll(contents(poll)[:-5], 0.0)  # without COUNT and TAG
        assert not op.open_reply(contents(reply), 0.0).late
    op.seal_poll(contents(test_auth.POLL3)[:-5], 0.0)
    # Its version 1.1 payload (NONE, IMG 0 OFFSET 5) and the pose of the reply it is chained to.
    poll11, reference = bytes.fromhex("00 00 05"), (10, -3, 2, 5, -7, 120)

    def parse(payload, sync, answers):
        return parse_reply(payload, poll11, reference)

    before = op.chain_to
    for n, vector in enumerate((LAST_WITHOUT_TRUNK, LONG_ZERO_DIFFERENCE), 1):
        got = op.open_reply(contents(vector), 0.0, parse)
        assert got is not None and got.malformed and not got.late  # authentic, a fault
        assert op.chain_to == before and op.counters.malformed == n
    # The reply of the vectors (LAST with its trunk, the pose whole) is then taken and chained to.
    got = op.open_reply(contents(test_auth.REPLY3), 0.0, parse)
    assert not got.malformed and op.chain_to.hex() == test_auth.CHAINS[7]
    assert got.parsed[2] == (1250, -300, 450, 150, -220, 9000)


def test_the_size_classes_caps_are_the_ones_the_page_prints():
    """§8.1: SIZE 0, 1 and 2 cap a cycle (poll frame plus reply frame); issue 40 made
    SIZE 0 72 bytes.  The page's figures are the code's."""
    from rovlink.link.radio.wire2 import V2_CYCLE

    found = re.search(r"are at most (\d+), (\d+) and (\d+) bytes for SIZE 0, 1 and 2", _section("8."))
    assert found is not None
    assert tuple(int(g) for g in found.groups()) == V2_CYCLE[:3] == (72, 110, 180)
