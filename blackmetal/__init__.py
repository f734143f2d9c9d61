"""blackmetal: the product around the gateway and odometry services.

Four layers, each importing only from those below (docs/concepts.md, "Layers"; the import-linter contract in
``pyproject.toml`` checks it): the command and tools; services and adapters; runtime, robot model, wire and
transport; schemas.
"""

__version__ = "0.2.0"
