"""A Foxglove WebSocket client (the app's side of the protocol) for tests and benchmarks of the live view."""

from __future__ import annotations

import asyncio
import json
import struct
import threading

import aiohttp

MESSAGE_DATA = 1
"""The protocol's binary opcode of a message on a subscription."""


class Client:
    """Connects to `url`, subscribes to `topics` (all, if empty) as they are advertised, keeps what arrives."""

    def __init__(self, url: str, topics: tuple[str, ...], limit: int = 20, timeout_s: float = 60.0) -> None:
        self.url, self.topics, self.limit, self.timeout_s = url, topics, limit, timeout_s
        self.channels: dict[str, dict] = {}
        self.received: dict[str, list[tuple[int, bytes]]] = {t: [] for t in topics}
        """Per topic, (log time ns, CDR bytes) of the first `limit` messages; empty `topics` subscribes to all."""
        self.count = 0
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def stop(self, timeout_s: float = 10.0) -> None:
        """Wait for the session to end (the server closing) at most `timeout_s`."""
        self.thread.join(timeout=timeout_s)

    def _run(self) -> None:
        try:
            asyncio.run(asyncio.wait_for(self._session(), timeout=self.timeout_s))
        except BaseException as exc:  # reported by the test
            self.error = exc

    async def _session(self) -> None:
        by_sub: dict[int, str] = {}
        ids = iter(range(1, 1 << 30))
        async with aiohttp.ClientSession() as http, http.ws_connect(self.url, protocols=["foxglove.sdk.v1"]) as ws:

            async def subscribe(topic: str) -> None:
                sub_id = next(ids)
                by_sub[sub_id] = topic
                channel = self.channels[topic]["id"]
                await ws.send_str(
                    json.dumps({"op": "subscribe", "subscriptions": [{"id": sub_id, "channelId": channel}]})
                )

            async def retry() -> None:
                # the server may announce a channel a moment before it takes subscriptions to it ("unknown
                # channel"): a subscribed topic that stays silent is asked for again under a new id
                while True:
                    await asyncio.sleep(0.5)
                    for topic in list(self.channels):
                        if not self.received.get(topic):
                            old = [k for k, t in by_sub.items() if t == topic]
                            await ws.send_str(json.dumps({"op": "unsubscribe", "subscriptionIds": old}))
                            await subscribe(topic)

            retrying = asyncio.create_task(retry())
            try:
                async for frame in ws:
                    if frame.type == aiohttp.WSMsgType.TEXT:
                        op = json.loads(frame.data)
                        if op.get("op") != "advertise":
                            continue
                        for ch in op["channels"]:
                            wanted = not self.topics or ch["topic"] in self.topics
                            if wanted and ch["topic"] not in self.channels:
                                self.channels[ch["topic"]] = ch
                                await subscribe(ch["topic"])
                    elif frame.type == aiohttp.WSMsgType.BINARY and frame.data[0] == MESSAGE_DATA:
                        sub_id, log_time = struct.unpack_from("<IQ", frame.data, 1)
                        self.count += 1
                        got = self.received.setdefault(by_sub[sub_id], [])
                        if len(got) < self.limit:
                            got.append((log_time, bytes(frame.data[13:])))
                        if self.topics and all(len(v) >= self.limit for v in self.received.values()):
                            return
                    elif frame.type in (aiohttp.WSMsgType.CLOSED, aiohttp.WSMsgType.ERROR):
                        return
            finally:
                retrying.cancel()


def main() -> None:
    """``python -m tests.peers.foxglove_client URL SECONDS``: the app's side in a process of its own (as the app
    is); subscribes to everything until the server closes or SECONDS pass, then prints ``received=<n>``."""
    import sys

    url, seconds = sys.argv[1], float(sys.argv[2])
    client = Client(url, (), limit=1, timeout_s=seconds)
    client.stop(timeout_s=seconds + 5)
    print(f"received={client.count}", flush=True)


if __name__ == "__main__":
    main()
