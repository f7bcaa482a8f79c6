"""The ROS 2 gateway: the service ``ros2-gateway`` that carries a run's declared topics to ROS 2
Jazzy over rmw_zenoh (``ddvi run --ros2``, a deployment's ``[ros2]``; docs/ros2.md), with the
wire format of ``services.ros2``.

Modules: ``ros_side`` (its second Zenoh session at the ROS 2 endpoint, joined or served, and its
node, publishers, subscriptions and their liveliness tokens), ``exposure`` (the ROS 2 topics a
deployment asks for, and what each bus message becomes on them), ``health`` (the services'
health as diagnostics), ``commands`` (the attitude commands a ROS 2 node sends a deputy flown
from ROS 2, checked before they reach the bus), ``service`` (the service itself, hosted by
``services.flight.host``).

May import: ``services.ros2``, and the layers a flight service may (``services.interface``,
``services.bus``, ``services.config``, ``services.model``, ``services.flight``), zenoh.
"""
