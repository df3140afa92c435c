"""Errors as the API answers them: every error body has `detail` (FastAPI's
own) and `message`, one line saying what is wrong.

OrderError (the Operator refusing a value) and UnknownClient are 422, like
any malformed request; NotHolder is 409: the request was fine, the caller
is not the one who may make it.  A POST a browser sends from another site's
page is 403: any page the pilot has open could otherwise take control or
press STOP through the pilot's browser (scripts send no Origin and pass)."""

from __future__ import annotations

from urllib.parse import urlsplit

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException

from rovlink.console.control import NotHolder, UnknownClient
from rovlink.console.session.base import NotNow, OrderError


def describe(errors) -> str:
    """Pydantic's error list as one line: 'body.vx: Input should be ...; ...'."""
    parts = []
    for e in errors:
        where = ".".join(str(p) for p in e.get("loc", ()))
        parts.append(f"{where}: {e.get('msg', 'invalid')}" if where else str(e.get("msg", "invalid")))
    return "; ".join(parts) or "invalid request"


def _error(status: int, detail, message: str, headers=None) -> JSONResponse:
    return JSONResponse({"detail": detail, "message": message}, status_code=status, headers=headers)


def same_origin(headers) -> bool:
    """Whether a request's Origin (if any) is the site it was sent to."""
    origin = headers.get("origin")
    if origin is None:
        return True  # not from a browser page
    return urlsplit(origin).netloc.lower() == (headers.get("host") or "").lower()


def install(app: FastAPI) -> None:
    @app.middleware("http")
    async def refuse_other_sites(request: Request, call_next):
        if request.method not in ("GET", "HEAD", "OPTIONS") and not same_origin(request.headers):
            message = f"cross-site request from {request.headers['origin']} refused"
            return _error(403, message, message)
        return await call_next(request)

    @app.exception_handler(RequestValidationError)
    async def invalid_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = exc.errors()
        detail = [{k: v for k, v in e.items() if k in ("type", "loc", "msg")} for e in errors]
        return _error(422, detail, describe(errors))

    @app.exception_handler(OrderError)
    async def refused_order(request: Request, exc: OrderError) -> JSONResponse:
        # A well-formed order the link cannot carry, or not now, is a conflict, not a bad request.
        return _error(409 if isinstance(exc, NotNow) else 422, str(exc), str(exc))

    @app.exception_handler(UnknownClient)
    async def unknown_client(request: Request, exc: UnknownClient) -> JSONResponse:
        return _error(422, str(exc), str(exc))

    @app.exception_handler(NotHolder)
    async def not_holder(request: Request, exc: NotHolder) -> JSONResponse:
        return _error(409, str(exc), str(exc))

    @app.exception_handler(HTTPException)
    async def http_error(request: Request, exc: HTTPException) -> JSONResponse:
        return _error(exc.status_code, exc.detail, str(exc.detail), getattr(exc, "headers", None))
