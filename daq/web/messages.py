"""Every message that crosses the web process's boundaries, as pydantic models.

Three boundaries: the daemon hands the web process its configuration (:class:`WebCfg`, one
JSON line on its stdin, so the operator token never appears in a process listing); the web
process asks the daemon to run a control request (:class:`PipeCommand` on its stdout, the
answer :class:`PipeReply` on its stdin: the daemon's own ``ControlServer.handle``, with the
role the web process established); and the browser speaks to the web process over a
WebSocket (:class:`View`, :class:`Ack` in; :class:`Frame` out) and ``POST /api/command``
(:class:`CommandBody`).

Decision record: docs/decisions/0020-live-web-page.md.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from daq.daemon.control import Op, Reply
from daq.strict import Closed

Role = Literal["operator", "observer"]


class WebCfg(Closed):
    """What the daemon tells its web process."""

    model_config = ConfigDict(frozen=True)
    host: str = "127.0.0.1"
    port: int = Field(0, ge=0, le=65535, description="0: any free port (the ready line says which)")
    bus: str = Field(description="the daemon's sample bus")
    also: list[str] = Field(default_factory=list, description="more publishers (the estimator's)")
    rig: str = ""
    curve: bool = Field(False, description="CURVE keys configured: a page is an observer unless it gives the token")
    token: str | None = Field(None, min_length=16, description="the operator token (with CURVE)")
    parent_pid: int = 0
    frame_s: float = Field(0.02, gt=0, le=1.0, description="shortest interval between two frames to one page")
    max_unacked: int = Field(1, ge=1, le=16, description="frames a page may hold unpainted before we wait for it "
                                                          "(more let frames queue behind the page's painting)")
    max_clients: int = Field(16, ge=1, le=256, description="pages without the operator token (observers; all "
                                                          "pages without CURVE)")
    max_operator_pages: int = Field(4, ge=1, le=64, description="pages with the operator token, beside the others: "
                                                                "viewers can never take the operator's place")
    max_body_bytes: int = Field(1 << 20, ge=1024, le=1 << 28,
                                description="request bodies above this get 413 as they arrive, never forwarded")
    observer_burst: int = Field(30, ge=1, le=10_000, description="token-less API requests and WebSocket handshakes "
                                                                 "one address may make at once (a page load: 2)")
    observer_rate_hz: float = Field(2.0, gt=0, le=1000.0, description="... and then per second; the operator is "
                                                                      "never limited (daq/web/limits.py)")
    status_s: float = Field(0.5, gt=0, description="how often the daemon's status is fetched")
    rcvhwm: int = Field(20_000, ge=100, description="bus blocks queued in the web process before it drops")


class PipeCommand(Closed):
    """Web process -> daemon: run this control request (raw JSON, as a client would send it) as ``role``."""

    id: int
    role: Role
    request: str


class PipeReply(Closed):
    """Daemon -> web process: the control server's reply to command ``id``."""

    id: int
    reply: Reply


class View(Closed):
    """Browser -> web process: what the page shows (time window, plot width in pixels)."""

    type: Literal["view"]
    window_s: float = Field(10.0, ge=0.0, le=86_400.0, description="0: the whole run")
    width: int = Field(1000, ge=50, le=8000)


class Ack(Closed):
    """Browser -> web process: frame ``seq`` is drawn (the page's flow control and the latency measurement)."""

    type: Literal["ack"]
    seq: int = Field(ge=0)


class ClientMessage(BaseModel):
    msg: Annotated[View | Ack, Field(discriminator="type")]


class CommandBody(Closed):
    """``POST /api/command``: one control request; the web process adds the id and the role."""

    op: Op
    args: dict[str, Any] = Field(default_factory=dict)


class StreamFrame(BaseModel):
    """New envelope columns of one stream: column ``k[i]`` spans ``[k dt, (k+1) dt)`` of run time.

    ``reset``: the page drops what it holds of this stream first (a new view); otherwise it
    drops its columns from ``k[0]`` on (the last one sent may have been still filling).
    """

    channels: list[str]
    units: list[str]
    dt: float
    reset: bool
    k: list[int]
    lo: list[list[float]]  # per channel; NaN (JSON null) = a gap
    hi: list[list[float]]


class EventRow(BaseModel):
    seq: int
    t: float  # run time [s]
    kind: str
    source: str
    detail: str
    count: int | None = None


class Scatter(BaseModel):
    """Friction coefficient against relative velocity over the last seconds (the estimator's)."""

    seconds: float
    v_rel: list[float]
    mu: list[float]


class Frame(BaseModel):
    """Web process -> browser: everything new since the page's last frame."""

    type: Literal["frame"] = "frame"
    seq: int
    now: float  # run time when built [s]
    origin_wall: float  # Unix time of run time 0
    window_s: float  # the window in force (the whole run's length so far for window 0)
    streams: dict[str, StreamFrame]
    events: list[EventRow]
    events_dropped: int = 0  # events this page missed (it fell further behind than the event ring)
    status: dict[str, Any] | None = None
    scatter: Scatter | None = None
    cycles: list[dict[str, float]] | None = None
