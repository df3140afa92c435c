"""The operator's web console (FastAPI): `create_app(operator, viser_url=...)`
and `serve(app, host, port)` in `console.web.app`.

Layout: `app` (factory, lifespan, serve), `deps` (Operator, control desk,
client id, holder guard), `models` (every request and response body),
`control` (who may drive), `telemetry` (shared snapshots), `errors` (422 and
409 bodies), `routers/` (state, orders, image, link, control, ws) and
`static/` (the operator page: one HTML, one script, one style sheet).
"""
