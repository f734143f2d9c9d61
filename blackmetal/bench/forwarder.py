"""The command path's floor: the least any Python gateway can do between Zenoh and the robot's socket.

One Zenoh subscriber on ``cmd_vel`` whose callback, on Zenoh's own thread,
decodes the JSON twist (msgspec, the schemas' Twist), turns it into wheel
speeds (the robot model's kinematics) and writes one set-velocity request
(the wire codec's bytes) to the robot's control socket (TCP_NODELAY).
Nothing else: no safety, no arbiter, no loop, no replies read. The bench
runs it in its own process, as it runs the gateway, and sets the gateway's
``cmd_vel`` latency beside it.
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
        session.declare_subscriber(Keys().cmd_vel, forward)
        announce_ready("forwarder")
        threading.Event().wait()
