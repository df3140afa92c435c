"""The parts of the operator's session, one job each.

`rovlink.console.session.radio.Operator` is the session: it drives the link master
and hands what happens to these parts, and it is the one place commands enter.

- `recorder`: the JSON-lines recording of a session (frames, orders, wishes, poses).
- `odometry`: the last reply the ROV sent, when it was sampled, speeds from successive poses.
- `predictor`: the ghost: the last odometry flown forward under the wishes as they
  were sent; the path a position order would take.
- `images`: the picture being received, its decode thread, its capture window and
  the pictures to look back at.
- `fates`: an order's fate typed once (`Fate`), and its words made in one place.
- `orders`: every order's fate (queued, sent, waiting, acknowledged, followed, rejected with its reason).
- `health`: the link's condition from replies (up, degraded, lost), its counters
  and the alerts raised when it changes.

Each part is handed what it needs (the session's lock, clock, recorder and
publish/note callables); none imports the Operator.
"""
