"""Headless Chromium driven over the DevTools protocol on a pipe: render preview HTML to PNG.

Why a pipe and not ``chromium --screenshot``: the screenshot must wait until the meshcat scene
is built and the animation is sought to the wanted frame, and the visual checks need to ask the
page's own camera where scene points land and which URLs the page requested. The DevTools
protocol over ``--remote-debugging-pipe`` needs no extra Python package and no open port.
"""

from __future__ import annotations

import base64
import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from sili_robots.errors import ConfigError

#: flags every launch uses: no sandbox (root in containers), no network chatter, software GL
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-dev-shm-usage",
    "--use-angle=swiftshader",
    "--enable-unsafe-swiftshader",
    "--hide-scrollbars",
    "--mute-audio",
    "--disable-breakpad",
    "--disable-crash-reporter",
    # Any host but this machine's loopback fails at once: a preview must render offline
    # (the loopback stays reachable for a live meshcat server).
    "--host-resolver-rules=MAP * ~NOTFOUND, EXCLUDE 127.0.0.1",
)
FD_WRAPPER = (
    "import os, sys; r, w = int(sys.argv[1]), int(sys.argv[2]); os.dup2(r, 3); os.dup2(w, 4);"
    " os.close(r); os.close(w); os.execv(sys.argv[3], sys.argv[3:])"
)
#: boxes of HTML drawn over the WebGL canvas (our captions, meshcat's controls)
COVERED_JS = (
    "Array.from(document.querySelectorAll('.preview-box, .dg.main'))"
    ".map(e => e.getBoundingClientRect()).filter(r => r.width > 0 && r.height > 0)"
    ".map(r => [r.left, r.top, r.right, r.bottom])"
)
#: the longest path of a Unix socket's address (``sun_path`` holds 108 bytes with its NUL)
SOCKET_PATH_MAX = 107
#: how the folders of Chromium's (and Chrome's) process-singleton socket are named: the prefix
#: of ``mkdtemp`` in the temporary directory
SINGLETON_FOLDERS = ("org.chromium.Chromium.", "com.google.Chrome.")
CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


class BrowserError(RuntimeError):
    """Chromium is missing, died, or the page did not become ready."""


def find_chromium() -> str:
    """Path of a Chromium binary (``SILI_CHROMIUM`` overrides the search)."""
    override = os.environ.get("SILI_CHROMIUM")
    if override:
        if shutil.which(override) is None:
            raise ConfigError(f"SILI_CHROMIUM={override!r} is not an executable")
        return str(shutil.which(override))
    for name in CANDIDATES:
        path = shutil.which(name)
        if path:
            return path
    raise ConfigError(
        "PNG rendering needs headless Chromium, none found on PATH (tried "
        f"{', '.join(CANDIDATES)}); install it, e.g. `apt-get install chromium fonts-dejavu-core`"
    )


@dataclass
class PageResult:
    """What one rendered page produced."""

    png: bytes
    width: int
    height: int
    #: every URL the page requested (the HTML file itself included)
    requests: list[str] = field(default_factory=list)
    #: console errors and uncaught exceptions
    errors: list[str] = field(default_factory=list)
    #: pixel (x, y) of each world point asked for, through the page's own camera; a point
    #: behind the camera lands at (-1, -1), outside the picture
    projections: list[tuple[float, float]] = field(default_factory=list)
    #: whatever the ``evaluate`` expression returned
    value: Any = None
    #: screenshots with some meshcat nodes hidden, by the (sorted) paths hidden
    hidden: dict[tuple[str, ...], bytes] = field(default_factory=dict)
    #: (x0, y0, x1, y1) of HTML boxes drawn over the 3D view (captions, controls)
    covered: list[tuple[float, float, float, float]] = field(default_factory=list)


class Browser:
    """One headless Chromium process; ``render`` may be called many times. Use as a context."""

    def __init__(self, executable: str | None = None, timeout: float = 60.0) -> None:
        self.executable = executable or find_chromium()
        self.timeout = timeout
        self._proc: subprocess.Popen | None = None
        self._profile: str | None = None
        self._next_id = 0
        self._buffer = b""
        self._events: list[dict[str, Any]] = []

    # ------------------------------------------------------------------ process
    def start(self) -> Browser:
        self._profile = tempfile.mkdtemp(prefix="sili-chromium-")
        to_browser_r, to_browser_w = os.pipe()
        from_browser_r, from_browser_w = os.pipe()
        # the child's ends must not be fds 3 or 4 themselves (the shell below moves them there)
        to_browser_r, from_browser_w = (_high_fd(to_browser_r), _high_fd(from_browser_w))
        args = [
            self.executable,
            *CHROMIUM_FLAGS,
            f"--user-data-dir={self._profile}",
            "--remote-debugging-pipe",
            "about:blank",
        ]
        # The browser reads commands on fd 3 and writes replies on fd 4; a tiny exec wrapper
        # puts the pipe ends there (no shell: dash cannot redirect fds above 9).
        try:
            wrapper = [sys.executable, "-c", FD_WRAPPER, str(to_browser_r), str(from_browser_w)]
            with open(self._stderr_log(), "wb") as stderr:  # its reasons, should it fail
                self._proc = subprocess.Popen(
                    [*wrapper, *args],
                    pass_fds=(to_browser_r, from_browser_w),
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.DEVNULL,
                    stderr=stderr,
                    start_new_session=True,
                    env=_profile_env(self._profile),
                )
        finally:
            os.close(to_browser_r)
            os.close(from_browser_w)
        self._write_fd = to_browser_w
        self._read_fd = from_browser_r
        os.set_blocking(self._read_fd, False)
        try:
            self.call("Browser.getVersion")
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Stop the browser and every process it started; safe to call twice."""
        proc, self._proc = self._proc, None
        if proc is not None:
            try:
                if proc.poll() is None:
                    try:
                        self._send("Browser.close")
                        proc.wait(timeout=5)
                    except (BrowserError, OSError, subprocess.TimeoutExpired):
                        pass
            finally:
                with contextlib.suppress(ProcessLookupError, PermissionError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
                for fd in (self._write_fd, self._read_fd):
                    with contextlib.suppress(OSError):
                        os.close(fd)
        if self._profile is not None:
            _remove_singleton_folder(self._profile)
            shutil.rmtree(self._profile, ignore_errors=True)
            self._profile = None

    def __enter__(self) -> Browser:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ protocol
    def _send(self, method: str, params: dict | None = None, session: str | None = None) -> int:
        if self._proc is None:
            raise BrowserError("the browser is not running")
        self._next_id += 1
        msg: dict[str, Any] = {"id": self._next_id, "method": method, "params": params or {}}
        if session is not None:
            msg["sessionId"] = session
        data = json.dumps(msg).encode() + b"\0"
        while data:
            try:
                n = os.write(self._write_fd, data)
            except BrokenPipeError:  # it exited before reading (a missing library, say)
                raise self._gone("Chromium closed its DevTools pipe") from None
            data = data[n:]
        return self._next_id

    def _stderr_log(self) -> Path:
        return Path(str(self._profile)) / "chromium-stderr.log"

    def _gone(self, what: str) -> BrowserError:
        """``what`` happened to Chromium, with the last lines it wrote to stderr (a missing
        library, a memory limit, a sandbox it cannot use)."""
        try:
            lines = self._stderr_log().read_text(errors="replace").strip().splitlines()
        except OSError:
            lines = []
        said = " | ".join(line.strip() for line in lines[-3:] if line.strip())
        what = f"{what} ({self.executable})"  # SILI_CHROMIUM may name something else
        return BrowserError((f"{what}; it said: {said}" if said else what) + _address_limit())

    def _read_message(self, deadline: float) -> dict[str, Any]:
        import select

        while b"\0" not in self._buffer:
            left = deadline - time.monotonic()
            if left <= 0:
                raise BrowserError(f"timed out waiting for Chromium ({self.executable})")
            ready, _, _ = select.select([self._read_fd], [], [], min(left, 0.5))
            if not ready:
                if self._proc is not None and self._proc.poll() is not None:
                    raise self._gone(f"Chromium exited with code {self._proc.returncode}")
                continue
            chunk = os.read(self._read_fd, 1 << 20)
            if not chunk:
                raise self._gone("Chromium closed its DevTools pipe")
            self._buffer += chunk
        raw, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(raw)

    def call(self, method: str, params: dict | None = None, session: str | None = None) -> dict:
        """Send one command and return its result (events seen meanwhile are kept)."""
        msg_id = self._send(method, params, session)
        deadline = time.monotonic() + self.timeout
        while True:
            msg = self._read_message(deadline)
            if msg.get("id") == msg_id:
                if "error" in msg:
                    raise BrowserError(f"{method} failed: {msg['error'].get('message')}")
                return msg.get("result", {})
            if "method" in msg:
                self._events.append(msg)

    def _wait_event(self, method: str, session: str, deadline: float) -> dict:
        while True:
            for i, ev in enumerate(self._events):
                if ev["method"] == method and ev.get("sessionId") == session:
                    return self._events.pop(i)
            msg = self._read_message(deadline)
            if "method" in msg:
                self._events.append(msg)

    def evaluate(self, session: str, expression: str) -> Any:
        """Evaluate JavaScript in the page (promises awaited) and return its JSON value."""
        res = self.call(
            "Runtime.evaluate",
            {"expression": expression, "awaitPromise": True, "returnByValue": True},
            session,
        )
        if "exceptionDetails" in res:
            details = res["exceptionDetails"]
            text = details.get("exception", {}).get("description") or details.get("text")
            raise BrowserError(f"page script failed: {text}")
        return res.get("result", {}).get("value")

    def _screenshot(self, session: str) -> bytes:
        """PNG of the page after two more animation frames (the scene drawn as it is now)."""
        self.evaluate(
            session, "new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))"
        )
        shot = self.call("Page.captureScreenshot", {"format": "png", "fromSurface": True}, session)
        return base64.b64decode(shot["data"])

    # ------------------------------------------------------------------ pages
    def render(
        self,
        html: str | Path,
        width: int = 640,
        height: int = 480,
        ready: str = "true",
        setup: str | None = None,
        points: list[tuple[float, float, float]] | None = None,
        evaluate: str | None = None,
        ready_timeout: float = 30.0,
        hide: list[tuple[str, ...]] = (),
    ) -> PageResult:
        """Open a local HTML file (or a URL), wait for ``ready`` (a JS expression), run
        ``setup``, take a screenshot.

        ``points`` are projected to pixels with the page's ``viewer.camera`` (meshcat) after the
        frame is drawn, so checks can look where the scene puts things. For each set of meshcat
        paths in ``hide`` another screenshot is taken with those nodes hidden.
        """
        if isinstance(html, str) and html.startswith(("http://", "https://", "file://")):
            url = html
        else:
            path = Path(html).resolve()
            if not path.is_file():
                raise ConfigError(f"no such HTML file: {path}")
            url = path.as_uri()
        self._events.clear()
        target = self.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True})[
            "sessionId"
        ]
        try:
            for domain in ("Page", "Network", "Runtime", "Log"):
                self.call(f"{domain}.enable", None, session)
            self.call(
                "Emulation.setDeviceMetricsOverride",
                {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False},
                session,
            )
            self.call("Page.navigate", {"url": url}, session)
            deadline = time.monotonic() + ready_timeout
            self._wait_event("Page.loadEventFired", session, deadline)
            while not self.evaluate(session, f"Boolean({ready})"):
                failed = _page_errors(self._events, session)
                if failed:
                    raise BrowserError(f"page failed before it was ready: {failed[0]}")
                if time.monotonic() > deadline:
                    raise BrowserError(f"page not ready after {ready_timeout} s: {ready}")
                time.sleep(0.05)
            if setup:
                self.evaluate(session, setup)
            # two animation frames: the scene is drawn with the setup applied
            self.evaluate(
                session,
                "new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))",
            )
            projections: list[tuple[float, float]] = []
            if points:
                projections = [tuple(p) for p in self.evaluate(session, _project_js(list(points)))]
            value = self.evaluate(session, evaluate) if evaluate else None
            covered = self.evaluate(session, COVERED_JS)
            shot = self._screenshot(session)
            hidden: dict[tuple[str, ...], bytes] = {}
            for paths in dict.fromkeys(hide):
                for path in paths:
                    self.evaluate(session, _visible_js(path, False))
                hidden[paths] = self._screenshot(session)
                for path in paths:
                    self.evaluate(session, _visible_js(path, True))
        finally:
            with contextlib.suppress(BrowserError):
                self.call("Target.closeTarget", {"targetId": target})
        requests, errors = [], []
        for ev in self._events:
            if ev.get("sessionId") != session:
                continue
            params = ev.get("params", {})
            if ev["method"] == "Network.requestWillBeSent":
                requests.append(params["request"]["url"])
            elif ev["method"] == "Runtime.exceptionThrown":
                d = params.get("exceptionDetails", {})
                errors.append(d.get("exception", {}).get("description") or d.get("text", ""))
            elif ev["method"] == "Runtime.consoleAPICalled" and params.get("type") == "error":
                errors.append(
                    " ".join(str(a.get("value", a.get("description"))) for a in params["args"])
                )
            elif ev["method"] == "Log.entryAdded" and params["entry"].get("level") == "error":
                entry = params["entry"]
                if not entry.get("url", "").endswith("/favicon.ico"):  # browsers' own request
                    errors.append(f"{entry.get('text', '')} {entry.get('url', '')}".strip())
        self._events = [e for e in self._events if e.get("sessionId") != session]
        return PageResult(
            png=shot,
            hidden=hidden,
            width=width,
            height=height,
            requests=requests,
            errors=errors,
            projections=projections,
            value=value,
            covered=[tuple(r) for r in covered],
        )


def _visible_js(path: str, visible: bool) -> str:
    parts = [p for p in path.split("/") if p]
    return (
        f"(() => {{ const n = viewer.scene_tree.find({json.dumps(parts)});"
        f" n.object.visible = {'true' if visible else 'false'}; viewer.set_dirty(); }})()"
    )


def _page_errors(events: list[dict[str, Any]], session: str) -> list[str]:
    """Uncaught exceptions the page has thrown so far."""
    out = []
    for ev in events:
        if ev.get("sessionId") == session and ev["method"] == "Runtime.exceptionThrown":
            d = ev["params"].get("exceptionDetails", {})
            out.append(d.get("exception", {}).get("description") or d.get("text", ""))
    return out


def _profile_env(profile: str) -> dict[str, str]:
    """The environment with the home, config and cache folders in the temporary profile:
    Chromium writes crash-report settings and a dconf cache there whatever ``--user-data-dir``
    says, and a preview leaves nothing in the user's home."""
    return {
        **os.environ,
        "HOME": profile,
        "TMPDIR": _chromium_tmpdir(),
        "XDG_CONFIG_HOME": os.path.join(profile, "config"),
        "XDG_CACHE_HOME": os.path.join(profile, "cache"),
    }


def _address_limit() -> str:
    """A note on the process's address-space limit (``ulimit -v``), if it has one: Chromium
    reserves far more virtual memory than it uses and stops at start under a limit of a few
    GiB, saying only something cryptic."""
    import resource

    limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    if limit == resource.RLIM_INFINITY:
        return ""
    return (
        f" (this process's address space is limited to {limit / 2**30:.1f} GiB, `ulimit -v`; "
        "Chromium reserves much more than it uses: lift the limit for previews)"
    )


def _chromium_tmpdir() -> str:
    """The user's temporary directory, or ``/tmp`` where that is too long for Chromium: its
    process-singleton socket goes there, and Chromium stops at start ("Socket path too long")
    when the socket's path is longer than a socket address holds (107 bytes)."""
    tmp = os.environ.get("TMPDIR") or "/tmp"
    socket = os.path.join(tmp, f"{SINGLETON_FOLDERS[0]}XXXXXX", "SingletonSocket")  # the longer
    if len(os.fsencode(socket)) <= SOCKET_PATH_MAX or not os.access("/tmp", os.W_OK):
        return tmp
    return "/tmp"


def _remove_singleton_folder(profile: str) -> None:
    """Remove the folder Chromium keeps its process-singleton socket in: it makes one in the
    temporary directory (``org.chromium.Chromium.*``; Chrome's ``com.google.Chrome.*``), linked
    from the profile, and a headless run leaves it there. Not moved into the profile with
    ``TMPDIR``: a socket's path has at most 107 bytes, and a profile under a long temporary path
    would stop Chromium from starting."""
    with contextlib.suppress(OSError):
        folder = Path(os.readlink(os.path.join(profile, "SingletonSocket"))).parent
        if folder.name.startswith(SINGLETON_FOLDERS):
            shutil.rmtree(folder, ignore_errors=True)


def _high_fd(fd: int) -> int:
    """A copy of ``fd`` numbered 10 or more (the original is closed)."""
    import fcntl

    high = fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10)
    os.close(fd)
    return high


def _project_js(points: list[tuple[float, float, float]]) -> str:
    return (
        "(() => { const c = viewer.camera; const el = viewer.renderer.domElement;"
        " viewer.scene.updateMatrixWorld(); c.updateMatrixWorld();"
        " const m = viewer.scene.matrixWorld; const v = c.position.clone();"
        f" return {json.dumps([list(map(float, p)) for p in points])}.map(p => {{"
        # meshcat's scene root turns its z-up world into three.js' y-up world
        " v.set(p[0], p[1], p[2]).applyMatrix4(m).project(c);"
        " if (v.z > 1) return [-1, -1];"  # behind the camera: mirrored, not in the picture
        " return [(v.x + 1) / 2 * el.clientWidth, (1 - v.y) / 2 * el.clientHeight]; }); })()"
    )
