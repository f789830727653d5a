"""ROS 2 message definitions, CDR and topic names shared by the recorder and the transports.

Standard Jazzy types come from the rosbags type store; the project's own types (``mrl_msgs``) come
from the ``.msg`` files in ``schemas/``. Every recorded type also has its ``.msg`` text in
``schemas/``; loading registers those files on top of the Jazzy store, which refuses a definition
that disagrees with its own, so the folder cannot drift from what is written to the wire.
"""

from pipeline.messages.store import MessageStore, message_store
from pipeline.messages.topics import QOS_COMMAND, QOS_EVENT, QOS_SENSOR, QosProfile, TopicSpec, fleet_topics

__all__ = [
    "QOS_COMMAND",
    "QOS_EVENT",
    "QOS_SENSOR",
    "MessageStore",
    "QosProfile",
    "TopicSpec",
    "fleet_topics",
    "message_store",
]
