"""QoS of the nodes' topics: the image_pipeline convention, overridable the standard way.

Publishers are reliable (keep last 10, volatile: what ``SystemDefaultsQoS`` resolves to), so a
plain ``create_subscription(..., 10)``, RViz2 and a bag recorder all match them, and a
best-effort (sensor-data) subscriber is served as well. Subscriptions are sensor-data
(best effort, keep last 5), which matches both reliable and best-effort camera drivers.

Every publisher and subscription is created with
``QoSOverridingOptions.with_default_policies()``: its history, depth and reliability are
read-only parameters ``qos_overrides.<resolved topic>.<publisher|subscription>.<policy>``, set
like any parameter (``-p``, a params file, launch ``parameters``). The profile passed here is
only their default.
"""

from __future__ import annotations

import copy
from collections.abc import Callable
from typing import Any

from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.subscription import Subscription

#: Reliability names as the parameters spell them (the ``qos_overrides`` ones too).
RELIABILITY = {"reliable": ReliabilityPolicy.RELIABLE,
               "best_effort": ReliabilityPolicy.BEST_EFFORT}


def publisher_qos(reliability: str = "reliable", depth: int = 10) -> QoSProfile:
    """Default profile of every image/CameraInfo publisher: reliable, keep last ``depth``."""
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,
                      reliability=RELIABILITY[reliability],
                      durability=DurabilityPolicy.VOLATILE)


def subscription_qos(reliability: str = "best_effort", depth: int = 5) -> QoSProfile:
    """Default profile of every image/CameraInfo subscription: sensor data (best effort, keep
    last 5), which every publisher matches whatever its reliability."""
    return QoSProfile(depth=depth, history=HistoryPolicy.KEEP_LAST,
                      reliability=RELIABILITY[reliability],
                      durability=DurabilityPolicy.VOLATILE)


def overridable_publisher(node: Node, msg_type: Any, topic: str,
                          qos: QoSProfile) -> Publisher:
    """``node.create_publisher`` whose QoS users override with ``qos_overrides.*``."""
    # A copy: rclpy writes the overrides into the profile it is given, and the callers share
    # one profile between topics.
    return node.create_publisher(
        msg_type, topic, copy.copy(qos),
        qos_overriding_options=QoSOverridingOptions.with_default_policies())


def overridable_subscription(node: Node, msg_type: Any, topic: str,
                             callback: Callable[[Any], None], qos: QoSProfile) -> Subscription:
    """``node.create_subscription`` whose QoS users override with ``qos_overrides.*``."""
    return node.create_subscription(  # a copy, as above
        msg_type, topic, callback, copy.copy(qos),
        qos_overriding_options=QoSOverridingOptions.with_default_policies())
