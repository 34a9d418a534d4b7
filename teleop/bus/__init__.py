"""The ZeroMQ bus between the robot, estimator and operator nodes.

:mod:`teleop.bus.wire` owns the wire format (documented there, message by message);
:mod:`teleop.bus.pubsub` sends and receives it, lossless or latest-value; :mod:`teleop.bus.peers`
keeps which peers were heard from, and when.
"""

from teleop.bus.peers import Heartbeat
from teleop.bus.pubsub import Publisher, Subscriber, SubscriberStats
from teleop.bus.wire import SCHEMAS, Message, decode, encode, make_message

__all__ = [
    "SCHEMAS",
    "Heartbeat",
    "Message",
    "Publisher",
    "Subscriber",
    "SubscriberStats",
    "decode",
    "encode",
    "make_message",
]
