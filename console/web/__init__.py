"""The operator's web console (FastAPI): `create_app(operator, viser_url=...)`
and `serve(app, host, port)` in `console.web.app`.

Layout: `app` (factory, lifespan, serve), `deps` (Operator, control desk,
client id, holder guard), `models` (every request and response body),
`telemetry` (shared snapshots), `errors` (422 and 409 bodies), `routers/`
(state, orders, image, link, control, ws) and `static/` (the operator page:
one HTML, one script, one style sheet).  Every route is an adapter over the
command layer, `rovlink.console.control`: it builds a typed order and submits
it with the caller's client id; who may order is decided there.
"""
