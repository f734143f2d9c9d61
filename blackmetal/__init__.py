"""blackmetal: the product around the gateway and odometry services.

Layers, top to bottom (each imports only from layers below; the
import-linter contract in ``pyproject.toml`` checks it):

1. ``blackmetal.cli``, ``blackmetal.tools`` and ``blackmetal.bench``: the command and user tools;
2. ``blackmetal.gateway``, ``blackmetal.odometry_service``, ``blackmetal.sim`` and the adapters: services and the simulator, independent of each other;
3. ``blackmetal.runtime`` (settings, Zenoh setup and edge, error reports, signals, process harness),
   ``blackmetal.robot_model``, ``blackmetal.wire`` and ``blackmetal.transport``: shared by everything above;
4. ``blackmetal.schemas``: messages, the key space and the error root; imports nothing of ours.
"""

__version__ = "0.2.0"
