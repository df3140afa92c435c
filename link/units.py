"""SI to the wire's units and back, for the operator's side: the one place the
console's metres, degrees and stick fractions become centimetres, decimetres,
centidegrees and VELOCITY's -127..127 (and back, for a recording's wishes).
The ROV's side has its mirror in `link.slave.status_from_pose`; what the ROV
says of itself comes back in SI through `link.report`.

Out-of-range values raise `ProtocolError` (a ValueError) with the field named.
"""

from __future__ import annotations

from .radio.messages import VELOCITY_FULL, Position, ProtocolError, Velocity

WISH_AXES = ("vx", "vy", "vz", "vyaw")
ACOUSTIC_XYZ_M = 3276.7  # an acoustic GOTO's int16 decimetres (§9.3)


def wrap_deg(a: float) -> float:
    return (a + 180.0) % 360.0 - 180.0


def velocity_ints(fractions: tuple[float, float, float, float]) -> tuple[int, int, int, int]:
    """A wish in fractions -1..1 of the maximum as VELOCITY's integers (§2)."""
    for name, v in zip(WISH_AXES, fractions):
        if not -1.0 <= v <= 1.0:
            raise ProtocolError(f"{name} must be a number in -1..1, got {v!r}")
    return tuple(int(round(v * VELOCITY_FULL)) for v in fractions)  # type: ignore[return-value]


def wish_fractions(ints) -> tuple[float, float, float, float]:
    """VELOCITY's integers (a poll's, or a recording's "wish") as fractions of the maximum."""
    return tuple(v / VELOCITY_FULL for v in ints)  # type: ignore[return-value]


def wish_of(order: Velocity) -> tuple[float, float, float, float]:
    return wish_fractions((order.vx, order.vy, order.vz, order.vyaw))


def position_order(x_m: float, y_m: float, z_m: float, yaw_deg: float, *, relative: bool, body: bool) -> Position:
    """A POSITION order (§2: centimetres and centidegrees), yaw wrapped to -180..180."""
    return Position(int(round(x_m * 100)), int(round(y_m * 100)), int(round(z_m * 100)),
                    int(round(wrap_deg(yaw_deg) * 100)), bool(relative), bool(body))


def acoustic_goto(x_m: float, y_m: float, z_m: float, yaw_deg: float | None, *, relative: bool, body: bool):
    """An acoustic GOTO (§9.3: decimetres and centidegrees; no yaw when None)."""
    from .acoustic import GoToBody

    for name, v in (("x_m", x_m), ("y_m", y_m), ("z_m", z_m)):
        if not abs(v) <= ACOUSTIC_XYZ_M:
            raise ProtocolError(f"{name} must be within ±{ACOUSTIC_XYZ_M} m on the acoustic link, got {v!r}")
    yaw = 0 if yaw_deg is None else int(round(wrap_deg(yaw_deg) * 100))
    goto = GoToBody(0, int(round(x_m * 10)), int(round(y_m * 10)), int(round(z_m * 10)), yaw, bool(relative), bool(body),
                yaw_deg is not None)
    bad = goto.invalid()
    if bad:
        raise ProtocolError(f"go-to: {bad}")
    return goto
