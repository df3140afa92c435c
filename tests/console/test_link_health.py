"""The link's degraded state (console/session/health.py): it says which figure crossed
which threshold, and it does not flap -- it enters and leaves on different thresholds and
stays at least DEGRADED_HOLD_S once entered.

The link is driven here as the operator drives LinkHealth: a poll, then its reply or
its loss, every `period_s`, and the driver's `watch` after each."""

from __future__ import annotations

from rovlink.console.session.health import BAD_FRAMES, DEGRADED_HOLD_S, DEGRADED_WINDOW_S, LOST_SHARE, LinkHealth
from rovlink.console.session.odometry import History


class Link:
    def __init__(self) -> None:
        self.notes: list[tuple[str, str]] = []
        self.health = LinkHealth(history=History(), note=lambda text, level="info", **_: self.notes.append((text, level)),
                                 clear=lambda cause: None)
        self.t = 0.0
        self.states: list[str] = []

    def run(self, seconds: float, *, lost_every: int = 0, period_s: float = 0.2, crc_every: int = 0) -> None:
        """Polls for `seconds`: every `lost_every`-th without a reply, a CRC error every `crc_every`-th."""
        for i in range(round(seconds / period_s)):
            self.t += period_s
            self.health.event(self.t, "tx", 10)
            if lost_every and i % lost_every == lost_every - 1:
                self.health.event(self.t, "lost")
            else:
                self.health.reply(self.t, 0.1)
            if crc_every and i % crc_every == crc_every - 1:
                self.health.crc_errors(self.health._crc_seen + 1, self.t)
            self.health.watch(self.t)
            state = self.health.condition(self.t)[0]
            if not self.states or self.states[-1] != state:
                self.states.append(state)

    @property
    def state(self) -> str:
        return self.health.condition(self.t)[0]


def test_a_reply_lost_now_and_then_is_a_working_link_not_a_flapping_one():
    link = Link()
    link.run(180, lost_every=15)  # one reply in 15 lost (7 %), one every 3 s, for three minutes
    assert link.states == ["up"], link.states
    assert not [n for n in link.notes if "degraded" in n[0]], link.notes


def test_degraded_says_which_figure_crossed_which_threshold_and_does_not_flap():
    link = Link()
    link.run(20)
    link.run(20, lost_every=4)  # 25 % lost
    assert link.state == "degraded"
    state, f = link.health.state(link.t, 3.0), link.health.figures(link.t)
    assert 0.24 <= f["lost_share"] <= 0.27 and f["polls"] >= 45, f
    assert state["degraded_short"] == f"{f['lost_share']:.0%} lost", state
    assert state["degraded_reason"].startswith(f"{f['lost']} of {f['polls']} replies lost in the last "
                                               f"{DEGRADED_WINDOW_S:g} s ({f['lost_share']:.0%};"), state
    assert f"degraded from {LOST_SHARE.enter:.0%}" in state["degraded_reason"]
    said = [text for text, level in link.notes if text.startswith("link degraded: ")]
    assert len(said) == 1 and "replies lost" in said[0] and level_of(link, said[0]) == "warn", link.notes
    # Between the two thresholds (7 % lost): still degraded, not up and down with each loss.
    link.run(60, lost_every=15)
    assert link.state == "degraded" and link.states == ["up", "degraded"], link.states
    assert link.health.state(link.t, 3.0)["degraded_short"] in ("6% lost", "7% lost", "8% lost")
    # Clean again: up once the window has no loss left in it, and said.
    link.run(DEGRADED_WINDOW_S + 1)
    assert link.state == "up" and link.states == ["up", "degraded", "up"], link.states
    assert link.health.state(link.t, 3.0)["degraded_reason"] is None
    assert any(text.startswith("link no longer degraded") for text, _ in link.notes), link.notes


def test_once_degraded_it_stays_at_least_its_hold_time():
    link = Link()
    link.run(20)
    link.run(4, lost_every=2)  # a short burst, 50 % lost: a fifth of the window's polls
    assert link.state == "degraded"
    entered = link.t
    link.run(DEGRADED_HOLD_S - 1)
    assert link.state == "degraded", "left within the hold time"
    link.run(DEGRADED_WINDOW_S + 1)
    assert link.state == "up" and link.t - entered >= DEGRADED_HOLD_S


def test_bad_frames_degrade_it_and_say_so():
    link = Link()
    link.run(20)
    link.run(BAD_FRAMES.enter * 2, crc_every=10)  # one CRC error every 2 s: 3 in 6 s
    assert link.state == "degraded"
    assert link.health.state(link.t, 3.0)["degraded_reason"].startswith(
        f"{BAD_FRAMES.enter} bad frames in the last {DEGRADED_WINDOW_S:g} s (degraded from {BAD_FRAMES.enter}")


def level_of(link: Link, text: str) -> str:
    return next(level for t, level in link.notes if t == text)
