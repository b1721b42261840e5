"""The web application of `station serve` (Starlette, served by uvicorn): the page and its assets,
the live stream of the bench's session (server-sent events), and the requests that drive it.

Every request is untrusted:
- the page and its assets are the files of `station/serve/pages/`, by name, nothing else;
- session files are served from the sessions folder only, by a plain file name (no path);
- a request that changes something is a POST with a JSON body (a page of another origin cannot
  send one without the browser's CORS check), its fields checked by `BenchSession`;
- on the loopback (the default) only the loopback host names are served (a DNS-rebinding page
  reaches nothing); bound elsewhere, every request needs the server's token (the address printed
  at start carries it once; the page keeps it as a cookie).

The live stream sends the session's snapshot every `period` seconds (`BenchSession.snapshot`:
state, question, view, and only the plot points the page has not had).
"""

import asyncio
import hmac
import json
import re
from pathlib import Path

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response, StreamingResponse
from starlette.routing import Route

from drivers.errors import DeviceError
from station.errors import InputError, StationError
from station.files.jsonable import jsonable

PAGES = Path(__file__).with_name("pages")
ASSETS = {"station.js": "text/javascript", "pose.js": "text/javascript",
          "plot.js": "text/javascript", "station.css": "text/css"}
"""The page's assets, by name (served from PAGES, nothing else is)."""
SERVED = {".h5": "application/x-hdf5", ".json": "application/json", ".html": "text/html",
          ".png": "image/png", ".h": "text/plain"}
"""What of the sessions folder is served, by suffix."""
FILE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,127}\Z")
LOOPBACK = ("127.0.0.1", "localhost", "[::1]")
COOKIE = "station_token"


def build(session, lookups, token: str | None = None, period: float = 0.05) -> Starlette:
    """The application around `session` (`BenchSession`). lookups: {"devices": profile name ->
    dict, "history": serial -> dict, "line": () -> dict, "sessions": () -> list}; token: required
    of every request (None: loopback only)."""

    async def page(request: Request) -> Response:
        return FileResponse(PAGES / "index.html", media_type="text/html",
                            headers={"Cache-Control": "no-store"})

    async def asset(request: Request) -> Response:
        name = request.path_params["name"]
        if name not in ASSETS:
            return JSONResponse({"error": f"no asset {name!r}"}, 404)
        return FileResponse(PAGES / name, media_type=ASSETS[name])

    async def state(request: Request) -> Response:
        return _json(session.snapshot(_cursor(request)))

    async def events(request: Request) -> Response:
        async def stream():
            since = _cursor(request)
            server = request.app.state.server
            while not (server is not None and server.should_exit):
                shown = session.snapshot(since)
                view = shown["view"]
                since = view["cursor"] if view else since
                yield f"data: {json.dumps(jsonable(shown))}\n\n"
                await asyncio.sleep(period)
                if await request.is_disconnected():
                    return

        return StreamingResponse(stream(), media_type="text/event-stream",
                                 headers={"Cache-Control": "no-store"})

    async def bench(request: Request) -> Response:
        return _json({"profiles": list(session.profiles), "sessions": lookups["sessions"]()})

    async def devices(request: Request) -> Response:
        return await _answer(lookups["devices"], request.query_params.get("profile", ""))

    async def history(request: Request) -> Response:
        return await _answer(lookups["history"], request.query_params.get("serial", ""))

    async def line(request: Request) -> Response:
        return await _answer(lookups["line"])

    async def act(request: Request) -> Response:
        body = await _body(request)
        action = request.path_params["action"]
        if action == "start":
            return await _answer(session.start, body.get("profile"), body.get("serial"))
        if action == "answer":
            ok = session.answer(body.get("id"), body.get("value"))
            return _json({"ok": ok}, 200 if ok else 409)
        if action == "resume":
            return await _answer(session.resume, body.get("session"))
        if action in ("pause", "abort"):
            return await _answer(getattr(session, action))
        return JSONResponse({"error": f"no action {action!r}"}, 404)

    async def files(request: Request) -> Response:
        name = request.path_params["name"]
        path = session.folder / name
        if not FILE_NAME.match(name) or path.suffix not in SERVED or not path.is_file() \
                or path.resolve().parent != session.folder.resolve():
            return JSONResponse({"error": f"no file {name!r} in the sessions folder"}, 404)
        return FileResponse(path, media_type=SERVED[path.suffix])

    async def icon(request: Request) -> Response:
        return Response(status_code=204)

    routes = [Route("/", page), Route("/favicon.ico", icon), Route("/assets/{name}", asset),
              Route("/api/state", state), Route("/api/events", events), Route("/api/bench", bench),
              Route("/api/devices", devices), Route("/api/history", history),
              Route("/api/line", line), Route("/api/{action}", act, methods=["POST"]),
              Route("/files/{name}", files)]
    middleware = [] if token else [Middleware(TrustedHostMiddleware, allowed_hosts=LOOPBACK)]
    app = Starlette(routes=routes, middleware=middleware)
    app.state.server = None
    if token:
        app.add_middleware(_TokenGate, token=token)
    return app


class _TokenGate:
    """Every request must carry the token: as the cookie the page keeps, or once as `?token=`
    (the address printed at start), which then sets the cookie."""

    def __init__(self, app, token: str):
        self.app, self.token = app, token

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        request = Request(scope)
        given = request.query_params.get("token")
        kept = request.cookies.get(COOKIE)
        if given is not None and hmac.compare_digest(given, self.token):
            async def keep(message):
                if message["type"] == "http.response.start":
                    cookie = f"{COOKIE}={self.token}; Path=/; HttpOnly; SameSite=Strict"
                    message["headers"] = [*message.get("headers", []),
                                          (b"set-cookie", cookie.encode())]
                await send(message)
            return await self.app(scope, receive, keep)
        if kept is not None and hmac.compare_digest(kept, self.token):
            return await self.app(scope, receive, send)
        response = JSONResponse({"error": "this station needs its token: open the address "
                                          "`station serve` printed"}, 401)
        return await response(scope, receive, send)


def _cursor(request: Request) -> int:
    try:
        return max(0, int(request.query_params.get("since", "0")))
    except ValueError:
        return 0


async def _body(request: Request) -> dict:
    """The JSON object of a POST; {} for anything else (its fields are then refused by name)."""
    if request.headers.get("content-type", "").split(";")[0].strip() != "application/json":
        return {}
    try:
        body = await request.json()
    except ValueError:
        return {}
    return body if isinstance(body, dict) else {}


async def _answer(call, *args) -> Response:
    """`call(*args)` in a worker thread: its result as JSON, a station's or device's error as a
    409 with its message (what to do included)."""
    try:
        result = await asyncio.to_thread(call, *args)
    except (StationError, DeviceError) as exc:
        words = " ".join(str(exc).split())
        return _json({"error": "; ".join([words, *getattr(exc, "__notes__", ())])},
                     400 if isinstance(exc, InputError) else 409)
    return _json({"ok": True} if result is None else result)


def _json(value, status: int = 200) -> Response:
    return Response(json.dumps(jsonable(value)), status, media_type="application/json",
                    headers={"Cache-Control": "no-store"})


class Listening:
    """`app` served by uvicorn on a socket bound now (`port` 0: a free one; `port` says which).
    `serve()` serves until Ctrl-C or SIGTERM, `stop()` ends it from another thread; the live
    streams end as it stops."""

    def __init__(self, app: Starlette, host: str, port: int):
        import socket

        import uvicorn

        family = socket.AF_INET6 if ":" in host else socket.AF_INET
        self.socket = socket.socket(family, socket.SOCK_STREAM)
        self.socket.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            self.socket.bind((host, port))
        except OSError as exc:
            self.socket.close()
            raise InputError(f"cannot listen on {host}:{port}: {exc.strerror}; give another "
                             "--port (or --host)") from None
        self.socket.listen(128)  # the address printed answers at once (served when uvicorn runs)
        self.port = self.socket.getsockname()[1]
        config = uvicorn.Config(app, log_level="warning", timeout_graceful_shutdown=2,
                                lifespan="off")
        self.server = app.state.server = uvicorn.Server(config)

    def serve(self) -> None:
        try:
            self.server.run(sockets=[self.socket])
        finally:
            self.socket.close()

    def stop(self) -> None:
        self.server.should_exit = True
