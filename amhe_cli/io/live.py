"""``--live``: the view (:mod:`amhe_cli.io.view`) streamed to Foxglove over its WebSocket protocol.

The server is the official Foxglove SDK's (``foxglove-sdk``, ``pip install 'amhe[live]'``):
``foxglove.start_server`` on its own :class:`foxglove.Context`, speaking the Foxglove WebSocket
protocol (subprotocols ``foxglove.sdk.v1`` / ``foxglove.websocket.v1``). Each view topic is an SDK
:class:`foxglove.Channel` with the topic's ``ros2msg`` schema and ``cdr`` messages, byte for byte
what a recording holds, so a layout works on both.

Off the control path: hooks hand :class:`~amhe_cli.io.view.Event` s to :meth:`LiveServer.offer`,
which only appends to bounded queues (a full queue drops the oldest frame: frames are dropped, never
delayed, and nothing blocks). One thread of its own converts and sends; it does no work for a topic
nobody subscribed to. The SDK's own per-client backlog drops the oldest message for a slow viewer.
"""

from __future__ import annotations

import collections
import threading
import time
from importlib import resources

from amhe_cli.errors import AmheError
from amhe_cli.io.view import VIEW_TOPICS, Event, ViewFrames, encoder, msgdef

#: Default port of ``--live`` (Foxglove's own default connection string, ws://localhost:8765).
DEFAULT_PORT = 8765
#: Default host: loopback only; ``--live 0.0.0.0:8765`` opens it to the network.
DEFAULT_HOST = "127.0.0.1"
#: Largest number of robot-state frames waiting to be sent (older ones are dropped first).
STATE_QUEUE = 64
#: Largest number of other events (plans, beliefs, logs) waiting; the oldest are dropped first.
EVENT_QUEUE = 256
#: The static scene (and the last of each :data:`LATCHED` kind) is re-sent this often [s] and when a
#: viewer subscribes, so a viewer that joins late sees the robot and the current belief.
SCENE_PERIOD = 2.0
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
    """A Foxglove WebSocket server streaming a view; a context manager.

    Protocol: the Foxglove WebSocket protocol of the official SDK (``foxglove.start_server`` on a
    :class:`foxglove.Context` of its own): one channel per :data:`~amhe_cli.io.view.VIEW_TOPICS`
    topic, ``ros2msg`` schema, ``cdr`` messages, log time = the event's log time [ns].

    Args:
        frames: converts events into messages (owned by the server's thread from :meth:`start` on).
        host, port: where to listen (port 0: any free port; :attr:`port` says which).
        name: the server's name as Foxglove shows it.

    Raises:
        AmheError: the SDK is missing, or the server cannot listen (a busy port, a bad host).

    Attributes:
        sent: messages sent; dropped: events dropped because a queue was full.
        cpu_s: CPU time the sending thread used so far [s] (converting and handing messages to the
            SDK; the SDK's own network threads are not counted).
    """

    def __init__(self, frames: ViewFrames, host: str = DEFAULT_HOST, port: int = DEFAULT_PORT, name: str = "amhe"):
        self.frames = frames
        self.host, self.port, self.name = host, port, name
        self.sent = 0
        self.dropped = 0
        self.cpu_s = 0.0
        self._states: collections.deque = collections.deque(maxlen=STATE_QUEUE)
        self._events: collections.deque = collections.deque(maxlen=EVENT_QUEUE)
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._scene_due = 0.0
        self._thread: threading.Thread | None = None
        self._server = None
        self._channels: dict = {}
        self._encoders = {}
        self._last_t = 0.0
        self._latched: dict[str, Event] = {}

    # -- lifetime -------------------------------------------------------------------------------------------
    def start(self) -> "LiveServer":
        """Listen and start the sending thread.

        Raises:
            AmheError: the SDK is missing or the address cannot be bound.
        """
        fg = require_sdk()
        self._ctx = fg.Context()
        server = self

        class _Listener(fg.websocket.ServerListener):
            def on_subscribe(self, client, channel):  # a new viewer: send the scene again soon
                server._scene_due = 0.0
                server._wake.set()

        try:
            self._server = fg.start_server(name=self.name, host=self.host, port=self.port, context=self._ctx,
                                           server_listener=_Listener())
        except Exception as exc:  # noqa: BLE001 - the SDK raises RuntimeError/OSError variants for a busy port
            why = " ".join(str(exc).split())
            raise AmheError(f"--live {self.host}:{self.port}: cannot listen there ({why})") from None
        self.port = self._server.port
        for topic, msgtype in VIEW_TOPICS.items():
            schema = fg.Schema(name=msgtype, encoding="ros2msg", data=msgdef(msgtype).encode())
            self._channels[topic] = fg.Channel(topic, schema=schema, message_encoding="cdr", context=self._ctx)
            self._encoders[topic] = encoder(msgtype)
        self._thread = threading.Thread(target=self._loop, name="amhe-live", daemon=True)
        self._thread.start()
        return self

    @property
    def address(self) -> str:
        """``ws://HOST:PORT`` to open in Foxglove."""
        return f"ws://{self.host}:{self.port}"

    def close(self) -> None:
        """Send what is queued (up to 1 s), stop the thread and the server. Safe to call twice."""
        if self._thread is not None:
            self._stop.set()
            self._wake.set()
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._server is not None:
            self._server.stop()
            self._server = None

    def __enter__(self) -> "LiveServer":
        return self.start() if self._server is None else self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the hooks' side: never blocks ----------------------------------------------------------------------
    def offer(self, ev: Event) -> None:
        """Queue ``ev`` for sending; a full queue drops its oldest entry (counted in :attr:`dropped`)."""
        q = self._states if ev.kind == "state" else self._events
        if len(q) == q.maxlen:
            self.dropped += 1
        q.append(ev)
        self._wake.set()

    # -- the sending thread ---------------------------------------------------------------------------------
    def _send(self, ev: Event) -> None:
        self._last_t = max(self._last_t, ev.t)
        if ev.kind in LATCHED:
            self._latched[ev.kind] = ev
        wanted = [t for t in _TOPICS_OF.get(ev.kind, ()) if self._channels[t].has_sinks()]
        if not wanted:
            return
        for topic, ns, msg in self.frames.convert(ev):
            if topic in wanted:
                self._channels[topic].log(self._encoders[topic](msg), log_time=ns)
                self.sent += 1

    def _loop(self) -> None:
        draining_until = None
        cpu0 = time.thread_time()
        while True:
            now = time.monotonic()
            self.cpu_s = time.thread_time() - cpu0
            if self._stop.is_set():
                if draining_until is None:
                    draining_until = now + 1.0
                if now >= draining_until or not (self._events or self._states):
                    return
            if now >= self._scene_due:  # periodically, and at once for a new subscriber
                self._scene_due = now + SCENE_PERIOD
                self._safe(Event("scene", self._last_t, ()))
                for ev in list(self._latched.values()):
                    self._safe(ev)
            while self._events:
                self._safe(self._events.popleft())
            wait = 0.05
            while self._states:
                ev = self._states[0]
                if ev.due > now and not self._stop.is_set():
                    wait = min(wait, ev.due - now)
                    break
                self._safe(self._states.popleft())
            self._wake.wait(wait)
            self._wake.clear()

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
