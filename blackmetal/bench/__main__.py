"""``python -m blackmetal.bench [echo PORT | robot | flooder PORT KEY SECONDS]``: the benchmark, or one of its peer processes."""

import sys

from . import build_parser, run
from .peers import _echo_main, _flooder_main, _robot_main

if len(sys.argv) > 1 and sys.argv[1] == "echo":
    _echo_main(int(sys.argv[2]))
elif len(sys.argv) > 1 and sys.argv[1] == "flooder":
    _flooder_main(int(sys.argv[2]), sys.argv[3], float(sys.argv[4]))
elif len(sys.argv) > 1 and sys.argv[1] == "robot":
    _robot_main()
else:
    sys.exit(run(build_parser().parse_args()))
