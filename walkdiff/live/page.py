"""`walkdiff play` without --script: a local page that steers a walker with the keyboard and records takes.

Why a page of our own rather than viser's (`walkdiff view`): viser 1.1 hands no keyboard events to Python,
and its three.js client needs WebGL, which a browser without a GPU (headless Chromium, a remote desktop)
runs in software, slowly. The page here is one self-written file, `page.html` beside this module: a
2-D canvas drawn in perspective (a floor grid, the walker's trail, its bones in left/right colours), the
camera following behind the commanded direction, keys and a small panel (style menu, speed slider, record
button). One local server answers on one port: the `websockets` package (already a dependency) serves
the page over plain HTTP and the websocket at /ws. Nothing is fetched from anywhere else, and any browser
draws it at once.

The server runs an asyncio loop; the walker runs on a worker thread of its own, a frame at a time at the
model's frame rate (torch releases the GIL, so the loop keeps serving meanwhile). The page's key events
are queued and applied between frames to the same `KeyControl`, through the same `Replay.update`, as
`walkdiff play --script` applies a script's; every frame goes to every open page as JSON (the joints'
world positions in metres, Y up; the heading; the command followed). R or the record button toggles
recording; each recording stopped is written by `write_takes` (take.bvh, take.glb, take.json, then
take2.*, take3.*, ...) on a writer thread while the walk goes on. Ctrl-C (or `stop()`) writes a recording
in progress before it ends.
"""

from __future__ import annotations

import asyncio
import copy
import errno
import json
import logging
import queue
import socket
import sys
import threading
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from http import HTTPStatus
from importlib import resources
from pathlib import Path

from walkdiff.common.errors import WalkdiffError
from walkdiff.common.files import check_free, output_folder
from walkdiff.common.memory import WALK_BYTES_PER_FRAME, check_frames
from walkdiff.live.keys import KeyControl
from walkdiff.live.play import (
    Replay,
    keys_for,
    load_walker,
    settings,
    take_files,
    write_takes,
)
from walkdiff.preview.scene import limb_sides
from walkdiff.walker.controller import WalkController, checked_speed

DEFAULT_PORT = 8081
# A browser opens spare sockets and may close them without a request; websockets logs each as a failed
# handshake with a traceback. Nothing is wrong then: keep the user's terminal for what is.
CONNECTIONS = logging.getLogger("walkdiff.live.page.connections")
CONNECTIONS.addFilter(lambda record: record.getMessage() != "opening handshake failed")
LOCAL_HOSTS = ("127.0.0.1", "localhost", "::1")
WHERE = "the page"
BEHIND_S = 0.25  # a walker this late on its schedule skips ahead instead of catching up in a burst


def page_html() -> bytes:
    return resources.files("walkdiff.live").joinpath("page.html").read_bytes()


def address(host: str, port: int) -> str:
    return f"http://{f'[{host}]' if ':' in host else host}:{port}/"


def check_port(host: str, port: int) -> None:
    """A clear error, before the model loads, when the port is taken (the server checks again)."""
    if not 0 <= port <= 65535:
        raise WalkdiffError(f"--port {port}: expected a port from 0 (any free one) to 65535")
    if port == 0:
        return
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_STREAM) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind((host, port))
        except OSError as error:
            raise port_error(host, port, error) from None


def port_error(host: str, port: int, error: OSError) -> WalkdiffError:
    if error.errno == errno.EADDRINUSE:
        return WalkdiffError(f"--port {port}: port {port} on {host} is in use; pick another (0: any free)")
    return WalkdiffError(f"--port {port}: cannot serve on {host} ({error.strerror or error})")


@dataclass
class Recording:
    """A recording in progress: the frame it started at, each frame's command, the page's key events."""

    start: int
    commands: list[dict] = field(default_factory=list)
    events: list[dict] = field(default_factory=list)


@dataclass
class Finished:
    """A recording stopped: a fork of the walker holding its frames, to write while the walk goes on."""

    walker: WalkController
    recording: Recording
    why: str


class PlayPage:
    """The page's server and its walker: `run()` serves until Ctrl-C (the command); `start()` serves on a
    thread and `stop()` ends it (tests, benchmarks). `out` None: recording is refused on the page."""

    def __init__(
        self,
        walker: WalkController,
        keys: KeyControl,
        out: Path | None,
        manifest: dict,
        fps: float | None = None,
        overwrite: bool = False,
    ):
        self.walker, self.keys, self.out, self.manifest = walker, keys, out, manifest
        self.fps, self.overwrite = fps, overwrite
        keys.recording = False
        self.replay = Replay(walker, keys, [], WHERE)
        self.actions: queue.SimpleQueue = queue.SimpleQueue()  # page events, for the walker's thread
        self.finished: queue.SimpleQueue = queue.SimpleQueue()  # recordings stopped, to write
        self.recording: Recording | None = None
        self.takes: list[list[str]] = []
        self.named = 0
        self.clients: set = set()
        self.latest: str | None = None
        self.url: str | None = None
        self.html = page_html()
        self.hello = json.dumps(self._hello())
        self._stop: asyncio.Event | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._thread: threading.Thread | None = None
        self._failure: BaseException | None = None
        self._writing: set[asyncio.Task] = set()

    def _hello(self) -> dict:
        profile = self.walker.model.profile
        sides = [None if c is None else f"rgb({c[0]},{c[1]},{c[2]})" for c in limb_sides(self.walker.joints)]
        return {
            "type": "hello", "fps": self.walker.fps, "styles": list(self.walker.styles),
            "joints": self.walker.joints, "parents": [int(p) for p in profile.skeleton.parents],
            "colors": sides, "top_speed": self.keys.top_speed, "record": self.out is not None,
            "out": None if self.out is None else str(self.out),
            "clips": [c["clip"] for c in self.walker.start_clips] or None,
        }  # fmt: skip

    # ------------------------------------------------------------ the walker's thread

    def step(self) -> tuple[list[dict], str]:
        """Apply the queued page events, make the next frame: (notes for the pages, the frame's message).
        Recordings stopped go to `finished`."""
        notes = []
        while True:
            try:
                action = self.actions.get_nowait()
            except queue.Empty:
                break
            notes += self._apply(action)
        walker = self.walker
        if self.recording is not None:
            try:
                check_frames("recording", len(walker.kept) + 1, WALK_BYTES_PER_FRAME)
            except WalkdiffError as error:
                self.keys.recording = False
                self.replay.update()
                self._stopped(f"stopped at the memory limit: {error}")
                notes.append({"type": "error", "message": str(error)})
        if self.recording is not None:
            time_s = round((walker.frame - self.recording.start) / walker.fps, 4)
            self.recording.commands.append({"frame": walker.frame, "time": time_s} | walker.commanded())
        pose = walker.advance()[0]
        self.replay.tick()
        state = self.keys.state()
        message = {
            "type": "pose", "frame": pose.frame, "positions": pose.positions.round(3).tolist(),
            "root": pose.root.round(3).tolist(), "heading": round(pose.heading, 2),
            "command": walker.commanded(), "speed_own": state["speed"] is None,
            "recording": walker.record, "recorded": len(walker.kept), "takes": len(self.takes),
        }  # fmt: skip
        return notes, json.dumps(message)

    def _apply(self, action: tuple) -> list[dict]:
        """One page event applied to the keys, then the walker; a refused one changes nothing."""
        kind, value = action
        before, recording = copy.copy(self.keys), self.walker.record
        before.held = set(self.keys.held)
        try:
            if kind == "key":
                self.keys.key(*value)
            else:
                self.keys.command(**value)
            if self.keys.recording and not recording and self.out is None:
                raise WalkdiffError("recording is off: start walkdiff play with --out DIR to record takes")
            self.replay.update()
        except WalkdiffError as error:
            self.keys.__dict__.update(before.__dict__)
            return [{"type": "error", "message": str(error)}]
        if self.walker.record and not recording:
            self.walker.kept = []
            self.recording = Recording(self.walker.frame)
        elif recording and not self.walker.record:
            self._stopped("stopped on the page")
        if self.recording is not None:
            t = round((self.walker.frame - self.recording.start) / self.walker.fps, 4)
            event = {"key": value[0], "down": value[1]} if kind == "key" else dict(value)
            self.recording.events.append({"t": t} | event)
        return []

    def _stopped(self, why: str) -> None:
        """The recording in progress handed over for writing; the walker keeps no frames meanwhile."""
        self.finished.put(Finished(self.walker.fork(), self.recording, why))
        self.walker.kept, self.recording = [], None

    # ------------------------------------------------------------ writing takes

    def write(self, finished: Finished) -> list[str]:
        """A stopped recording as the next free take name's files (take, take2, ...): all or none."""
        while True:
            self.named += 1
            name = "take" if self.named == 1 else f"take{self.named}"
            files = take_files(self.out, 1, name)
            if self.overwrite or not any(f.exists() for f in files):
                break
        walker, recording = finished.walker, finished.recording
        manifest = self.manifest | {
            "source": WHERE, "stopped": finished.why, "start_frame": recording.start,
            "recorded_frames": len(walker.kept), "events": recording.events, "commands": recording.commands,
        }  # fmt: skip
        written = [str(f) for f in write_takes(self.out, walker, manifest, self.fps, name)]
        self.takes.append(written)
        print(f"walkdiff play: wrote {', '.join(written)}", flush=True)
        return written

    async def _write(self, pool: ThreadPoolExecutor, finished: Finished) -> None:
        try:
            files = await asyncio.get_running_loop().run_in_executor(pool, self.write, finished)
            note = {"type": "saved", "files": files}
        except WalkdiffError as error:
            note = {"type": "error", "message": f"the take was not written: {error}"}
        self._broadcast(json.dumps(note))

    # ------------------------------------------------------------ the server

    def _http(self, connection, request):
        from websockets.datastructures import Headers
        from websockets.http11 import Response

        path = request.path.split("?", 1)[0]
        if path == "/ws":
            origin, host = request.headers.get("Origin"), request.headers.get("Host")
            if origin is not None and origin != f"http://{host}":  # another site's page may not steer it
                return connection.respond(HTTPStatus.FORBIDDEN, "only the page itself may connect\n")
            return None
        if path not in ("/", "/index.html"):
            return connection.respond(HTTPStatus.NOT_FOUND, "not found\n")
        headers = Headers(
            [("Content-Type", "text/html; charset=utf-8"), ("Content-Length", str(len(self.html))),
             ("Cache-Control", "no-store"), ("Connection", "close")]
        )  # fmt: skip
        return Response(HTTPStatus.OK.value, HTTPStatus.OK.phrase, headers, self.html)

    async def _connection(self, websocket) -> None:
        from websockets.exceptions import ConnectionClosed

        self.clients.add(websocket)
        try:
            await websocket.send(self.hello)
            if self.latest is not None:
                await websocket.send(self.latest)
            async for text in websocket:
                problem = self.receive(text)
                if problem is not None:
                    await websocket.send(json.dumps({"type": "error", "message": problem}))
        except ConnectionClosed:
            pass
        finally:
            self.clients.discard(websocket)

    def receive(self, text) -> str | None:
        """A page's message queued for the walker's thread; what is wrong with it, if anything."""
        try:
            data = json.loads(text)
        except (TypeError, ValueError):
            data = None
        if not isinstance(data, dict):
            return "expected a JSON object"
        if data.get("type") == "key":
            key, down = data.get("key"), data.get("down", True)
            if not isinstance(key, str) or not isinstance(down, bool):
                return 'a key event: {"type": "key", "key": "ArrowLeft", "down": true}'
            self.actions.put(("key", (key, down)))
            return None
        if data.get("type") == "command":
            command = {k: data[k] for k in ("speed", "style") if k in data}
            try:
                if "speed" in command:
                    command["speed"] = min(checked_speed(command["speed"]), self.keys.top_speed)
            except WalkdiffError as error:
                return str(error)
            if not isinstance(command.get("style", ""), str) or not command:
                return 'a command: {"type": "command", "speed": m/s} or {"type": "command", "style": name}'
            self.actions.put(("command", command))
            return None
        return f"unknown message type {data.get('type')!r}; expected key or command"

    def _broadcast(self, message: str) -> None:
        from websockets.asyncio.server import broadcast

        broadcast(self.clients, message)

    async def _tick(self, walking: ThreadPoolExecutor, writing: ThreadPoolExecutor) -> None:
        """The walker at the model's frame rate: a frame made on its thread, sent to every page."""
        loop = asyncio.get_running_loop()
        period, due = 1.0 / self.walker.fps, loop.time()
        while True:
            notes, message = await loop.run_in_executor(walking, self.step)
            while not self.finished.empty():
                task = asyncio.create_task(self._write(writing, self.finished.get()))
                self._writing.add(task)
                task.add_done_callback(self._writing.discard)
            for note in notes:
                self._broadcast(json.dumps(note))
            self.latest = message
            self._broadcast(message)
            due += period
            if due < loop.time() - BEHIND_S:
                due = loop.time()
            await asyncio.sleep(max(due - loop.time(), 0.0))

    async def _serve(self, host: str, port: int, ready: Callable[[str], None]) -> None:
        from websockets.asyncio.server import serve

        self._loop, self._stop = asyncio.get_running_loop(), asyncio.Event()
        try:
            server = await serve(
                self._connection, host, port, process_request=self._http, compression=None, max_size=2**16,
                logger=CONNECTIONS,
            )  # fmt: skip
        except OSError as error:
            raise port_error(host, port, error) from None
        walking = ThreadPoolExecutor(1, thread_name_prefix="walkdiff-walker")
        writing = ThreadPoolExecutor(1, thread_name_prefix="walkdiff-takes")
        async with server:
            self.url = address(host, server.sockets[0].getsockname()[1])
            ticker = asyncio.create_task(self._tick(walking, writing))
            stopping = asyncio.create_task(self._stop.wait())
            ready(self.url)
            try:
                await asyncio.wait([ticker, stopping], return_when=asyncio.FIRST_COMPLETED)
            finally:
                ticker.cancel()
                stopping.cancel()
                await asyncio.gather(ticker, stopping, return_exceptions=True)
                walking.shutdown(wait=True)  # the frame in the making, if any, is done
                await asyncio.gather(*self._writing, return_exceptions=True)
                writing.shutdown(wait=True)
                if self.recording is not None:  # Ctrl-C or stop() while recording: keep the take
                    self._stopped("stopped with the server")
                while not self.finished.empty():
                    self.write(self.finished.get())
            if ticker.done() and not ticker.cancelled() and ticker.exception() is not None:
                raise ticker.exception()

    def run(self, host: str = "127.0.0.1", port: int = DEFAULT_PORT) -> dict:
        """Serve until Ctrl-C; the address is printed. Returns the summary."""

        def ready(url: str) -> None:
            print(f"walkdiff play: {url} (open it in a browser; Ctrl-C to stop)", flush=True)

        try:
            asyncio.run(self._serve(host, port, ready))
        except KeyboardInterrupt:
            pass
        return self.summary()

    def start(self, host: str = "127.0.0.1", port: int = 0, timeout: float = 60.0) -> str:
        """Serve on a thread of its own; returns the page's address once it listens."""
        listening = threading.Event()

        def serve() -> None:
            try:
                asyncio.run(self._serve(host, port, lambda url: listening.set()))
            except BaseException as error:  # handed to the caller of start or stop
                self._failure = error
            finally:
                listening.set()

        self._thread = threading.Thread(target=serve, name="walkdiff-play-page", daemon=True)
        self._thread.start()
        listening.wait(timeout)
        if self._failure is not None:
            raise self._failure
        if self.url is None:
            raise WalkdiffError(f"the play page did not start serving within {timeout:g} s")
        return self.url

    def stop(self, timeout: float = 60.0) -> dict:
        """End what `start` began (a recording in progress is written); the summary."""
        if self._thread is not None:
            if self._loop is not None and self._stop is not None:
                self._loop.call_soon_threadsafe(self._stop.set)
            self._thread.join(timeout)
            self._thread = None
        if self._failure is not None:
            raise self._failure
        return self.summary()

    def summary(self) -> dict:
        return {
            "url": self.url, "frames": self.walker.frame, "takes": self.takes,
            "files": [f for take in self.takes for f in take],
        }  # fmt: skip


def open_page(
    ckpt: str, out: str | None = None, fps: float | None = None, overwrite: bool = False, **options
) -> PlayPage:
    """The page's walker loaded and its output folder checked (take.* free unless `overwrite`);
    `options`: the walker's, as `PathFollower.controller` takes them (style, speed, seed, the sampler,
    transition, turn_rate, heading_assist, foot_lock, style_clips, match_clips)."""
    folder = None if out is None else output_folder(out)
    if folder is not None:
        check_free(take_files(folder, 1), overwrite)
    walker = load_walker(ckpt, record=False, **options)
    return PlayPage(walker, keys_for(walker, False), folder, settings(ckpt, walker, fps), fps, overwrite)


def serve_page(ckpt: str, host: str = "127.0.0.1", port: int = DEFAULT_PORT, **options) -> dict:
    """`walkdiff play` without --script: serve the page until Ctrl-C (`open_page`'s options)."""
    if host not in LOCAL_HOSTS:
        print(
            f"walkdiff play: warning: serving on {host}, not only this machine: anyone who reaches it can "
            "steer the walker and write takes to --out",
            file=sys.stderr, flush=True,
        )  # fmt: skip
    check_port(host, port)
    started = time.perf_counter()
    page = open_page(ckpt, **options)
    print(f"walkdiff play: model loaded in {time.perf_counter() - started:.1f} s", flush=True)
    return page.run(host, port)
