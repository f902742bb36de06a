"""``--live``: the view (:mod:`amhe_cli.io.view`) streamed to Foxglove over its WebSocket protocol.

The server is the official Foxglove SDK's (``foxglove-sdk``, ``pip install 'amhe[live]'``):
``foxglove.start_server`` on its own :class:`foxglove.Context`, speaking the Foxglove WebSocket
protocol (subprotocols ``foxglove.sdk.v1`` / ``foxglove.websocket.v1``). Each view topic is an SDK
:class:`foxglove.Channel` with the topic's ``ros2msg`` schema and ``cdr`` messages, byte for byte
what a recording holds, so a layout works on both.

Off the control path: hooks hand :class:`~amhe_cli.io.view.Event` s to :meth:`LiveServer.offer`,
which only sends them, pickled, as one datagram on a local socket pair to the server's own process
(a full buffer drops the event: frames are dropped, never delayed, and nothing blocks). That
process converts, encodes and sends, so none of it holds the control process's interpreter lock;
it keeps bounded queues of its own (the oldest frame dropped first) and does no work for a topic
nobody subscribed to. The SDK's own per-client backlog drops the oldest message for a slow viewer.
"""

from __future__ import annotations

import collections
import multiprocessing
import os
import pickle
import signal
import socket
import time
from importlib import resources

from amhe_cli.errors import AmheError
from amhe_cli.io.view import VIEW_TOPICS, Event, ViewFrames, encoder, msgdef

#: Default port of ``--live`` (Foxglove's own default connection string, ws://localhost:8765).
DEFAULT_PORT = 8765
#: Default host: loopback only; ``--live 0.0.0.0:8765`` opens it to the network.
DEFAULT_HOST = "127.0.0.1"
#: Bytes of events in flight to the server's process (the socket's send buffer; more are dropped,
#: never waited for): about a thousand robot-state frames.
INBOX_BYTES = 1 << 20
#: Longest wait for the server's process to start and listen [s] (it imports mujoco and the SDK).
START_TIMEOUT = 30.0
_END = pickle.dumps(None)

#: Largest number of robot-state frames waiting to be sent (older ones are dropped first).
STATE_QUEUE = 64
#: Largest number of other events (plans, beliefs, logs) waiting; the oldest are dropped first.
EVENT_QUEUE = 256
#: The static scene (and the last of each :data:`LATCHED` kind) is re-sent this often [s] and when a
#: viewer subscribes, so a viewer that joins late sees the robot and the current belief.
SCENE_PERIOD = 2.0
#: How long the server keeps its viewers' connections open after the last message at the end [s].
LINGER = 0.5
#: Event kinds whose last message a late viewer gets again (a belief may not change for a whole run).
LATCHED = ("belief", "safety")


def parse_live_address(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` -> (host, port); a bare PORT listens on :data:`DEFAULT_HOST`.

    Raises:
        AmheError: not ``PORT`` or ``HOST:PORT`` with a port 0–65535 (0: any free port).
    """
    text = str(text).strip()
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host = DEFAULT_HOST
    host = host.strip("[]") or DEFAULT_HOST
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not 0 <= port <= 65535:
        raise AmheError(f"--live {text!r}: expected [HOST:]PORT with PORT 0-65535, e.g. 8765 or 127.0.0.1:8765")
    return host, port


def require_sdk():
    """The ``foxglove`` module, or AmheError saying how to install it."""
    try:
        import foxglove
    except ImportError:
        raise AmheError("--live needs the Foxglove SDK: pip install 'amhe[live]' (foxglove-sdk)") from None
    return foxglove


def layout_text() -> str:
    """The Foxglove layout shipped with amhe (``amhe live-layout``): 3D scene, plan, belief plots with σ
    and truth, planner rate, safety state and the log."""
    return resources.files("amhe_cli").joinpath("live_layout.json").read_text(encoding="utf-8")


class LiveServer:
    """A Foxglove WebSocket server streaming a view, in a process of its own; a context manager.

    Protocol: the Foxglove WebSocket protocol of the official SDK (``foxglove.start_server`` on a
    :class:`foxglove.Context` of its own): one channel per :data:`~amhe_cli.io.view.VIEW_TOPICS`
    topic, ``ros2msg`` schema, ``cdr`` messages, log time = the event's log time [ns].

    Off the control path: the server, the conversion of events into messages and their CDR encoding
    (pure Python, about 0.5 ms per robot-state frame) run in a child process (``spawn``), so they
    never hold the control process's interpreter lock. :meth:`offer` only pickles the event and
    sends it as one non-blocking datagram on a local socket pair (about 20 µs, in the caller's thread;
    no other thread of the control process wakes); when the socket's buffer (:data:`INBOX_BYTES`) is
    full, the server's process is gone or the event is too big, the event is dropped, never waited for.

    Args:
        frames: converts events into messages (a copy goes to the server's process at :meth:`start`;
            later changes reach it only as events, e.g. ``Event("goal", t, (x, y))``).
        host, port: where to listen (port 0: any free port; :attr:`port` says which).
        name: the server's name as Foxglove shows it.

    Raises:
        AmheError: the SDK is missing, or the server cannot listen (a busy port, a bad host), or its
            process did not start within :data:`START_TIMEOUT` s.

    Attributes (read from the server's process while it runs):
        sent: messages sent; dropped: events dropped (a full buffer or queue, a failed conversion).
        cpu_s: CPU time the server's process used so far [s] (converting, encoding, the SDK's
            network threads), none of it on the control process.
    """

    def __init__(self, frames: ViewFrames, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, name: str = "amhe"):
        self.frames = frames
        self.host, self.port, self.name = host, port, name
        self._proc = None
        self._tx = None
        self._stats = None
        self._dropped_here = 0

    # -- lifetime -------------------------------------------------------------------------------------------
    def start(self) -> "LiveServer":
        """Start the server's process and wait until it listens.

        Raises:
            AmheError: the SDK is missing, the address cannot be bound, or the process did not start.
        """
        require_sdk()
        ctx = multiprocessing.get_context("spawn")  # never fork a process that runs control threads
        # events travel as datagrams on a local socket pair: one non-blocking send in the caller's
        # thread, no feeder thread to wake, whole or not at all
        try:
            self._tx, rx = socket.socketpair(socket.AF_UNIX, socket.SOCK_DGRAM)
        except (AttributeError, OSError) as exc:  # no local datagram sockets (Windows)
            raise AmheError(f"--live needs local datagram sockets (Linux, macOS): {exc}") from None
        self._tx.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, INBOX_BYTES)
        self._tx.setblocking(False)
        self._stats = ctx.Array("d", 3, lock=False)  # sent, dropped, cpu_s
        ready, child_end = ctx.Pipe(duplex=False)
        self._proc = ctx.Process(target=_serve, name="amhe-live", daemon=True,
                                 args=(self.frames, self.host, self.port, self.name, rx, child_end,
                                       self._stats, os.getpid()))
        self._proc.start()
        child_end.close()
        rx.close()
        try:
            reply = ready.recv() if ready.poll(START_TIMEOUT) else ("error", f"no answer in {START_TIMEOUT:g} s")
        except EOFError:
            self._proc.join(timeout=1.0)
            reply = ("error", f"the server's process ended (exit code {self._proc.exitcode})")
        finally:
            ready.close()
        if reply[0] != "ok":
            self._kill()
            raise AmheError(f"--live {self.host}:{self.port}: cannot listen there ({reply[1]})")
        self.port = reply[1]
        return self

    @property
    def address(self) -> str:
        """``ws://HOST:PORT`` to open in Foxglove."""
        return f"ws://{self.host}:{self.port}"

    @property
    def sent(self) -> int:
        """Messages the server's process has sent."""
        return int(self._stats[0]) if self._stats is not None else 0

    @property
    def dropped(self) -> int:
        """Events dropped here (buffer full, process gone) and there (its queues full, a failed conversion)."""
        return self._dropped_here + (int(self._stats[1]) if self._stats is not None else 0)

    @property
    def cpu_s(self) -> float:
        """CPU time [s] the server's process has used since it listened."""
        return float(self._stats[2]) if self._stats is not None else 0.0

    def close(self) -> None:
        """Let the server send what is queued (up to 1 s) and its viewers receive it (:data:`LINGER` s),
        then stop its process. Safe to call twice."""
        if self._proc is None:
            return
        try:
            self._tx.settimeout(1.0)
            self._tx.send(_END)
        except OSError:
            pass
        self._proc.join(timeout=3.0)
        self._kill()

    def _kill(self) -> None:
        if self._proc is not None and self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=2.0)
        self._proc = None
        if self._tx is not None:
            self._tx.close()

    def __enter__(self) -> "LiveServer":
        return self.start() if self._proc is None else self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the hooks' side: never blocks ----------------------------------------------------------------------
    def offer(self, ev: Event) -> None:
        """Hand ``ev`` to the server's process; a full buffer, a server process gone or a server
        already closed drops it (counted in :attr:`dropped`)."""
        if self._proc is None:
            self._dropped_here += 1
            return
        try:
            self._tx.send(pickle.dumps(ev, pickle.HIGHEST_PROTOCOL))
        except OSError:  # the buffer is full (BlockingIOError), the process gone, or the event too big
            self._dropped_here += 1


def _serve(frames: ViewFrames, host: str, port: int, name: str, inbox: socket.socket, ready, stats,
           parent: int) -> None:
    """The server's process: listen, answer ``ready`` with ("ok", port) or ("error", why), then send
    what ``inbox`` brings until it brings None (draining up to 1 s) or the parent process is gone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle; it stops us
    sender = _Sender(frames, stats)
    try:
        sender.listen(host, port, name)
    except Exception as exc:  # noqa: BLE001 - the SDK raises RuntimeError/OSError variants for a busy port
        ready.send(("error", " ".join(str(exc).split())))
        return
    ready.send(("ok", sender.port))
    ready.close()
    sender.cpu0 = time.process_time()  # what the view costs from here on, not the imports
    try:
        sender.run(inbox, parent)
        sender.linger()
    finally:
        sender.stop()


class _Sender:
    """Inside the server's process: bounded queues of events, converted and sent in order; robot-state
    frames wait until their ``due`` time (paced playback); the scene and the :data:`LATCHED` kinds are
    re-sent every :data:`SCENE_PERIOD` s and when a viewer subscribes; nothing is converted for a topic
    nobody subscribed to."""

    def __init__(self, frames: ViewFrames, stats):
        self.frames, self.stats = frames, stats
        self.sent = self.dropped = 0
        self.states: collections.deque = collections.deque(maxlen=STATE_QUEUE)
        self.events: collections.deque = collections.deque(maxlen=EVENT_QUEUE)
        self.scene_due = 0.0
        self.last_t = 0.0
        self.latched: dict[str, Event] = {}
        self.channels: dict = {}
        self.encoders: dict = {}
        self.server = None
        self.port = None
        self.cpu0 = 0.0

    def listen(self, host: str, port: int, name: str) -> None:
        fg = require_sdk()
        self.ctx = ctx = fg.Context()  # kept: the channels live only as long as their context
        sender = self

        class _Listener(fg.websocket.ServerListener):
            def on_subscribe(self, client, channel):  # a new viewer: send the scene again now
                sender.scene_due = 0.0

        self.server = fg.start_server(name=name, host=host, port=port, context=ctx, server_listener=_Listener())
        self.port = self.server.port
        for topic, msgtype in VIEW_TOPICS.items():
            schema = fg.Schema(name=msgtype, encoding="ros2msg", data=msgdef(msgtype).encode())
            self.channels[topic] = fg.Channel(topic, schema=schema, message_encoding="cdr", context=ctx)
            self.encoders[topic] = encoder(msgtype)

    def linger(self) -> None:
        """Give the SDK :data:`LINGER` s to write what was logged to the viewers' sockets before the
        server stops: its stop closes the connections without sending what they still queue, so the
        run's last messages (its closing log line) would otherwise be lost."""
        if any(ch.has_sinks() for ch in self.channels.values()):
            time.sleep(LINGER)

    def stop(self) -> None:
        if self.server is not None:
            self.server.stop()
            self.server = None

    def _take(self, ev: Event | None) -> bool:
        """Queue one event from the inbox; False for the end (None)."""
        if ev is None:
            return False
        if ev.kind == "goal":  # the scene changes: re-send it now
            self.frames.convert(ev)
            self.scene_due = 0.0
            return True
        q = self.states if ev.kind == "state" else self.events
        if len(q) == q.maxlen:
            self.dropped += 1
        q.append(ev)
        return True

    def run(self, inbox: socket.socket, parent: int) -> None:
        draining_until = None
        wait = 0.0
        while True:
            try:  # block for the first event (at most ``wait``), then take all that are there
                inbox.settimeout(wait)
                while draining_until is None:
                    if not self._take(pickle.loads(inbox.recv(INBOX_BYTES))):
                        draining_until = time.monotonic() + 1.0
                    inbox.setblocking(False)
            except (BlockingIOError, TimeoutError):
                pass
            except OSError:  # the parent is gone
                return
            now = time.monotonic()
            self.stats[0], self.stats[1], self.stats[2] = self.sent, self.dropped, time.process_time() - self.cpu0
            if draining_until is not None and (now >= draining_until or not (self.events or self.states)):
                return
            if os.getppid() != parent:
                return
            if now >= self.scene_due:  # periodically, and at once for a new subscriber
                self.scene_due = now + SCENE_PERIOD
                self._safe(Event("scene", self.last_t, ()))
                for ev in list(self.latched.values()):
                    self._safe(ev)
            while self.events:
                self._safe(self.events.popleft())
            wait = 0.05
            while self.states:
                ev = self.states[0]
                if ev.due > now and draining_until is None:
                    wait = min(wait, ev.due - now)
                    break
                self._safe(self.states.popleft())
            if draining_until is not None:
                wait = 0.0

    def _send(self, ev: Event) -> None:
        self.last_t = max(self.last_t, ev.t)
        if ev.kind in LATCHED:
            self.latched[ev.kind] = ev
        wanted = [t for t in _TOPICS_OF.get(ev.kind, ()) if self.channels[t].has_sinks()]
        if not wanted:
            return
        for topic, ns, msg in self.frames.convert(ev):
            if topic in wanted:
                self.channels[topic].log(self.encoders[topic](msg), log_time=ns)
                self.sent += 1

    def _safe(self, ev: Event) -> None:
        try:
            self._send(ev)
        except Exception:  # noqa: BLE001 - a view must never take the run down; the frame is lost
            self.dropped += 1


#: Topics each event kind produces.
_TOPICS_OF = {"state": ("/amhe/tf",), "scene": ("/amhe/scene",), "plan": ("/amhe/planner", "/amhe/plan"),
              "belief": ("/amhe/belief",), "safety": ("/amhe/safety",), "log": ("/amhe/log",)}


def build_layout() -> str:
    """The layout :func:`layout_text` ships, built with the SDK's ``foxglove.layouts`` (needs the SDK).

    Left: the 3D scene in ``world`` (robot, box, goal, floor μ, plan). Right: box mass and box–floor μ
    with ±σ band, window estimate and truth (``/amhe/belief``), the replanning rate, the safety state,
    the log. A test checks the shipped file is this function's output.
    """
    import foxglove.layouts as fl

    def belief_plot(k: int, name: str, unit: str):
        base = 6 * k  # see amhe_cli.io.view.BELIEF_FIELDS
        series = [("estimate", 0, "#1f77b4", "solid"), ("estimate - σ", 2, "#aec7e8", "dashed"),
                  ("estimate + σ", 3, "#aec7e8", "dashed"), ("window", 4, "#ff7f0e", "dotted"),
                  ("truth", 5, "#2ca02c", "solid")]
        return fl.PlotPanel(title=f"{name} [{unit}]", config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=f"/amhe/belief.data[{base + i}]", label=label, color=color, line_style=style,
                                 line_interpolation="step") for label, i, color, style in series],
            show_legend=True, legend_display="top"))

    scene = fl.ThreeDeePanel(title="robot, box, goal, floor μ, plan", config=fl.ThreeDeeConfig(
        fixed_frame="world", follow_tf="trunk", follow_mode="follow-position",
        topics={t: fl.BaseRendererSceneUpdateTopicSettings(visible=True) for t in ("/amhe/scene", "/amhe/plan")}))
    rate = fl.PlotPanel(title="planner [Hz], compute [ms]", config=fl.PlotConfig(paths=[
        fl.PlotSeries(value="/amhe/planner.data[0]", label="replanning rate [Hz]"),
        fl.PlotSeries(value="/amhe/planner.data[1]", label="compute [ms]")], show_legend=True, legend_display="top"))
    safety = fl.RawMessagesPanel(title="safety state", config=fl.RawMessagesConfig(topic_path="/amhe/safety"))
    log = fl.LogPanel(title="log: warnings, trips, watchdogs", config=fl.LogConfig(topic_to_render="/amhe/log"))
    right = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=2, content=belief_plot(0, "box mass", "kg")),
        fl.SplitItem(proportion=2, content=belief_plot(1, "box–floor μ", "-")),
        fl.SplitItem(proportion=1, content=rate),
        fl.SplitItem(proportion=1, content=fl.SplitContainer(direction="row", items=[
            fl.SplitItem(proportion=1, content=safety), fl.SplitItem(proportion=2, content=log)]))])
    layout = fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=3, content=scene), fl.SplitItem(proportion=2, content=right)]))
    return layout.to_json()
