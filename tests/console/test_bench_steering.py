"""`rovlink bench console`'s steering rows (console/bench/steering.py, issue 40): every
byte of a cycle is put down to one thing, and the floor's arithmetic holds together."""

from rovlink.console.bench.steering import WISH_LIMIT_S, cycle_bytes, measure_steering, steering_floor
from rovlink.link.radio.wire2 import V2_CYCLE


def test_the_floor_is_the_longest_cycle_the_wish_limit_allows():
    longest = steering_floor(wish_poll_share=0.5)
    one_more = steering_floor(wish_poll_share=0.5, cycle_cap=longest["cycle_bytes"] + 1)
    assert longest["wish_p95_s"] <= WISH_LIMIT_S < one_more["wish_p95_s"]
    # A longer cycle carries more picture, so the floor is at the longest one.
    today = steering_floor(wish_poll_share=0.5, cycle_cap=V2_CYCLE[0])
    assert longest["picture_s"] <= today["picture_s"]
    # Every byte of the pose costs picture: a larger pose, a later picture.
    assert steering_floor(wish_poll_share=0.5, pose_bytes=9)["picture_s"] > longest["picture_s"]
    # Each cycle's trunk is what is left of it.
    assert longest["trunk_bytes"] == (longest["cycle_bytes"] - longest["poll_bytes"]
                                      - longest["reply_overhead_bytes"])
    assert longest["cycles"] * longest["trunk_bytes"] >= 2000 > (longest["cycles"] - 1) * longest["trunk_bytes"]


def test_a_short_session_puts_every_byte_down_to_what_it_carries():
    result = measure_steering(120.0, seed=3)
    spent = result["bytes_per_cycle"]
    assert result["steering_picture_s"] is not None and result["wish_p95_s"] is not None
    assert spent["polls"] > 100 and spent["replies"] > 100
    # A steering cycle fills SIZE 0's cap (a picture's end and the few lost frames aside).
    assert V2_CYCLE[0] - 3 <= spent["cycle"] <= V2_CYCLE[0]
    assert spent["poll"]["tag"] == spent["reply"]["tag"] == 4
    assert 6 <= spent["reply"]["pose"] <= 12
    assert 0 < spent["wish_poll_share"] < 1


def test_frames_are_split_by_their_own_bytes():
    # §8.1's vectors: a VELOCITY poll without ARM/MODE, and a reply with a pose of seven
    # bytes of differences and a 5-byte trunk.
    poll = bytes.fromhex("550a013200ec0a018fe21f06")
    reply = bytes.fromhex("551291b11405040a0df0010005616263258c2e02")
    spent = cycle_bytes([poll], [reply])
    assert spent["poll"] == {"framing": 2, "byte_0": 1, "request_and_order": 4, "count": 1, "tag": 4}
    assert spent["reply"] == {"framing": 2, "byte_0_and_status": 2, "pose": 7, "annex": 0, "trunk": 5, "tag": 4}
    assert (spent["poll_frame"], spent["reply_frame"]) == (len(poll), len(reply))
    assert spent["wish_poll_share"] == 1.0
