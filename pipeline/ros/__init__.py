"""The network edge: ROS 2 topics over Cyclone DDS from Python, or over rclpy where ROS 2 is installed.

``open_transport("dds" | "rclpy", NetworkSettings(...))`` gives a :class:`Transport`; both backends
speak the contract of :mod:`pipeline.messages.topics`. Importing this package loads neither
cyclonedds nor rclpy; the chosen backend is imported when a transport is opened.
"""

from pipeline.ros.errors import BackendUnavailableError, NetworkSettingsError, TransportError
from pipeline.ros.transport import MessageCallback, NetworkSettings, Publisher, Subscription, Transport, open_transport

__all__ = [
    "BackendUnavailableError",
    "MessageCallback",
    "NetworkSettings",
    "NetworkSettingsError",
    "Publisher",
    "Subscription",
    "Transport",
    "TransportError",
    "open_transport",
]
