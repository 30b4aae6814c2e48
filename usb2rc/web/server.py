"""The web server: the page, `GET /api/status` and `GET /api/events` (server-sent events).

Read-only: there is no route that changes anything. With a token (`--token-file`), every
request must carry it: `?token=...` once (the page then keeps it in a cookie), or an
`Authorization: Bearer ...` header for scripts. Without one the server only listens on a
loopback address (usb2rc.commands.web refuses anything else)."""

from __future__ import annotations

import asyncio
import contextlib
import hmac
import json
import socket
from collections.abc import AsyncIterator, Awaitable, Callable
from importlib import resources
from types import FrameType

import uvicorn
from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.base import BaseHTTPMiddleware
from starlette.requests import Request
from starlette.responses import JSONResponse, PlainTextResponse, Response, StreamingResponse
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from usb2rc.web.feed import StatusFeed

STREAM_MIN_PERIOD_S = 0.05  # the live stream sends at most 20 records a second per page
KEEPALIVE_S = 5.0  # an SSE comment when nothing changed: proxies and phones keep the stream
TOKEN_COOKIE = "usb2rc_token"
STATIC = resources.files("usb2rc.web") / "static"
SECURITY_HEADERS = {
    "Content-Security-Policy": "default-src 'self'; frame-ancestors 'none'",
    "X-Content-Type-Options": "nosniff",
    "Referrer-Policy": "no-referrer",
    "Cache-Control": "no-store",
}


def create_app(feed: StatusFeed, token: str | None = None) -> Starlette:
    """The app; it runs `feed` for as long as it serves."""

    @contextlib.asynccontextmanager
    async def lifespan(_app: Starlette) -> AsyncIterator[None]:
        task = asyncio.create_task(feed.run())
        try:
            yield
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    async def page(_request: Request) -> Response:
        html = (STATIC / "index.html").read_text(encoding="utf-8")
        return Response(html, media_type="text/html; charset=utf-8")

    async def status(_request: Request) -> Response:
        return JSONResponse(feed.record())

    async def events(request: Request) -> Response:
        return StreamingResponse(
            _stream(feed, request),
            media_type="text/event-stream",
            headers={"X-Accel-Buffering": "no"},
        )

    app = Starlette(
        routes=[
            Route("/", page),
            Route("/api/status", status),
            Route("/api/events", events),
            Mount("/static", StaticFiles(directory=str(STATIC)), name="static"),
        ],
        lifespan=lifespan,
        middleware=[Middleware(BaseHTTPMiddleware, dispatch=_guard(token))],
    )
    return app


async def _stream(feed: StatusFeed, request: Request) -> AsyncIterator[str]:
    """The latest record whenever there is a new one, at most every STREAM_MIN_PERIOD_S: a
    slow page skips records (it always gets the latest), it never makes a queue grow."""
    seen = -1
    loop = asyncio.get_running_loop()
    while not await request.is_disconnected():
        started = loop.time()
        version = await feed.wait_newer(seen, KEEPALIVE_S)
        if feed.closing:
            return
        if version == seen:
            yield ": keepalive\n\n"
            continue
        seen = version
        yield "data: " + json.dumps(feed.record(), separators=(",", ":")) + "\n\n"
        await asyncio.sleep(max(0.0, STREAM_MIN_PERIOD_S - (loop.time() - started)))


Handler = Callable[[Request], Awaitable[Response]]


def _guard(token: str | None) -> Callable[[Request, Handler], Awaitable[Response]]:
    """The middleware: the security headers, and the token check when there is one."""

    async def guard(request: Request, call_next: Handler) -> Response:
        given = _token_of(request)
        if token is not None and (given is None or not hmac.compare_digest(given, token)):
            response: Response = PlainTextResponse(
                "usb2rc web: a token is needed: open the page as http://HOST:PORT/?token=... "
                "(the token is in the file given to --token-file)\n",
                status_code=401,
            )
        else:
            response = await call_next(request)
            if token is not None and request.query_params.get("token") is not None:
                response.set_cookie(TOKEN_COOKIE, token, httponly=True, samesite="strict")
        response.headers.update(SECURITY_HEADERS)
        return response

    return guard


def _token_of(request: Request) -> str | None:
    header = request.headers.get("authorization", "")
    if header.lower().startswith("bearer "):
        return header[7:].strip()
    return request.query_params.get("token") or request.cookies.get(TOKEN_COOKIE)


class _Server(uvicorn.Server):
    """uvicorn's server, ending the live streams at SIGTERM/SIGINT: otherwise each open page
    holds the stop until uvicorn's graceful timeout cancels it (with a traceback)."""

    def __init__(self, config: uvicorn.Config, feed: StatusFeed) -> None:
        super().__init__(config)
        self.feed = feed

    def handle_exit(self, sig: int, frame: FrameType | None) -> None:
        self.feed.close()
        super().handle_exit(sig, frame)


def listen(host: str, port: int) -> list[socket.socket]:
    """Listening sockets on every address `host` names, bound as asyncio's create_server
    binds them (SO_REUSEADDR; an IPv6 socket IPv6 only). Bound here, before uvicorn runs,
    so that a taken address is an OSError the command can word (uvicorn logs it, exits 3).
    Raises OSError (socket.gaierror for an unknown host name)."""
    infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    sockets: list[socket.socket] = []
    try:
        for family, kind, proto, _name, address in infos:
            sock = socket.socket(family, kind, proto)
            sockets.append(sock)
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if family == socket.AF_INET6:
                sock.setsockopt(socket.IPPROTO_IPV6, socket.IPV6_V6ONLY, 1)
            sock.bind(address)
            sock.listen(128)
    except OSError:
        for sock in sockets:
            sock.close()
        raise
    return sockets


def serve(feed: StatusFeed, token: str | None, sockets: list[socket.socket]) -> bool:
    """Serve on `sockets` (`listen`) until SIGTERM/SIGINT; False when it could not start."""
    config = uvicorn.Config(
        create_app(feed, token),
        log_level="warning",
        access_log=False,
        timeout_graceful_shutdown=1,  # a stream that did not end by itself
    )
    server = _Server(config, feed)
    server.run(sockets=sockets)
    return bool(server.started)
