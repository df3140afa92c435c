"""What the browser tests do on an operator page, written once."""

from __future__ import annotations


def wish(live) -> dict:
    """The velocity wish the console holds now."""
    return live.operator.state()["velocity_wish"]


def take_control(page) -> None:
    page.click("#take")
    page.wait_for_function("document.getElementById('control-text').textContent === 'You have control.'")


def drag_roi(page, selector: str, start: tuple[float, float], end: tuple[float, float]) -> None:
    """A rectangle dragged with the mouse on the picture `selector`, from `start` to `end`
    given as fractions of its width and height."""
    box = page.locator(selector).bounding_box()
    page.mouse.move(box["x"] + box["width"] * start[0], box["y"] + box["height"] * start[1])
    page.mouse.down()
    page.mouse.move(box["x"] + box["width"] * end[0], box["y"] + box["height"] * end[1], steps=5)
    page.mouse.up()


def telemetry_seen(page) -> int:
    return int(page.evaluate("+document.body.dataset.telemetry || 0"))


def after_updates(page, n: int = 3, timeout_ms: float = 30000) -> None:
    """Until the page has rendered `n` more telemetry messages (each ~0.1 s apart):
    long enough for anything the page would send on its own to have gone out,
    measured in what the page did rather than in time, so a loaded machine only
    makes it slower."""
    seen = telemetry_seen(page)
    page.wait_for_function(f"(+document.body.dataset.telemetry || 0) >= {seen + n}", timeout=timeout_ms)


def after_ticks(page, n: int = 3, timeout_ms: float = 30000) -> None:
    """Until the page's input loop (its 100 ms tick: gamepad buttons read, wish sent) has
    turned `n` more times: long enough for a held button or stick to have acted, counted in
    the page's own turns, so a loaded machine only makes it slower."""
    seen = int(page.evaluate("+document.body.dataset.ticks || 0"))
    page.wait_for_function(f"(+document.body.dataset.ticks || 0) >= {seen + n}", timeout=timeout_ms)
