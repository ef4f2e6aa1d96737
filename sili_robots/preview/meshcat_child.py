"""Run meshcat's server on the loopback only, and end it when the process that started it ends.

Usage: ``python -m sili_robots.preview.meshcat_child PARENT_PID``. meshcat-python 0.3.2's own
``meshcat-server`` binds its web port on every interface (tornado's ``listen`` with no address)
although it prints a 127.0.0.1 URL; here both ports are bound to 127.0.0.1. A watchdog thread
exits within ``POLL`` seconds of the parent process ending, however it ends (even SIGKILL). It
watches the parent *process*: Linux's ``PR_SET_PDEATHSIG`` would fire when the parent *thread*
ends, killing a server started from a worker thread that has finished.
"""

from __future__ import annotations

import functools
import os
import sys
import threading
import time

from meshcat.servers.tree import walk
from meshcat.servers.zmqserver import ZMQWebSocketBridge

LOOPBACK = "127.0.0.1"
POLL = 0.2


class LoopbackBridge(ZMQWebSocketBridge):
    """meshcat's bridge with its web server listening on the loopback only, replaying a scene
    to a page that connects as the file does (``SceneRecorder.commands``)."""

    def make_app(self):
        app = super().make_app()
        app.listen = functools.partial(app.listen, address=LOOPBACK)
        return app

    def send_scene(self, websocket):
        """``scene_messages``: meshcat's own replay sends a node's animation before its
        children's objects, so the page's tracks bound to objects not made yet: the live view
        animated a scene the file shows right, wrongly."""
        for data in scene_messages(self.tree):
            websocket.write_message(data, binary=True)


def scene_messages(tree) -> list[bytes]:
    """A scene tree's packed commands in the order a page must get them: every object,
    property and transform (meshcat's tree walk), then the animations, which bind to them."""
    out, animations = [], []
    for node in walk(tree):
        out.extend(d for d in (node.object, *node.properties, node.transform) if d is not None)
        if node.animation is not None:
            animations.append(node.animation)
    return out + animations


def exit_with(parent: int) -> None:
    """End this process once ``parent`` is no longer its parent (it exited)."""
    while os.getppid() == parent:
        time.sleep(POLL)
    os._exit(0)


def main() -> None:
    parent = int(sys.argv[1])
    if os.getppid() != parent:  # the parent is already gone
        sys.exit(0)
    threading.Thread(target=exit_with, args=(parent,), daemon=True).start()
    bridge = LoopbackBridge(host=LOOPBACK)
    print(f"zmq_url={bridge.zmq_url}\nweb_url={bridge.web_url}", flush=True)
    bridge.run()  # until SIGTERM from ``LiveServer.stop`` or the watchdog's exit


if __name__ == "__main__":
    main()
