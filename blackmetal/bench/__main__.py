"""``python -m blackmetal.bench [echo PORT | robot | flooder PORT KEY SECONDS | forwarder PORT CONTROL_PORT]``: the benchmark, or one of its peer processes.

A peer ends quietly on SIGINT: the bench stops its peers with it, and Ctrl-C reaches the whole process group.
"""

import sys

from . import build_parser, run
from .forwarder import forwarder_main
from .peers import echo_main, flooder_main, robot_main

PEERS = {
    "echo": lambda args: echo_main(int(args[0])),
    "flooder": lambda args: flooder_main(int(args[0]), args[1], float(args[2])),
    "robot": lambda args: robot_main(),
    "forwarder": lambda args: forwarder_main(int(args[0]), int(args[1])),
}

if len(sys.argv) > 1 and sys.argv[1] in PEERS:
    try:
        PEERS[sys.argv[1]](sys.argv[2:])
    except KeyboardInterrupt:
        pass
else:
    sys.exit(run(build_parser().parse_args()))
