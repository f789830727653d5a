"""A live view of a session in the Foxglove app, served by Foxglove's own SDK (``foxglove-sdk``).

:class:`LiveView` starts the SDK's WebSocket server (default ``ws://127.0.0.1:8765``, the app's
default connection) and taps a :class:`~pipeline.record.writer.McapRecorder`: every message the
session records goes out on a channel of the same topic, ROS 2 schema (``ros2msg``, the text
rosbag2 stores) and CDR bytes, stamped with its log time, so the app shows the session with the
bundled layout (``pipeline/record/foxglove_layout.json``) as it runs, exactly as it will read the
MCAP afterwards. Logging a message hands its bytes to the SDK, which queues them for connected
clients on its own threads; a message the SDK refuses is counted, never raised into the recorder.
"""

from __future__ import annotations

import contextlib
import logging
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from pipeline.errors import MrlError
from pipeline.messages.store import MessageStore, message_store
from pipeline.record.writer import McapRecorder

log = logging.getLogger(__name__)

LAYOUT_FILE = Path(__file__).resolve().parent / "foxglove_layout.json"
"""The bundled layout for the three reference robots (Layouts -> Import from file)."""
DEFAULT_PORT = 8765
"""The Foxglove app's default WebSocket port."""


class LiveViewError(MrlError):
    """The live view cannot start (the SDK is missing, or the port is taken)."""

    def __init__(self, detail: str) -> None:
        super().__init__(f"live view: {detail}")


class LiveView:
    """A Foxglove WebSocket server fed by recorders; `port` 0 picks a free port (see :attr:`port`)."""

    def __init__(
        self, host: str = "127.0.0.1", port: int = DEFAULT_PORT, name: str = "mrl", store: MessageStore | None = None
    ) -> None:
        try:
            import foxglove
        except ImportError as exc:
            raise LiveViewError("the foxglove-sdk package is not installed (pip install foxglove-sdk)") from exc
        self._foxglove = foxglove
        self.store = store if store is not None else message_store()
        self.context = foxglove.Context()
        try:
            self.server = foxglove.start_server(name=name, host=host, port=port, context=self.context)
        except Exception as exc:  # the SDK raises its own error types for a taken port or bad host
            raise LiveViewError(f"cannot serve on {host}:{port}: {exc}") from exc
        self.host = host
        self.port = int(self.server.port)
        self.failures = 0
        self._channels: dict[str, Any] = {}
        self._lock = threading.Lock()

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def attach(self, recorder: McapRecorder) -> None:
        """Serve everything `recorder` records from now on."""
        recorder.taps.append(self.log)

    def log(self, topic: str, typename: str, data: bytes, log_time_ns: int) -> None:
        """Send one CDR message of `typename` on `topic` to connected clients."""
        try:
            channel = self._channels.get(topic)
            if channel is None:
                channel = self._channel(topic, typename)
            channel.log(data, log_time=log_time_ns)
        except Exception as exc:  # the view never stops the session it shows
            self.failures += 1
            if self.failures == 1:
                log.warning("live view: a message on %s was not sent (%s); further failures are counted", topic, exc)

    def _channel(self, topic: str, typename: str) -> Any:
        with self._lock:
            channel = self._channels.get(topic)
            if channel is None:
                fg = self._foxglove
                schema = fg.Schema(name=typename, encoding="ros2msg", data=self.store.msgdef(typename).encode())
                channel = fg.Channel(topic, schema=schema, message_encoding="cdr", context=self.context)
                self._channels[topic] = channel
            return channel

    def close(self) -> None:
        self.server.stop()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@contextlib.contextmanager
def live_view(enabled: bool, port: int = DEFAULT_PORT, what: str = "session") -> Iterator[LiveView | None]:
    """A LiveView for the duration of the block when `enabled` (its address printed), else None."""
    if not enabled:
        yield None
        return
    view = LiveView(port=port)
    print(f"live view: {what} served at {view.url} (Foxglove: Open connection; layout: {LAYOUT_FILE})", flush=True)
    try:
        yield view
    finally:
        view.close()
