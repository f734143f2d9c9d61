"""The command path's floor: the least any Python gateway can do between Zenoh and the robot's socket.

Decode, kinematics, one wire request, on Zenoh's own thread (the link's, ``indirect=False``, as a single
robot's gateway takes its commands); no safety, no arbiter, no replies read (docs/performance.md).
"""

from __future__ import annotations

import socket
import threading

import msgspec

from blackmetal import robot_model, wire
from blackmetal.runtime.harness import announce_ready
from blackmetal.schemas import Keys, Twist

from .peers import _zenoh_conf


def forwarder_main(zport: int, control_port: int) -> None:
    """Child process: forward ``cmd_vel`` from Zenoh (listening on ``zport``) to the robot's control port until SIGINT (``__main__``)."""
    import zenoh

    decoder = msgspec.json.Decoder(Twist)
    robot = socket.create_connection(("127.0.0.1", control_port))
    robot.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)

    def forward(sample: zenoh.Sample) -> None:
        twist = decoder.decode(sample.payload.to_bytes())
        wheels, _ = robot_model.twist_to_wheels(twist.linear.x, twist.angular.z, robot_model.WHEEL_SEPARATION, robot_model.MAX_WHEEL_SPEED)
        robot.sendall(wire.encode_request(wire.set_velocity(left=wheels.left, right=wheels.right)))

    with robot, zenoh.open(_zenoh_conf(listen=zport)) as session:
        session.declare_subscriber(Keys().cmd_vel, zenoh.handlers.Callback(forward, indirect=False))
        announce_ready("forwarder")
        threading.Event().wait()
